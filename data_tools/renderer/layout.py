"""The block layout: a loop of streets (or corridors) around a rectangular block.

World frame: z up, the block centred at the origin. The loop's centre line is a rectangle of
`block_length` x `block_width`; the street (`street_width`) runs between the block's walls
(facing out) and the outer walls (facing in). Tags hang on the walls, objects stand along them,
clear of the path.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from data_tools.renderer import textures
from data_tools.renderer.config import RendererConfig
from data_tools.renderer.path import Motion
from data_tools.renderer.scene import (
    TAG36H11_COUNT,
    TAG_CELLS,
    TAG_MARGIN_CELLS,
    BoxObject,
    Scene,
    Surface,
    Tag,
    Texture,
    cuboid_surfaces,
    facing_surface,
    tag_surface,
)
from pipeline.errors import InputError

log = logging.getLogger(__name__)

# Landmark ids of objects start here, clear of the tag ids (tag36h11: 0..586).
OBJECT_ID_BASE = 1000
UP = np.array([0.0, 0.0, 1.0])
# Tags stand this far proud of their wall (no depth fighting with it).
TAG_STANDOFF = 0.005


@dataclass(frozen=True)
class Wall:
    """A wall's foot from `start` to `end` (2-D), its front facing `normal` (into the street)
    and `travel`, the direction the vehicle passes it in."""

    start: np.ndarray
    end: np.ndarray
    normal: np.ndarray
    travel: np.ndarray
    inner: bool

    @property
    def length(self) -> float:
        return float(np.linalg.norm(self.end - self.start))

    @property
    def direction(self) -> np.ndarray:
        return (self.end - self.start) / self.length


def motion_from_config(config: RendererConfig) -> Motion:
    drive = config.path
    return Motion(
        half_length=config.scene.block_length / 2 - drive.lane_offset,
        half_width=config.scene.block_width / 2 - drive.lane_offset,
        drive=drive,
    )


def block_walls(block_length: float, block_width: float, street_width: float) -> list[Wall]:
    """The block's four walls (facing out) and the four outer walls (facing in); outer walls
    run on past the corners so that they overlap instead of leaving a gap."""
    half_street = street_width / 2
    walls = []
    for inner in (True, False):
        grow = -half_street if inner else half_street
        hx, hy = block_length / 2 + grow, block_width / 2 + grow
        extra = 0.0 if inner else 0.5
        # Counter-clockwise sides: lower, right, upper, left.
        sides = [
            ((-hx - extra, -hy), (hx + extra, -hy), (0.0, -1.0)),
            ((hx, -hy - extra), (hx, hy + extra), (1.0, 0.0)),
            ((hx + extra, hy), (-hx - extra, hy), (0.0, 1.0)),
            ((-hx, hy + extra), (-hx, -hy - extra), (-1.0, 0.0)),
        ]
        for start, end, outward in sides:
            outward = np.array(outward)
            travel = (np.array(end) - np.array(start)) / np.linalg.norm(np.subtract(end, start))
            normal = outward if inner else -outward
            walls.append(Wall(np.array(start), np.array(end), normal, travel, inner))
    return walls


def _pieces(length: float, piece: float) -> list[tuple[float, float]]:
    """(start, length) of equal pieces no longer than `piece` covering [0, length]."""
    count = max(1, math.ceil(length / piece))
    return [(i * length / count, length / count) for i in range(count)]


def wall_surfaces(walls: list[Wall], config: RendererConfig, rng: np.random.Generator):
    scene = config.scene
    surfaces = []
    for wall in walls:
        normal = np.append(wall.normal, 0.0)
        for start, length in _pieces(wall.length, scene.segment_length):
            foot = wall.start + wall.direction * (start + length / 2)
            centre = np.array([foot[0], foot[1], scene.wall_height / 2])
            if scene.style == "street":
                image = textures.facade(rng, length, scene.wall_height, scene.wall_texels_per_metre)
            else:
                image = textures.clutter(
                    rng, length, scene.wall_height, scene.wall_texels_per_metre, 170.0, 10.0
                )
            surfaces.append(
                facing_surface(
                    centre, normal, UP, length, scene.wall_height, Texture.from_image(image)
                )
            )
    return surfaces


def floor_rectangles(config: RendererConfig) -> list[tuple[float, float, float, float]]:
    """(x0, y0, x1, y1) strips covering the streets, reaching half a metre under the walls."""
    scene = config.scene
    hx, hy, hs = scene.block_length / 2, scene.block_width / 2, scene.street_width / 2
    m = 0.5
    return [
        (-hx - hs - m, -hy - hs - m, hx + hs + m, -hy + hs + m),
        (-hx - hs - m, hy - hs - m, hx + hs + m, hy + hs + m),
        (-hx - hs - m, -hy + hs + m, -hx + hs + m, hy - hs - m),
        (hx - hs - m, -hy + hs + m, hx + hs + m, hy - hs - m),
    ]


def floor_surfaces(config: RendererConfig, rng: np.random.Generator) -> list[Surface]:
    """Floor pieces (and ceiling pieces for corridors), cut along each strip's long side."""
    scene = config.scene
    surfaces = []
    levels = [(0.0, UP)] + ([(scene.wall_height, -UP)] if scene.ceiling else [])
    for x0, y0, x1, y1 in floor_rectangles(config):
        along_x = (x1 - x0) >= (y1 - y0)
        long_side, short_side = (x1 - x0, y1 - y0) if along_x else (y1 - y0, x1 - x0)
        axis = np.array([1.0, 0.0, 0.0]) if along_x else np.array([0.0, 1.0, 0.0])
        for height, normal in levels:
            for start, length in _pieces(long_side, scene.segment_length):
                middle = (
                    (x0 + start + length / 2, (y0 + y1) / 2)
                    if along_x
                    else ((x0 + x1) / 2, y0 + start + length / 2)
                )
                centre = np.array([middle[0], middle[1], height])
                tpm = scene.floor_texels_per_metre
                if scene.style == "street" and height == 0.0:
                    image = textures.asphalt(rng, short_side, length, tpm)
                else:
                    base = 125.0 if height == 0.0 else 205.0
                    image = textures.clutter(rng, short_side, length, tpm, base, 6.0)
                # Texture rows run along the strip ("up" = its long axis).
                surfaces.append(
                    facing_surface(
                        centre, normal, axis, short_side, length, Texture.from_image(image)
                    )
                )
    return surfaces


