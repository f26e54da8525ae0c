"""Sweep configuration: a TOML file read into frozen dataclasses, checked key by key.

A sweep names a scenario, a base cell (odometry noise scale, misclassification rate), axes that
vary one factor from the base, the seeds of every cell and the methods. Paths in the file are
relative to the file. Every problem is an `InputError` naming the file and the key.

    name = "indoor-tags"              # optional (default: the file's stem)
    scenario = "indoor-tags"
    scenario_config = "small.toml"    # optional, over configs/scenarios/<scenario>.toml
    backend_config = "backend.toml"   # optional, over configs/default.toml
    num_classes = 2                   # optional (default: the scenario's); in [1, 1000]
    true_covariance = false           # optional
    seeds = 10                        # seeds 0..9 (1 to 10000), or a list of seeds >= 0: [0, 4, 7]
    methods = ["known", "ml", "gpda", "mm", "mm-nh"]
    odom_noise_scale = 1.0            # the base cell (default: the scenario's); in [0, 100]
    misclassification = 0.1           # the base cell (default: 0); in [0, 1]

    [[axes]]                          # optional, any number; each makes a figure
    name = "noise"
    factor = "odom_noise_scale"       # or "misclassification", or "stated_yaw" and the like
    values = [0, 2, 4, 6, 8, 10]      # the other factors stay at the base cell's; its range

A stated-noise axis states one direction of the log's noise its values times (variances) what
it would state: an odometry direction ("stated_roll" .. "stated_vertical", "stated_odometry"
for all six), or a detection component ("stated_bearing", "stated_elevation",
"stated_range", "stated_detections" for all three); its value 1 is the log as it is.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import msgspec.inspect as mi

from data_tools.scenarios import MAX_NOISE_SCALE, SCENARIOS, load_config
from data_tools.stated_noise import MAX_FACTOR, STATED_DIRECTIONS
from pipeline import settings
from pipeline.backend.methods import METHODS
from pipeline.errors import InputError

# An axis stating one direction of the log's noise wrong (or all of the odometry's, or of the
# detections'), by variance factors (`data_tools/stated_noise.py`): "stated_yaw", ...
STATED_FACTORS = tuple(f"stated_{d}" for d in STATED_DIRECTIONS)
FACTORS = ("odom_noise_scale", "misclassification", *STATED_FACTORS)
# Valid ranges (`pipeline/settings.py`); the sweep files' comments say the same.
FACTOR_RANGES = {
    "odom_noise_scale": settings.number_type(float, settings.within(0.0, MAX_NOISE_SCALE)),
    "misclassification": settings.number_type(float, settings.UNIT),  # a rate, not a percentage
    **{
        f: settings.number_type(float, settings.within(1.0 / MAX_FACTOR, MAX_FACTOR))
        for f in STATED_FACTORS
    },
}
SEED = settings.number_type(int, settings.within(0, 2**32 - 1))
SEED_COUNT = settings.number_type(int, settings.within(1, 10**4))
NUM_CLASSES = settings.number_type(int, settings.within(1, 1000))
FACTOR_LABELS = {
    "odom_noise_scale": "odometry noise scale",
    "misclassification": "misclassification rate",
    **{f"stated_{d}": f"{d} stated (variance factor)" for d in STATED_DIRECTIONS},
}
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")
_KEYS = {
    "name",
    "scenario",
    "scenario_config",
    "backend_config",
    "num_classes",
    "true_covariance",
    "seeds",
    "methods",
    "odom_noise_scale",
    "misclassification",
    "axes",
}


@dataclass(frozen=True)
class Axis:
    """One factor varied from the base cell, the other held at the base cell's value."""

    name: str
    factor: str  # one of FACTORS
    values: tuple[float, ...]


@dataclass(frozen=True)
class SweepConfig:
    name: str
    scenario: str
    scenario_config: Path | None
    backend_config: Path | None
    num_classes: int
    true_covariance: bool
    seeds: tuple[int, ...]
    methods: tuple[str, ...]
    odom_noise_scale: float  # the base cell
    misclassification: float
    axes: tuple[Axis, ...]
    fingerprint: str  # what decides a run's result besides its cell, seed and method


def stated_direction(factor: str) -> str:
    """The direction a stated-noise factor names: "stated_yaw" -> "yaw"."""
    return factor.removeprefix("stated_")


def _fail(path: Path, message: str) -> InputError:
    return InputError(f"config {path}: {message}")


