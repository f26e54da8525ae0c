"""Renderer presets: `configs/renderer/<name>.toml` loaded into frozen dataclasses.

Every key must be present, of the right type and within its valid range (declared beside
it, checked at load); the meaning of each is commented in the preset files.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal, get_args

from pipeline import settings
from pipeline.errors import InputError
from pipeline.settings import positive, within

PRESET_DIR = settings.CONFIG_DIR / "renderer"
INSTALLED_PRESET_DIR = settings.INSTALLED_CONFIG_DIR / "renderer"

SceneStyle = Literal["street", "corridor"]
ObjectStyle = Literal["car", "crate"]
STYLES = get_args(SceneStyle)
OBJECT_STYLES = get_args(ObjectStyle)
Pixels = Annotated[int, within(1, 8192)]
Focal = Annotated[float, positive(1e5)]  # pixels
Metres = Annotated[float, positive(1e4)]
Offset = Annotated[float, within(-1e4, 1e4)]  # m, either side
Gap = Annotated[float, within(0.0, 1e4)]  # m
Texels = Annotated[float, positive(1e4)]  # per metre


@dataclass(frozen=True)
class CameraConfig:
    width: Pixels
    height: Pixels
    fx: Focal
    fy: Focal
    cx: Annotated[float, within(-1e5, 1e5)]
    cy: Annotated[float, within(-1e5, 1e5)]
    baseline: Annotated[float, positive(100.0)]  # m
    frame_rate: Annotated[float, positive(1000.0)]  # Hz
    supersample: Annotated[int, within(1, 4)]
    noise_sigma: Annotated[float, within(0.0, 255.0)]  # grey levels


@dataclass(frozen=True)
class SceneConfig:
    style: SceneStyle
    block_length: Metres
    block_width: Metres
    street_width: Metres
    wall_height: Metres
    ceiling: bool
    segment_length: Metres
    wall_texels_per_metre: Texels
    floor_texels_per_metre: Texels
    object_texels_per_metre: Texels


@dataclass(frozen=True)
class TagConfig:
    count: Annotated[int, within(0, 587)]  # the tag36h11 family
    size: Annotated[float, positive(100.0)]
    height_min: Gap
    height_max: Gap
    turn_min_deg: Annotated[float, within(0.0, 90.0, high_open=True)]
    turn_max_deg: Annotated[float, within(0.0, 90.0, high_open=True)]
    min_spacing: Metres


@dataclass(frozen=True)
class ObjectConfig:
    count: Annotated[int, within(0, 10**4)]
    class_name: str
    style: ObjectStyle
    length: Metres
    width: Metres
    height: Metres
    wall_gap: Gap
    path_clearance: Gap


@dataclass(frozen=True)
class PathConfig:
    lane_offset: Offset
    corner_radius: Metres
    laps: Annotated[float, positive(1000.0)]
    speed: Annotated[float, positive(100.0)]  # m/s
    max_yaw_rate: Annotated[float, positive(100.0)]  # rad/s
    max_acceleration: Annotated[float, positive(1000.0)]  # m/s^2
    camera_height: Metres
    weave_amplitude: Offset
    weave_wavelength: Metres
    sway_amplitude: Gap


@dataclass(frozen=True)
class RendererConfig:
    camera: CameraConfig
    scene: SceneConfig
    tags: TagConfig
    objects: ObjectConfig
    path: PathConfig


def preset_path(preset: str | Path) -> Path:
    """A preset name (`demo`) or a TOML file path to the file to read."""
    candidate = Path(preset)
    if candidate.suffix == ".toml" or candidate.exists():
        return candidate
    for folder in (PRESET_DIR, INSTALLED_PRESET_DIR):
        path = folder / f"{preset}.toml"
        if path.exists():
            return path
    names = sorted(p.stem for p in PRESET_DIR.glob("*.toml"))
    raise InputError(f"renderer preset '{preset}': not found (known: {', '.join(names)})")


def load_preset(preset: str | Path) -> RendererConfig:
    path = preset_path(preset)
    config = settings.build(RendererConfig, settings.read_toml(path), path)
    _check(config, path)
    return config


def _check(config: RendererConfig, path: Path) -> None:
    def require(condition: bool, message: str) -> None:
        settings.require(condition, path, message)

    scene, tags, drive = config.scene, config.tags, config.path
    require(
        min(scene.block_length, scene.block_width) > scene.street_width,
        "the block must be longer and wider than the street",
    )
    require(scene.wall_height > drive.camera_height, "the camera must be below the walls")
    require(
        max(scene.wall_texels_per_metre, scene.floor_texels_per_metre) * scene.segment_length
        < 20000,
        "segment_length * texels_per_metre must stay under 20000 texels (OpenCV's limit)",
    )
    require(
        tags.height_min <= tags.height_max <= scene.wall_height - tags.size,
        "tag heights must lie on the walls",
    )
    require(tags.turn_min_deg <= tags.turn_max_deg, "tags.turn_min_deg must be <= turn_max_deg")
    require(
        abs(drive.lane_offset) + abs(drive.weave_amplitude) < scene.street_width / 2 - 0.5,
        "the lane (offset + weave) must stay half a metre inside the street",
    )
    half = min(scene.block_length, scene.block_width) / 2 - drive.lane_offset
    require(drive.corner_radius <= half, "path.corner_radius must fit the loop")
