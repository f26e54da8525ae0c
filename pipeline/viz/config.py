"""Typed viewing configuration: defaults in configs/viz.toml (`[viz]`), overridden by a file."""

from __future__ import annotations

import sys
import tomllib
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, get_type_hints

from pipeline.errors import InputError

DEFAULT_VIZ_CONFIG = Path(__file__).resolve().parents[2] / "configs" / "viz.toml"
INSTALLED_VIZ_CONFIG = Path(sys.prefix) / "share" / "mmslam" / "configs" / "viz.toml"


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


def _read(path: Path) -> dict[str, Any]:
    try:
        with open(path, "rb") as f:
            table = tomllib.load(f)
    except FileNotFoundError:
        raise InputError(f"config {path}: no such file") from None
    except OSError as exc:
        raise InputError(f"config {path}: cannot be read ({exc.strerror})") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"config {path}: not valid TOML ({exc})") from None
    unknown = set(table) - {"viz"}
    if unknown:
        raise InputError(f"config {path}: unknown table '{sorted(unknown)[0]}' (only [viz])")
    viz = table.get("viz", {})
    if not isinstance(viz, dict):
        raise InputError(f"config {path}: 'viz' must be a table")
    return viz


def load_viz_config(path: str | Path | None = None) -> VizConfig:
    """The defaults, with the `[viz]` keys of `path` (if given) put over them."""
    default_path = DEFAULT_VIZ_CONFIG if DEFAULT_VIZ_CONFIG.exists() else INSTALLED_VIZ_CONFIG
    table = _read(default_path)
    source = default_path
    if path is not None:
        source = Path(path)
        for key, value in _read(source).items():
            if key not in table:
                raise InputError(f"config {source}: unknown key 'viz.{key}'")
            table[key] = value
    hints = get_type_hints(VizConfig)
    values: dict[str, Any] = {}
    for f in fields(VizConfig):
        if f.name not in table:
            raise InputError(f"config {source}: missing key 'viz.{f.name}'")
        value, kind = table[f.name], hints[f.name]
        accepted = (int, float) if kind is float else (kind,)
        if isinstance(value, bool) is not (kind is bool) or not isinstance(value, accepted):
            raise InputError(
                f"config {source}: 'viz.{f.name}' must be {kind.__name__}, got {value!r}"
            )
        values[f.name] = kind(value)
    config = VizConfig(**values)
    _check(config, source)
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
