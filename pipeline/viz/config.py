"""Typed viewing configuration: defaults in configs/viz.toml (`[viz]`), overridden by a file."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from pipeline import settings
from pipeline.errors import InputError


@dataclass(frozen=True)
class VizConfig:
    refresh_every: int
    refresh_move_m: float
    keyframe_marginals: bool
    final_marginals: bool
    ellipsoid_confidence: float
    image_every: int
    jpeg_quality: int
    robot_axis_length_m: float
    smoothing_window: int
    warn_changes_at_once: int
    warn_changes_per_detection: int


@dataclass(frozen=True)
class _VizFile:
    viz: VizConfig


def load_viz_config(path: str | Path | None = None) -> VizConfig:
    """The defaults, with the `[viz]` keys of `path` (if given) put over them."""
    default = settings.config_path("viz.toml")
    config = settings.load(_VizFile, default, path).viz
    _check(config, Path(path) if path is not None else default)
    return config


def _check(config: VizConfig, path: Path) -> None:
    if config.refresh_every < 1:
        raise InputError(f"config {path}: viz.refresh_every must be >= 1")
    if config.refresh_move_m < 0:
        raise InputError(f"config {path}: viz.refresh_move_m must not be negative")
    if not 0.0 < config.ellipsoid_confidence < 1.0:
        raise InputError(f"config {path}: viz.ellipsoid_confidence must be in (0, 1)")
    if config.image_every < 0:
        raise InputError(f"config {path}: viz.image_every must not be negative")
    if not 1 <= config.jpeg_quality <= 100:
        raise InputError(f"config {path}: viz.jpeg_quality must be in 1..100")
    if config.robot_axis_length_m <= 0:
        raise InputError(f"config {path}: viz.robot_axis_length_m must be positive")
    for key in ("smoothing_window", "warn_changes_at_once", "warn_changes_per_detection"):
        if getattr(config, key) < 1:
            raise InputError(f"config {path}: viz.{key} must be >= 1")
