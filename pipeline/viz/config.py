"""Typed viewing configuration: defaults in configs/viz.toml (`[viz]`), overridden by a file.

Each setting's valid range is declared beside it (`pipeline/settings.py`) and checked at load.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from pipeline import settings
from pipeline.settings import POSITIVE, PROBABILITY, at_least, between, setting


@dataclass(frozen=True)
class VizConfig:
    refresh_every: int = setting(at_least(1))
    refresh_move_m: float = setting(at_least(0.0))
    keyframe_marginals: bool
    final_marginals: bool
    ellipsoid_confidence: float = setting(PROBABILITY)
    image_every: int = setting(at_least(0))
    jpeg_quality: int = setting(between(1, 100))
    robot_axis_length_m: float = setting(POSITIVE)
    smoothing_window: int = setting(at_least(1))
    plot_window: int = setting(at_least(0))
    warn_changes_at_once: int = setting(at_least(1))
    warn_changes_per_detection: int = setting(at_least(1))


@dataclass(frozen=True)
class _VizFile:
    viz: VizConfig


def load_viz_config(path: str | Path | None = None) -> VizConfig:
    """The defaults, with the `[viz]` keys of `path` (if given) put over them."""
    return settings.load(_VizFile, settings.config_path("viz.toml"), path).viz