def place_tags(walls: list[Wall], config: RendererConfig, rng: np.random.Generator) -> list[Tag]:
    """Tags at random places on the walls, each turned towards oncoming traffic by a random
    angle (0 = flat on the wall, like a poster; larger = a sign sticking out)."""
    tags_config = config.tags
    if tags_config.count == 0:
        return []
    ids = rng.choice(TAG36H11_COUNT, size=tags_config.count, replace=False)
    lengths = np.array([w.length for w in walls])
    margin = tags_config.size
    placed: list[tuple[int, float]] = []
    tags = []
    attempts = 0
    while len(tags) < tags_config.count:
        attempts += 1
        if attempts > 200 * tags_config.count:
            raise InputError(
                f"renderer: cannot place {tags_config.count} tags {tags_config.min_spacing} m "
                "apart; lower tags.count or tags.min_spacing"
            )
        index = int(rng.choice(len(walls), p=lengths / lengths.sum()))
        wall = walls[index]
        along = rng.uniform(margin, wall.length - margin)
        if any(i == index and abs(a - along) < tags_config.min_spacing for i, a in placed):
            continue
        placed.append((index, along))
        turn = math.radians(rng.uniform(tags_config.turn_min_deg, tags_config.turn_max_deg))
        facing = math.cos(turn) * wall.normal - math.sin(turn) * wall.travel
        # Stand the tag off so that its far edge stays in front of the wall.
        total = tags_config.size * (TAG_CELLS + 2 * TAG_MARGIN_CELLS) / TAG_CELLS
        standoff = TAG_STANDOFF + total / 2 * math.sin(turn)
        foot = wall.start + wall.direction * along + wall.normal * standoff
        centre = np.array(
            [foot[0], foot[1], rng.uniform(tags_config.height_min, tags_config.height_max)]
        )
        z_axis = -np.append(facing, 0.0)
        y_axis = -UP
        rotation = np.column_stack([np.cross(y_axis, z_axis), y_axis, z_axis])
        tags.append(Tag(int(ids[len(tags)]), tags_config.size, centre, rotation))
    return tags


