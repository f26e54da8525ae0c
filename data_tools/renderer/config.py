"""Renderer presets: `configs/renderer/<name>.toml` loaded into frozen dataclasses.

Every key must be present and of the right type; the meaning of each is commented in the
preset files.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from pipeline import settings
from pipeline.errors import InputError

PRESET_DIR = settings.CONFIG_DIR / "renderer"
INSTALLED_PRESET_DIR = settings.INSTALLED_CONFIG_DIR / "renderer"

STYLES = ("street", "corridor")
OBJECT_STYLES = ("car", "crate")


@dataclass(frozen=True)
class CameraConfig:
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    baseline: float
    frame_rate: float
    supersample: int
    noise_sigma: float


@dataclass(frozen=True)
class SceneConfig:
    style: str
    block_length: float
    block_width: float
    street_width: float
    wall_height: float
    ceiling: bool
    segment_length: float
    wall_texels_per_metre: float
    floor_texels_per_metre: float
    object_texels_per_metre: float


@dataclass(frozen=True)
class TagConfig:
    count: int
    size: float
    height_min: float
    height_max: float
    turn_min_deg: float
    turn_max_deg: float
    min_spacing: float


@dataclass(frozen=True)
class ObjectConfig:
    count: int
    class_name: str
    style: str
    length: float
    width: float
    height: float
    wall_gap: float
    path_clearance: float


@dataclass(frozen=True)
class PathConfig:
    lane_offset: float
    corner_radius: float
    laps: float
    speed: float
    max_yaw_rate: float
    max_acceleration: float
    camera_height: float
    weave_amplitude: float
    weave_wavelength: float
    sway_amplitude: float


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

    cam, scene, tags, objects, drive = (
        config.camera,
        config.scene,
        config.tags,
        config.objects,
        config.path,
    )
    require(cam.width > 0 and cam.height > 0, "camera width and height must be positive")
    require(cam.fx > 0 and cam.fy > 0, "camera focal lengths must be positive")
    require(cam.baseline > 0 and cam.frame_rate > 0, "baseline and frame_rate must be positive")
    require(1 <= cam.supersample <= 4, "camera.supersample must be 1..4")
    require(cam.noise_sigma >= 0, "camera.noise_sigma must be >= 0")
    require(scene.style in STYLES, f"scene.style must be one of {STYLES}")
    require(
        min(scene.block_length, scene.block_width) > scene.street_width > 0,
        "the block must be longer and wider than the street",
    )
    require(scene.wall_height > drive.camera_height > 0, "the camera must be below the walls")
    require(scene.segment_length > 0, "scene.segment_length must be positive")
    require(
        min(
            scene.wall_texels_per_metre,
            scene.floor_texels_per_metre,
            scene.object_texels_per_metre,
        )
        > 0,
        "texel densities must be positive",
    )
    require(
        max(scene.wall_texels_per_metre, scene.floor_texels_per_metre) * scene.segment_length
        < 20000,
        "segment_length * texels_per_metre must stay under 20000 texels (OpenCV's limit)",
    )
    require(0 <= tags.count <= 587, "tags.count must be 0..587 (the tag36h11 family)")
    require(tags.size > 0 and tags.min_spacing > 0, "tag size and spacing must be positive")
    require(
        0 <= tags.height_min <= tags.height_max <= scene.wall_height - tags.size,
        "tag heights must lie on the walls",
    )
    require(0 <= tags.turn_min_deg <= tags.turn_max_deg < 90, "tag turns must be in [0, 90)")
    require(objects.count >= 0, "objects.count must be >= 0")
    require(objects.style in OBJECT_STYLES, f"objects.style must be one of {OBJECT_STYLES}")
    require(min(objects.length, objects.width, objects.height) > 0, "object sizes must be positive")
    require(drive.laps > 0 and drive.speed > 0, "path laps and speed must be positive")
    require(drive.max_yaw_rate > 0 and drive.max_acceleration > 0, "path limits must be > 0")
    require(drive.weave_wavelength > 0, "path.weave_wavelength must be positive")
    require(
        abs(drive.lane_offset) + abs(drive.weave_amplitude) < scene.street_width / 2 - 0.5,
        "the lane (offset + weave) must stay half a metre inside the street",
    )
    half = min(scene.block_length, scene.block_width) / 2 - drive.lane_offset
    require(0 < drive.corner_radius <= half, "path.corner_radius must fit the loop")
