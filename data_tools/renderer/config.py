"""Renderer presets: `configs/renderer/<name>.toml` loaded into frozen dataclasses.

Every key must be present, of the right type and within its valid range (declared beside it,
checked at load); the meaning of each is commented in the preset files.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from pipeline import settings
from pipeline.errors import InputError
from pipeline.settings import ANY, POSITIVE, at_least, between, one_of, setting

PRESET_DIR = settings.CONFIG_DIR / "renderer"
INSTALLED_PRESET_DIR = settings.INSTALLED_CONFIG_DIR / "renderer"

STYLES = ("street", "corridor")
OBJECT_STYLES = ("car", "crate")


@dataclass(frozen=True)
class CameraConfig:
    width: int = setting(at_least(1))
    height: int = setting(at_least(1))
    fx: float = setting(POSITIVE)
    fy: float = setting(POSITIVE)
    cx: float = setting(ANY)
    cy: float = setting(ANY)
    baseline: float = setting(POSITIVE)
    frame_rate: float = setting(POSITIVE)
    supersample: int = setting(between(1, 4))
    noise_sigma: float = setting(at_least(0.0))


@dataclass(frozen=True)
class SceneConfig:
    style: str = setting(one_of(*STYLES))
    block_length: float = setting(POSITIVE)
    block_width: float = setting(POSITIVE)
    street_width: float = setting(POSITIVE)
    wall_height: float = setting(POSITIVE)
    ceiling: bool
    segment_length: float = setting(POSITIVE)
    wall_texels_per_metre: float = setting(POSITIVE)
    floor_texels_per_metre: float = setting(POSITIVE)
    object_texels_per_metre: float = setting(POSITIVE)


@dataclass(frozen=True)
class TagConfig:
    count: int = setting(between(0, 587))  # the tag36h11 family
    size: float = setting(POSITIVE)
    height_min: float = setting(at_least(0.0))
    height_max: float = setting(at_least(0.0))
    turn_min_deg: float = setting(between(0.0, 90.0, high_open=True))
    turn_max_deg: float = setting(between(0.0, 90.0, high_open=True))
    min_spacing: float = setting(POSITIVE)


@dataclass(frozen=True)
class ObjectConfig:
    count: int = setting(at_least(0))
    class_name: str = setting(ANY)
    style: str = setting(one_of(*OBJECT_STYLES))
    length: float = setting(POSITIVE)
    width: float = setting(POSITIVE)
    height: float = setting(POSITIVE)
    wall_gap: float = setting(at_least(0.0))
    path_clearance: float = setting(at_least(0.0))


@dataclass(frozen=True)
class PathConfig:
    lane_offset: float = setting(ANY)
    corner_radius: float = setting(POSITIVE)
    laps: float = setting(POSITIVE)
    speed: float = setting(POSITIVE)
    max_yaw_rate: float = setting(POSITIVE)
    max_acceleration: float = setting(POSITIVE)
    camera_height: float = setting(POSITIVE)
    weave_amplitude: float = setting(ANY)
    weave_wavelength: float = setting(POSITIVE)
    sway_amplitude: float = setting(at_least(0.0))


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
