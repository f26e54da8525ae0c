"""Typed viewing configuration: defaults in configs/viz.toml (`[viz]`), overridden by a file.

Each setting's type and valid range are declared beside it (`pipeline/settings.py`) and
checked at load.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

from pipeline import settings
from pipeline.settings import PROBABILITY, positive, within

Every = Annotated[int, within(1, 10**6)]


@dataclass(frozen=True)
class VizConfig:
    refresh_every: Every
    refresh_move_m: Annotated[float, within(0.0, 1e6)]
    keyframe_marginals: bool
    final_marginals: bool
    ellipsoid_confidence: Annotated[float, PROBABILITY]
    image_every: Annotated[int, within(0, 10**6)]
    jpeg_quality: Annotated[int, within(1, 100)]
    robot_axis_length_m: Annotated[float, positive(1000.0)]
    smoothing_window: Every
    plot_window: Annotated[int, within(0, 10**6)]
    warn_changes_at_once: Every
    warn_changes_per_detection: Every


@dataclass(frozen=True)
class _VizFile:
    viz: VizConfig


def load_viz_config(path: str | Path | None = None) -> VizConfig:
    """The defaults, with the `[viz]` keys of `path` (if given) put over them."""
    return settings.load(_VizFile, settings.config_path("viz.toml"), path).viz
