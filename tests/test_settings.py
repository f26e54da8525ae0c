"""Valid ranges of settings: their meaning, a refusal naming the key for each nonsense value the
issue found, and every key of configs/ declaring a range its file documents."""

from __future__ import annotations

import os
import re
import threading
from pathlib import Path
from typing import Annotated, Literal

import msgspec.inspect as mi
import pytest

from data_tools.landmarks2d import _ConfigFile as Landmarks2dFile
from data_tools.renderer.config import RendererConfig
from data_tools.scenarios.city_grid import CityGridConfig
from data_tools.scenarios.indoor_tags import IndoorTagsConfig
from data_tools.scenarios.kitti05_cars import Kitti05CarsConfig
from data_tools.scenarios.planar_park import PlanarParkConfig
from data_tools.sweep.config import FACTOR_RANGES, NUM_CLASSES, SEED_COUNT
from pipeline import settings
from pipeline.cli import main
from pipeline.config import Config, load_config
from pipeline.errors import InputError
from pipeline.frontend.config import FrontendConfig
from pipeline.settings import FRACTION, PROBABILITY, positive, within
from pipeline.viz.config import _VizFile

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
TYPED_FILES = {
    "default.toml": Config,
    "paper.toml": Config,
    "viz.toml": _VizFile,
    "frontend.toml": FrontendConfig,
    "landmarks2d.toml": Landmarks2dFile,
    "plain-calibration.toml": None,  # a sequence's calibration, read by its own reader
    "renderer/demo.toml": RendererConfig,
    "renderer/kitti-size.toml": RendererConfig,
    "renderer/corridor.toml": RendererConfig,
    "tag-poses.toml": Config,
    "scenarios/indoor-tags.toml": IndoorTagsConfig,
    "scenarios/city-grid.toml": CityGridConfig,
    "scenarios/city-grid-world3.toml": CityGridConfig,
    "scenarios/small-indoor-tags.toml": IndoorTagsConfig,
    "scenarios/kitti05-cars.toml": Kitti05CarsConfig,
    "scenarios/planar-park.toml": PlanarParkConfig,
}
KEY_LINE = re.compile(r"^\s*([A-Za-z0-9_]+)\s*=(.*)$")
TABLE_LINE = re.compile(r"^\s*\[\[?\s*([A-Za-z0-9_.]+)\s*\]\]?")
DOC = re.compile(r"#.*valid:\s*(.*?)\s*$")


def _range(kind: type, meta) -> mi.Type:
    return mi.type_info(Annotated[kind, meta])


@pytest.mark.parametrize(
    "info,inside,outside,text",
    [
        (_range(int, within(1, 1000)), [1, 2, 1000], [0, -1, 1001], "in [1, 1000]"),
        (_range(float, positive(1e6)), [1e-300, 5.0, 1e6], [0.0, -1e-9, 1.5e6], "in (0, 1e6]"),
        (
            _range(float, within(0.0, 1.0, high_open=True)),
            [0.0, 0.5, 0.999999],
            [1.0, -0.1, 2.0, float("nan")],
            "in [0, 1)",
        ),
        (_range(float, PROBABILITY), [0.1, 0.9], [0.0, 1.0], "in (0, 1)"),
        (_range(float, FRACTION), [1.0, 0.01], [0.0, 1.01, float("inf")], "in (0, 1]"),
        (_range(int, within(0, 2**32 - 1)), [0, 2**32 - 1], [2**32], "in [0, 4294967295]"),
        (mi.type_info(Literal["QR", "CHOLESKY"]), ["QR"], ["qr", ""], "one of CHOLESKY, QR"),
    ],
)
def test_a_range_holds_what_it_says(info, inside, outside, text):
    assert all(settings.holds(info, v) for v in inside)
    assert not any(settings.holds(info, v) for v in outside)
    assert settings.describe(info) == text