def _number(value: Any, path: Path, key: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise _fail(path, f"'{key}' must be a finite number, got {value!r}")
    return float(value)


def _integer(value: Any, path: Path, key: str, valid: mi.Type) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise _fail(path, f"'{key}' must be an integer, got {value!r}")
    settings.check_range(value, valid, path, key)
    return value


def _factor_value(factor: str, value: Any, path: Path, key: str) -> float:
    number = _number(value, path, key)
    settings.check_range(number, FACTOR_RANGES[factor], path, key)
    return number


def _seeds(value: Any, path: Path) -> tuple[int, ...]:
    if isinstance(value, list):
        if not value:
            raise _fail(path, "'seeds' must not be empty")
        seeds = tuple(_integer(v, path, f"seeds[{i}]", SEED) for i, v in enumerate(value))
        if len(set(seeds)) != len(seeds):
            raise _fail(path, "'seeds' lists a seed twice")
        return seeds
    return tuple(range(_integer(value, path, "seeds", SEED_COUNT)))


def _methods(value: Any, path: Path) -> tuple[str, ...]:
    known = METHODS
    if not isinstance(value, list) or not value:
        raise _fail(path, f"'methods' must be a non-empty list of {', '.join(known)}")
    for i, method in enumerate(value):
        if method not in known:
            raise _fail(path, f"'methods[{i}]': unknown method {method!r}; use {', '.join(known)}")
    if len(set(value)) != len(value):
        raise _fail(path, "'methods' lists a method twice")
    return tuple(value)


def _axes(value: Any, path: Path) -> tuple[Axis, ...]:
    if not isinstance(value, list):
        raise _fail(path, "'axes' must be an array of tables ([[axes]])")
    axes = []
    for i, table in enumerate(value):
        where = f"axes[{i}]"
        if not isinstance(table, dict):
            raise _fail(path, f"'{where}' must be a table")
        axis = settings.build(Axis, table, path, f"{where}.")  # keys and types
        if not _NAME.match(axis.name):
            raise _fail(path, f"'{where}.name' must be a plain name (letters, digits, _ . -)")
        if axis.factor not in FACTORS:
            raise _fail(path, f"'{where}.factor' must be one of {', '.join(FACTORS)}")
        if not axis.values:
            raise _fail(path, f"'{where}.values' must not be empty")
        for k, v in enumerate(axis.values):
            _factor_value(axis.factor, v, path, f"{where}.values[{k}]")
        if len(set(axis.values)) != len(axis.values):
            raise _fail(path, f"'{where}.values' lists a value twice")
        axes.append(axis)
    if len({a.name for a in axes}) != len(axes):
        raise _fail(path, "two axes have the same name")
    return tuple(axes)


def _path(value: Any, path: Path, key: str) -> Path:
    if not isinstance(value, str) or not value:
        raise _fail(path, f"'{key}' must be a file name")
    resolved = (path.parent / value).resolve()
    if not resolved.is_file():
        raise _fail(path, f"'{key}': no such file {resolved}")
    return resolved


def _scenario_config(scenario: str, override: Path | None) -> Any:
    """The scenario's config (its loader checks the override file)."""
    return load_config(scenario, override)


def fingerprint(
    scenario: str, scenario_config: Any, backend_config: Any, num_classes: int, true_cov: bool
) -> str:
    """A digest of everything besides cell, seed and method that decides a run's result."""
    text = repr((scenario, scenario_config, backend_config, num_classes, true_cov))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def load_sweep_config(path: str | Path) -> SweepConfig:
    """Read and check a sweep config, and the scenario and back-end configs it names."""
    from pipeline.config import load_config

    path = Path(path)
    table = settings.read_toml(path)
    unknown = sorted(set(table) - _KEYS)
    if unknown:
        raise _fail(path, f"unknown key '{unknown[0]}'")
    for key in ("scenario", "seeds", "methods"):
        if key not in table:
            raise _fail(path, f"missing key '{key}'")
    scenario = table["scenario"]
    if scenario not in SCENARIOS:
        raise _fail(path, f"unknown scenario {scenario!r}; choose one of {', '.join(SCENARIOS)}")
    name = table.get("name", path.stem)
    if not isinstance(name, str) or not _NAME.match(name):
        raise _fail(path, "'name' must be a plain name (letters, digits, _ . -)")
    scenario_path = (
        _path(table["scenario_config"], path, "scenario_config")
        if "scenario_config" in table
        else None
    )
    backend_path = (
        _path(table["backend_config"], path, "backend_config")
        if "backend_config" in table
        else None
    )
    scenario_config = _scenario_config(scenario, scenario_path)
    backend_config = load_config(backend_path)
    num_classes = _integer(
        table.get("num_classes", scenario_config.num_classes), path, "num_classes", NUM_CLASSES
    )
    true_covariance = table.get("true_covariance", False)
    if not isinstance(true_covariance, bool):
        raise _fail(path, f"'true_covariance' must be true or false, got {true_covariance!r}")
    noise = _factor_value(
        "odom_noise_scale",
        table.get("odom_noise_scale", scenario_config.odometry.default_noise_scale),
        path,
        "odom_noise_scale",
    )
    alpha = _factor_value(
        "misclassification", table.get("misclassification", 0.0), path, "misclassification"
    )
    axes = _axes(table.get("axes", []), path)
    rates = [alpha] + [v for a in axes if a.factor == "misclassification" for v in a.values]
    if num_classes == 1 and any(rate > 0 for rate in rates):
        raise _fail(path, "a misclassification rate above 0 needs num_classes of at least 2")
    return SweepConfig(
        name=name,
        scenario=scenario,
        scenario_config=scenario_path,
        backend_config=backend_path,
        num_classes=num_classes,
        true_covariance=true_covariance,
        seeds=_seeds(table["seeds"], path),
        methods=_methods(table["methods"], path),
        odom_noise_scale=noise,
        misclassification=alpha,
        axes=axes,
        fingerprint=fingerprint(
            scenario, scenario_config, backend_config, num_classes, true_covariance
        ),
    )


def with_seeds(config: SweepConfig, count: int) -> SweepConfig:
    """The sweep with seeds 0..count-1 instead of its own (`--seeds`); the seeds are not part
    of the fingerprint, so a folder's runs are kept and more seeds add to them."""
    if isinstance(count, bool) or not isinstance(count, int) or count < 1:
        raise InputError(f"--seeds must be an integer of at least 1, got {count!r}")
    return replace(config, seeds=tuple(range(count)))


# --- the copy kept in the output folder, read back by the report ------------------------------


def to_json(config: SweepConfig, code_versions: tuple[str, ...] = ()) -> str:
    """The resolved config, and the versions of mmslam that made the runs (by `git describe`)."""
    table = {
        "name": config.name,
        "scenario": config.scenario,
        "scenario_config": str(config.scenario_config) if config.scenario_config else None,
        "backend_config": str(config.backend_config) if config.backend_config else None,
        "num_classes": config.num_classes,
        "true_covariance": config.true_covariance,
        "seeds": list(config.seeds),
        "methods": list(config.methods),
        "odom_noise_scale": config.odom_noise_scale,
        "misclassification": config.misclassification,
        "axes": [
            {"name": a.name, "factor": a.factor, "values": list(a.values)} for a in config.axes
        ],
        "fingerprint": config.fingerprint,
        "code_versions": list(code_versions),
    }
    return json.dumps(table, indent=2) + "\n"


def code_versions_of(text: str) -> tuple[str, ...]:
    """The code versions recorded by `to_json` (none in a hand-made copy)."""
    try:
        return tuple(str(v) for v in json.loads(text).get("code_versions", []))
    except (ValueError, AttributeError, TypeError):
        return ()


def from_json(text: str, source: Path) -> SweepConfig:
    """The copy written by `to_json` (already checked when it was written)."""
    try:
        t = json.loads(text)
        return SweepConfig(
            name=t["name"],
            scenario=t["scenario"],
            scenario_config=Path(t["scenario_config"]) if t["scenario_config"] else None,
            backend_config=Path(t["backend_config"]) if t["backend_config"] else None,
            num_classes=int(t["num_classes"]),
            true_covariance=bool(t["true_covariance"]),
            seeds=tuple(int(s) for s in t["seeds"]),
            methods=tuple(t["methods"]),
            odom_noise_scale=float(t["odom_noise_scale"]),
            misclassification=float(t["misclassification"]),
            axes=tuple(
                Axis(a["name"], a["factor"], tuple(float(v) for v in a["values"]))
                for a in t["axes"]
            ),
            fingerprint=t["fingerprint"],
        )
    except (ValueError, KeyError, TypeError) as exc:
        raise InputError(f"{source}: not a sweep description ({exc!r})") from None