def place_objects(
    walls: list[Wall], path_xy: np.ndarray, config: RendererConfig, rng: np.random.Generator
) -> list[BoxObject]:
    """Objects lined up along the walls (parked cars, crates), clear of the path and of each
    other, kept out of the crossings where the walls end."""
    spec = config.objects
    size = np.array([spec.length, spec.width, spec.height])
    lengths = np.array([w.length for w in walls])
    objects: list[BoxObject] = []
    attempts = 0
    while len(objects) < spec.count:
        attempts += 1
        if attempts > 500 * max(spec.count, 1):
            raise InputError(
                f"renderer: cannot place {spec.count} objects clear of the path; lower "
                "objects.count or objects.path_clearance"
            )
        wall = walls[int(rng.choice(len(walls), p=lengths / lengths.sum()))]
        # Outer walls run across the crossings: keep a street's width off their ends.
        margin = spec.length / 2 + (0.5 if wall.inner else config.scene.street_width + 0.5)
        if wall.length <= 2 * margin:
            continue
        along = rng.uniform(margin, wall.length - margin)
        foot = wall.start + wall.direction * along
        centre_xy = foot + wall.normal * (spec.wall_gap + spec.width / 2)
        clearance = np.min(np.linalg.norm(path_xy - centre_xy, axis=1)) - spec.width / 2
        if clearance < spec.path_clearance:
            continue
        if any(np.linalg.norm(o.centre[:2] - centre_xy) < spec.length + 0.8 for o in objects):
            continue
        yaw = math.atan2(wall.direction[1], wall.direction[0]) + rng.normal(0.0, 0.05)
        if rng.random() < 0.5:
            yaw += math.pi
        c, s = math.cos(yaw), math.sin(yaw)
        rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        centre = np.array([centre_xy[0], centre_xy[1], spec.height / 2])
        objects.append(
            BoxObject(
                OBJECT_ID_BASE + len(objects), spec.class_name, centre, rotation, size, spec.style
            )
        )
    return objects


def object_surfaces(obj: BoxObject, texels_per_metre: float, rng: np.random.Generator):
    """A car is a body box and a cabin box; a crate one box. No bottom faces (on the floor)."""
    length, width, height = obj.size
    if obj.style == "crate":
        images = textures.crate_textures(rng, (length, width, height), texels_per_metre)
        faces = {name: Texture.from_image(image) for name, image in images.items()}
        return cuboid_surfaces(obj.centre, obj.rotation, obj.size, faces, obj.landmark_id)
    body_height = 0.62 * height
    cabin = (0.55 * length, 0.9 * width, height - body_height)
    body_images, cabin_images = textures.car_textures(
        rng, length, width, body_height, cabin, texels_per_metre
    )
    ground = obj.centre - obj.rotation @ np.array([0.0, 0.0, height / 2])
    body_centre = ground + obj.rotation @ np.array([0.0, 0.0, body_height / 2])
    cabin_centre = ground + obj.rotation @ np.array(
        [-0.08 * length, 0.0, body_height + cabin[2] / 2]
    )
    body = {name: Texture.from_image(image) for name, image in body_images.items()}
    top = {name: Texture.from_image(image) for name, image in cabin_images.items()}
    return cuboid_surfaces(
        body_centre, obj.rotation, np.array([length, width, body_height]), body, obj.landmark_id
    ) + cuboid_surfaces(cabin_centre, obj.rotation, np.array(cabin), top, obj.landmark_id)


def check_path_clearance(walls: list[Wall], path_xy: np.ndarray, clearance: float) -> None:
    """Refuse a path that comes closer than `clearance` to a wall (or goes through one)."""
    for wall in walls:
        relative = path_xy - wall.start
        along = relative @ wall.direction
        across = relative @ wall.normal
        beside = (along > 0) & (along < wall.length)
        if np.any(beside & (np.abs(across) < clearance)):
            raise InputError(
                f"renderer: the path passes within {clearance} m of a wall; reduce "
                "path.corner_radius or path.lane_offset, or widen the street"
            )


def place_landmarks(
    config: RendererConfig, walls: list[Wall], path_xy: np.ndarray, seed: int
) -> tuple[list[Tag], list[BoxObject]]:
    """The tags and objects of a scene, from their own random stream (not the textures')."""
    layout_rng = np.random.default_rng([seed, 0])
    tags = place_tags(walls, config, layout_rng)
    return tags, place_objects(walls, path_xy, config, layout_rng)


def build_scene(config: RendererConfig, path_xy: np.ndarray, seed: int) -> Scene:
    """Walls, floor (and ceiling), tags and objects of the block, from a preset and the path.

    Placement and textures draw from separate random streams, so that presets differing only
    in resolution or texture density (demo, kitti-size) share the same landmarks.
    """
    scene = config.scene
    walls = block_walls(scene.block_length, scene.block_width, scene.street_width)
    check_path_clearance(walls, path_xy, 1.0)
    tags, objects = place_landmarks(config, walls, path_xy, seed)
    texture_rng = np.random.default_rng([seed, 1])
    surfaces = wall_surfaces(walls, config, texture_rng) + floor_surfaces(config, texture_rng)
    surfaces += [tag_surface(tag) for tag in tags]
    for obj in objects:
        surfaces += object_surfaces(obj, scene.object_texels_per_metre, texture_rng)
    sky = (205.0, 160.0) if scene.style == "street" else (128.0, 128.0)
    log.info("scene: %d surfaces, %d tags, %d objects", len(surfaces), len(tags), len(objects))
    return Scene(tuple(surfaces), tuple(tags), tuple(objects), sky)
