"""Built-in scenarios: contract-v1 logs with ground truth, to drive and judge the back-end.

`simulate("indoor-tags" | "kitti05-cars", out, ...)` writes a log and returns its figures.
Defaults live in `configs/scenarios/<name>.toml`; see `noise.py` for the noise models.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from data_tools.scenarios import city_grid, indoor_tags, kitti05_cars, planar_park
from data_tools.scenarios.common import SimulationOptions
from data_tools.scenarios.config import MAX_NOISE_SCALE, CheckedConfig, load_checked
from data_tools.scenarios.writing import (
    SimulationSummary,
    restated,
    source_text,
    summarise,
    write_log,
)
from data_tools.stated_noise import StatedNoise
from pipeline.errors import InputError

_MODULES = {
    indoor_tags.NAME: indoor_tags,
    kitti05_cars.NAME: kitti05_cars,
    city_grid.NAME: city_grid,
    planar_park.NAME: planar_park,
}
SCENARIOS: tuple[str, ...] = tuple(_MODULES)
# Each scenario's config: the defaults in configs/scenarios/<name>.toml read as these.
_CONFIGS: dict[str, type[CheckedConfig]] = {
    indoor_tags.NAME: indoor_tags.IndoorTagsConfig,
    kitti05_cars.NAME: kitti05_cars.Kitti05CarsConfig,
    city_grid.NAME: city_grid.CityGridConfig,
    planar_park.NAME: planar_park.PlanarParkConfig,
}


def load_config(scenario: str, path: Path | None = None) -> Any:
    """The config of `scenario`: its defaults, with the keys of `path` (if given) put over
    them, checked."""
    return load_checked(_CONFIGS[scenario], scenario, path)


__all__ = [
    "MAX_NOISE_SCALE",
    "SCENARIOS",
    "SimulationOptions",
    "SimulationSummary",
    "load_config",
    "simulate",
]


def noise_truth(
    scenario: str,
    config_path: Path | None,
    odom_noise_scale: float,
    true_covariance: bool,
    stated: StatedNoise | None = None,
) -> dict[str, float]:
    """What a scenario's log understates, per direction: the variance of the noise drawn over
    the variance the log states (above 1: understated), for the odometry's directions
    (`ODOMETRY_AXES`) and the detections' components; what a learnt scale should come to.
    indoor-tags, kitti05-cars and city-grid state each detection's covariance as drawn;
    planar-park has no such truth (its odometry drifts by a bias, its bearing is overstated on
    purpose) and is refused."""
    if scenario == "planar-park":
        raise InputError("planar-park's odometry drifts by a bias: no per-direction noise truth")
    from data_tools.scenarios.noise import odometry_covariances
    from pipeline.backend.noise import MEASUREMENT_COMPONENTS, ODOMETRY_AXES

    stated = stated or StatedNoise()
    config = load_config(scenario, config_path)
    calibrated, true = odometry_covariances(config.odometry, odom_noise_scale)
    written = np.diag(true if true_covariance else calibrated) * np.array(stated.odometry)
    odometry = np.diag(true) / written
    detections = 1.0 / np.array(stated.detections)
    return {
        **dict(zip(ODOMETRY_AXES, odometry.tolist(), strict=True)),
        **dict(zip(MEASUREMENT_COMPONENTS, detections.tolist(), strict=True)),
    }


def _number(name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise InputError(f"{name} must be a finite number, got {value!r}")
    return float(value)


def simulate(
    scenario: str,
    out: Path,
    *,
    seed: int = 0,
    odom_noise_scale: float | None = None,
    misclassification: float = 0.0,
    num_classes: int | None = None,
    true_covariance: bool = False,
    config_path: Path | None = None,
    foxglove: bool = True,
    stated: StatedNoise | None = None,
) -> SimulationSummary:
    """Write the log of `scenario` to `out` (atomically) and return what it holds.

    `seed` draws all noise (same seed, same bytes); the world itself comes from the config.
    `odom_noise_scale` multiplies the paper's added odometry noise (default: the config's);
    `misclassification` is the detector's alpha (1 - alpha on the confusion matrix's diagonal);
    `num_classes` defaults to the config's; `true_covariance` writes the odometry covariance
    of the noise actually drawn instead of the calibrated model's; `stated` scales what the
    log states beyond that, per direction (`data_tools.stated_noise`); `foxglove` adds
    Foxglove's well-known messages beside the contract's.
    """
    if scenario not in _MODULES:
        raise InputError(f"unknown scenario {scenario!r}; choose one of {', '.join(SCENARIOS)}")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise InputError(f"--seed must be a non-negative integer, got {seed!r}")
    alpha = _number("--misclassification", misclassification)
    if not 0.0 <= alpha <= 1.0:
        raise InputError(f"--misclassification must be within 0..1, got {alpha:g}")
    module = _MODULES[scenario]
    config = load_config(scenario, config_path)
    if odom_noise_scale is None:
        odom_noise_scale = config.odometry.default_noise_scale
    scale = _number("--odom-noise-scale", odom_noise_scale)
    if not 0 <= scale <= MAX_NOISE_SCALE:
        raise InputError(f"--odom-noise-scale must be within 0..{MAX_NOISE_SCALE:g}, got {scale:g}")
    classes = config.num_classes if num_classes is None else num_classes
    if isinstance(classes, bool) or not isinstance(classes, int) or classes < 1:
        raise InputError(f"--num-classes must be an integer >= 1, got {classes!r}")
    if classes == 1 and alpha > 0.0:
        raise InputError("--misclassification needs --num-classes of at least 2")
    options = SimulationOptions(
        seed=seed,
        odom_noise_scale=scale,
        misclassification=alpha,
        num_classes=classes,
        true_covariance=bool(true_covariance),
        stated=stated or StatedNoise(),
    )
    run = restated(module.simulate(config, options, config_path), options.stated)
    out = Path(out)
    counts = write_log(out, run, source_text(scenario, options, config_path), foxglove)
    return summarise(scenario, out, options, run, counts)