ISSUE_SETTINGS = {  # the nonsense settings issue 13 found running, or killing replay with SIGFPE
    "relinearize_skip = 0": ("isam2", "'isam2.relinearize_skip' must be in [1, 1e6], got 0"),
    "search_margin_m = -3": ("association", "'association.search_margin_m' must be in [0, 1e6]"),
    "min_weight = 2": ("association", "'association.min_weight' must be in [0, 1), got 2"),
    "relinearize_threshold = -0.1": ("isam2", "'isam2.relinearize_threshold' must be in [0, "),
    "pose0_sigma_translation = 0": ("prior", "'prior.pose0_sigma_translation' must be in (0, "),
    "pose0_sigma_rotation = -1e-6": ("prior", "'prior.pose0_sigma_rotation' must be in (0, "),
    "search_sigmas = -4.0": ("association", "'association.search_sigmas' must be in [0, 1000]"),
    "chi2_confidence = 1.5": ("association", "'association.chi2_confidence' must be in (0, 1)"),
    "selection = 'fastest'": ("mixture", "'mixture.selection' must be one of between-updates"),
    "max_iterations = 0": ("gpda", "'gpda.max_iterations' must be in [1, 1000]"),
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
    "[association]\nnull_model = 'gaussian'": "'association.null_model' must be one of literal, r",
    "[association]\njoint_confidence = 1.0": "'association.joint_confidence' must be in (0, 1)",
    "[association]\nambiguity_log_odds = -1.0": "'association.ambiguity_log_odds' must be in [0,",
    "[association]\nmin_loop_pairs = 0": "'association.min_loop_pairs' must be in [1, 1000], got 0",
    "[association]\nmax_joint_detections = 0": "'association.max_joint_detections' must be in [1,",
    "[association]\nmax_keyframe_nodes = 0": "'association.max_keyframe_nodes' must be in [1, 1e7]",
    "[association]\nmin_loop_pairs = 4": "association.crowded_loop_pairs must be >= association",
    "[association]\nnull_crossover_sq = 0.0": "'association.null_crossover_sq' must be in (0,",
    "[mixture]\nfirst_choice = 'best'": "'mixture.first_choice' must be one of joint, prediction",
    "[merges]\nmin_class_agreement = 1.5": "'merges.min_class_agreement' must be in [0, 1]",
    "[merges]\nevery_keyframes = 0": "'merges.every_keyframes' must be in [1, 1e6], got 0",
    "[merges]\nlocal_confidence = 0.0": "'merges.local_confidence' must be in (0, 1)",
    "[merges]\nloop_log_odds = -0.5": "'merges.loop_log_odds' must be in [0, 1000]",
    "[merges]\nsearch_sigmas = 0.0": "'merges.search_sigmas' must be in (0, 1000]",
    "[merges]\nmax_pairs = 0": "'merges.max_pairs' must be in [1, 100000], got 0",
    "[merges]\nmax_check_nodes = 0": "'merges.max_check_nodes' must be in [1, 1e7], got 0",
    "[merges]\nmax_marginals = 0": "'merges.max_marginals' must be in [1, 1e6], got 0",
    "[isam2]\nmax_root_landmarks = 0": "'isam2.max_root_landmarks' must be in [1, 1e6], got 0",
    "[landmarks]\nanchor_sigma_m = 0.0": "'landmarks.anchor_sigma_m' must be in (0, 1e9]",
    "[noise]\nmin_scale = 0.0": "'noise.min_scale' must be in (0, 1]",
    "[noise]\nmax_scale = 0.5": "'noise.max_scale' must be in [1, 1e6]",
    "[noise]\nmeasurement_scale = [1.0, -1.0, 1.0]": "'noise.measurement_scale[1]' must be in (0,",
    "[noise]\ndrift_windows = 0": "'noise.drift_windows' must be in [1, 1e6], got 0",
    "[noise]\nodometry_scale = [1, 1, 20000, 1, 1, 1]": "noise.odometry_scale and measurement_",
    "[noise]\nodometry_scale = [1, 1, 1]": "'noise.odometry_scale' must",
    "[noise]\ndrop = -1": "'noise.drop' must be in [0, 1000], got -1",
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
    with pytest.raises(InputError, match=r"'merges\.prior_log_odds' must be finite, in \[-1000"):
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
        InputError, match=re.escape("'objects.input_size[1]' must be in [32, 8192], got 16")
    ):
        load_frontend_config(config)


def test_a_config_that_is_not_utf8_is_one_line(tmp_path):
    config = tmp_path / "latin1.toml"
    config.write_bytes("# caf\xe9\n[isam2]\nrelinearize_skip = 2\n".encode("latin-1"))
    with pytest.raises(InputError, match="not UTF-8 text") as raised:
        load_config(config)
    assert "\n" not in str(raised.value)


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


def test_every_config_file_is_declared():
    files = {str(p.relative_to(CONFIGS)) for p in CONFIGS.rglob("*.toml")}
    sweeps = {name for name in files if name.startswith("sweeps/")}
    assert files - sweeps <= set(TYPED_FILES), sorted(files - sweeps - set(TYPED_FILES))


