"""Valid ranges of settings: their meaning, a refusal naming the key for each nonsense value the
issue found, and every key of configs/ declaring a range its file documents."""

from __future__ import annotations

import dataclasses
import re
import typing
from pathlib import Path

import pytest

from data_tools.renderer.config import RendererConfig
from data_tools.sweep.config import FACTOR_RANGES, NUM_CLASSES, SEED_COUNT
from pipeline import settings
from pipeline.config import Config, load_config
from pipeline.errors import InputError
from pipeline.frontend.config import FrontendConfig
from pipeline.settings import ANY, Valid, at_least, between, one_of
from pipeline.viz.config import _VizFile

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
TYPED_FILES = {
    "default.toml": Config,
    "paper.toml": Config,
    "viz.toml": _VizFile,
    "frontend.toml": FrontendConfig,
    "renderer/demo.toml": RendererConfig,
    "renderer/kitti-size.toml": RendererConfig,
    "renderer/corridor.toml": RendererConfig,
    "sweeps/indoor-tags-backend.toml": Config,
}
KEY_LINE = re.compile(r"^\s*([A-Za-z0-9_]+)\s*=(.*)$")
TABLE_LINE = re.compile(r"^\s*\[\[?\s*([A-Za-z0-9_.]+)\s*\]\]?")
DOC = re.compile(r"#.*valid:\s*(.*?)\s*$")


@pytest.mark.parametrize(
    "valid,inside,outside,text",
    [
        (at_least(1), [1, 2, 10**9], [0, -1, 0.999], ">= 1"),
        (settings.POSITIVE, [1e-300, 5.0], [0.0, -1e-9], "> 0"),
        (between(0.0, 1.0, high_open=True), [0.0, 0.5, 0.999999], [1.0, -0.1, 2.0], "in [0, 1)"),
        (settings.PROBABILITY, [0.1, 0.9], [0.0, 1.0], "in (0, 1)"),
        (settings.FRACTION, [1.0, 0.01], [0.0, 1.01], "in (0, 1]"),
        (Valid(high=3.0, high_open=True), [-5.0, 2.9], [3.0], "< 3"),
        (one_of("QR", "CHOLESKY"), ["QR"], ["qr", ""], "one of QR, CHOLESKY"),
        (ANY, [-1e300, 0, 7], [], "any"),
    ],
)
def test_a_range_holds_what_it_says(valid, inside, outside, text):
    assert all(valid.holds(v) for v in inside)
    assert not any(valid.holds(v) for v in outside)
    assert valid.describe() == text


ISSUE_SETTINGS = {  # the nonsense settings issue 13 found running, or killing replay with SIGFPE
    "relinearize_skip = 0": ("isam2", "'isam2.relinearize_skip' must be >= 1, got 0"),
    "search_margin_m = -3": ("association", "'association.search_margin_m' must be >= 0"),
    "min_weight = 2": ("association", "'association.min_weight' must be in [0, 1), got 2"),
    "relinearize_threshold = -0.1": ("isam2", "'isam2.relinearize_threshold' must be >= 0"),
    "pose0_sigma_translation = 0": ("prior", "'prior.pose0_sigma_translation' must be > 0"),
    "pose0_sigma_rotation = -1e-6": ("prior", "'prior.pose0_sigma_rotation' must be > 0"),
    "search_sigmas = -4.0": ("association", "'association.search_sigmas' must be >= 0"),
    "chi2_confidence = 1.5": ("association", "'association.chi2_confidence' must be in (0, 1)"),
    "selection = 'fastest'": ("mixture", "'mixture.selection' must be one of between-updates"),
    "max_iterations = 0": ("gpda", "'gpda.max_iterations' must be >= 1"),
}


@pytest.mark.parametrize("line", sorted(ISSUE_SETTINGS))
def test_a_setting_outside_its_range_is_refused_naming_the_key(tmp_path, line):
    table, needle = ISSUE_SETTINGS[line]
    config = tmp_path / "bad.toml"
    config.write_text(f"[{table}]\n{line}\n")
    with pytest.raises(InputError) as raised:
        load_config(config)
    assert str(raised.value).startswith(f"config {config}: {needle}")
    assert "\n" not in str(raised.value)


NEW_BACKEND_SETTINGS = {  # the association, mixture, merge and noise keys of back-end v2
    "[association]\nnull_model = 'gaussian'": "'association.null_model' must be one of relative",
    "[association]\njoint_confidence = 1.0": "'association.joint_confidence' must be in (0, 1)",
    "[association]\nambiguity_log_odds = -1.0": "'association.ambiguity_log_odds' must be >= 0",
    "[association]\nmin_loop_pairs = 0": "'association.min_loop_pairs' must be >= 1, got 0",
    "[association]\nmin_loop_pairs = 4": "association.crowded_loop_pairs must be >= association",
    "[association]\nnull_crossover_sq = 0.0": "'association.null_crossover_sq' must be > 0",
    "[mixture]\nfirst_choice = 'best'": "'mixture.first_choice' must be one of joint, prediction",
    "[merges]\nmin_class_agreement = 1.5": "'merges.min_class_agreement' must be in [0, 1]",
    "[merges]\nevery_keyframes = 0": "'merges.every_keyframes' must be >= 1, got 0",
    "[merges]\nlocal_confidence = 0.0": "'merges.local_confidence' must be in (0, 1)",
    "[merges]\nloop_log_odds = -0.5": "'merges.loop_log_odds' must be >= 0",
    "[merges]\nsearch_sigmas = 0.0": "'merges.search_sigmas' must be > 0",
    "[landmarks]\nanchor_sigma_m = 0.0": "'landmarks.anchor_sigma_m' must be > 0",
    "[noise]\nmin_scale = 0.0": "'noise.min_scale' must be in (0, 1]",
    "[noise]\nmax_scale = 0.5": "'noise.max_scale' must be >= 1",
    "[noise]\nmeasurement_scale = [1.0, -1.0, 1.0]": "'noise.measurement_scale[1]' must be > 0",
    "[noise]\nwindow = 0": "'noise.window' must be >= 1, got 0",
    "[noise]\nodometry_scale = 500.0": "noise.odometry_scale and measurement_scale must lie",
    "[noise]\nodometry_start_scale = 500.0": "noise.odometry_start_scale must be <= max_scale",
}