@pytest.mark.parametrize("name", sorted(n for n, cls in TYPED_FILES.items() if cls is not None))
def test_every_setting_declares_both_bounds_and_its_file_documents_them(name):
    leaves = settings.leaves(TYPED_FILES[name])
    for key, info in leaves.items():
        scalar = info
        if isinstance(info, mi.VarTupleType | mi.TupleType):
            items = [info.item_type] if isinstance(info, mi.VarTupleType) else info.item_types
            scalar = items[0]
        if isinstance(scalar, mi.IntType | mi.FloatType):
            low = scalar.ge if scalar.ge is not None else scalar.gt
            high = scalar.le if scalar.le is not None else scalar.lt
            assert low is not None and high is not None, f"{key} declares no range, or one end"
    for key, doc in _documented(CONFIGS / name).items():
        if key not in leaves:  # a free-form table's entry, such as objects.class_map.car
            assert doc is None, f"{name}: {key} documents a range it does not have"
            continue
        expected = settings.describe(leaves[key])
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
            expected = settings.describe(valid) if valid else None
            assert (doc.group(1) if doc else None) == expected, line
    assert docs


def _deep_arrays(path: Path) -> Path:
    path.write_text("a = " + "[" * 500 + "]" * 500 + "\n")
    return path


def _deep_tables(path: Path) -> Path:
    path.write_text("a = " + "{b = " * 500 + "1" + "}" * 500 + "\n")
    return path


def _dotted(path: Path) -> Path:
    path.write_text("a" + ".b" * 2000 + " = 1\n")
    return path


def _long_key(path: Path) -> Path:
    path.write_text("k" * 100_000 + " = 1\n")
    return path


def _sparse(path: Path) -> Path:
    with open(path, "wb") as f:
        f.truncate(2 * 2**30)  # 2 GB that take no disk
    return path


def _endless_pipe(path: Path) -> Path:
    """A FIFO a thread fills for as long as someone reads it."""
    os.mkfifo(path)

    def fill() -> None:
        try:
            with open(path, "wb") as f:
                while True:
                    f.write(b"#" * 65536)
        except OSError:  # the reader has gone
            pass

    threading.Thread(target=fill, daemon=True).start()
    return path


HOSTILE_CONFIGS = {
    "500 nested arrays": (_deep_arrays, "arrays or tables nested deeper than 32 levels"),
    "500 nested inline tables": (_deep_tables, "arrays or tables nested deeper than 32 levels"),
    "a key of 2000 dotted parts": (_dotted, "tables nested deeper than 32 levels"),
    "a key of 100,000 characters": (_long_key, "a key of 100000 characters ('kkkk"),
    "/dev/zero": (lambda path: Path("/dev/zero"), "larger than 1 MiB; not a config file"),
    "a 2 GB file": (_sparse, "larger than 1 MiB; not a config file"),
    "an endless FIFO": (_endless_pipe, "larger than 1 MiB; not a config file"),
}
# Every command that reads a config file, with the file at CONFIG.
CONFIG_READERS = {
    "replay": ["replay", "absent.mcap", "--method", "ml", "--out", "out", "--config", "CONFIG"],
    "compare": ["compare", "absent.mcap", "--out", "out", "--config", "CONFIG"],
    "simulate": ["simulate", "city-grid", "--out", "x.mcap", "--config", "CONFIG"],
    "sweep": ["sweep", "CONFIG", "--out", "out"],
    "frontend": ["frontend", "absent", "--out", "x.mcap", "--config", "CONFIG"],
    "convert": ["convert", "absent.txt", "--out", "x.mcap", "--config", "CONFIG"],
}


@pytest.mark.parametrize("reader", sorted(CONFIG_READERS))
@pytest.mark.parametrize("case", sorted(HOSTILE_CONFIGS))
def test_every_config_reader_refuses_a_hostile_file_in_one_line(
    tmp_path, monkeypatch, capsys, reader, case
):
    """Issue 53: 500 `[` made every reader a 3,002-line RecursionError, and `--config
    /dev/zero` was read until memory ran out."""
    make, needle = HOSTILE_CONFIGS[case]
    config = make(tmp_path / "hostile.toml")
    monkeypatch.chdir(tmp_path)
    args = [str(config) if a == "CONFIG" else a for a in CONFIG_READERS[reader]]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"config {config}: " in err and needle in err, err
    assert len(err) < 300
    assert [p.name for p in tmp_path.iterdir() if p != config] == []  # nothing written


def test_nesting_does_not_count_brackets_in_strings_or_comments():
    text = 'a = "[[[[" # [[[[[\nb = """\n{{{{\n"""\nc = \'[[\'\n[t]\nd = [[1], [2]]\n'
    assert settings.nesting(text) == 2
    assert max(settings.nesting(p.read_text()) for p in CONFIGS.rglob("*.toml")) <= 3