@pytest.mark.parametrize("text", sorted(NEW_BACKEND_SETTINGS))
def test_the_back_end_v2_keys_are_refused_outside_their_ranges(tmp_path, text):
    config = tmp_path / "bad.toml"
    config.write_text(text + "\n")
    with pytest.raises(InputError) as raised:
        load_config(config)
    assert str(raised.value).startswith(f"config {config}: {NEW_BACKEND_SETTINGS[text]}")


def test_prior_log_odds_takes_any_finite_number(tmp_path):
    config = tmp_path / "odds.toml"
    config.write_text("[merges]\nprior_log_odds = -2.5\n")
    assert load_config(config).merges.prior_log_odds == -2.5
    config.write_text("[merges]\nprior_log_odds = inf\n")
    with pytest.raises(InputError, match=r"'merges\.prior_log_odds' must be finite"):
        load_config(config)


def test_the_papers_settings_load_over_the_defaults():
    paper = load_config(settings.config_path("paper.toml"))
    assert (paper.association.null_model, paper.mixture.first_choice) == ("literal", "weights")
    assert not paper.merges.enabled and not paper.noise.estimate
    assert not paper.isam2.per_type_thresholds
    assert paper.association.chi2_confidence == load_config().association.chi2_confidence


def test_ranges_hold_in_tuples_too(tmp_path):
    config = tmp_path / "f.toml"
    config.write_text("[objects]\ninput_size = [832, 16]\n")
    from pipeline.frontend.config import load_frontend_config

    with pytest.raises(
        InputError, match=re.escape("'objects.input_size[1]' must be >= 32, got 16")
    ):
        load_frontend_config(config)


def test_a_config_that_is_not_utf8_is_one_line(tmp_path):
    config = tmp_path / "latin1.toml"
    config.write_bytes("# caf\xe9\n[isam2]\nrelinearize_skip = 2\n".encode("latin-1"))
    with pytest.raises(InputError, match="not UTF-8 text") as raised:
        load_config(config)
    assert "\n" not in str(raised.value)


def _leaves(cls: type, prefix: str = "") -> dict[str, tuple[type, Valid | None]]:
    """Every setting of a config dataclass: dotted key -> (type, declared range)."""
    leaves = {}
    hints = typing.get_type_hints(cls)
    for field in dataclasses.fields(cls):
        kind = hints[field.name]
        if dataclasses.is_dataclass(kind):
            leaves.update(_leaves(kind, f"{prefix}{field.name}."))
        else:
            leaves[prefix + field.name] = (kind, field.metadata.get(settings.VALID))
    return leaves


def _documented(path: Path) -> dict[str, str | None]:
    """Dotted key -> the `# valid:` text on its line (None where there is none)."""
    docs, table = {}, ""
    for line in path.read_text().splitlines():
        if line.lstrip().startswith("#"):
            continue
        if header := TABLE_LINE.match(line):
            table = header.group(1) + "."
        elif key := KEY_LINE.match(line):
            doc = DOC.search(key.group(2))
            docs[table + key.group(1)] = doc.group(1) if doc else None
    return docs


@pytest.mark.parametrize("name", sorted(TYPED_FILES))
def test_every_setting_declares_a_range_its_file_documents(name):
    leaves = _leaves(TYPED_FILES[name])
    for key, (kind, valid) in leaves.items():
        scalar = typing.get_args(kind)[0] if typing.get_origin(kind) is tuple else kind
        if scalar in (int, float, str):
            assert valid is not None, f"{key} declares no valid range"
    for key, doc in _documented(CONFIGS / name).items():
        if key not in leaves:  # a free-form table's entry, such as objects.class_map.car
            assert doc is None, f"{name}: {key} documents a range it does not have"
            continue
        valid = leaves[key][1]
        expected = None if valid in (None, ANY) else valid.describe()
        assert doc == expected, f"{name}: {key} says {doc!r}, its range is {expected!r}"


SWEEPS = sorted(p for p in (CONFIGS / "sweeps").glob("*.toml") if "methods" in p.read_text())


@pytest.mark.parametrize("path", SWEEPS, ids=lambda p: p.name)
def test_sweep_files_document_their_ranges(path):
    docs, factor = _documented(path), None
    ranges = {"seeds": SEED_COUNT, "num_classes": NUM_CLASSES, **FACTOR_RANGES}
    for line in path.read_text().splitlines():
        if key := KEY_LINE.match(line):
            name, doc = key.group(1), DOC.search(key.group(2))
            factor = key.group(2).split("#")[0].strip().strip('"') if name == "factor" else factor
            valid = FACTOR_RANGES[factor] if name == "values" else ranges.get(name)
            assert (doc.group(1) if doc else None) == (valid.describe() if valid else None), line
    assert docs
