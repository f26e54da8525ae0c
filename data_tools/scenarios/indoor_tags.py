"""indoor-tags: the paper's indoor AprilTag run, simulated on an office floor.

The world: a grid of corridors (`floor`), a robot route through them with loops (`route`), and
tags on the corridor walls (`tags`). It is built from the config's `world_seed` alone, so every
`--seed` sees the same world and truth; the seed draws the odometry noise, the missed
detections, the measurement noise and the reported classes.

A tag's frame: x along its outward normal (into the corridor, towards a viewer), z up, y to
the left of x. A detection gives the tag centre as bearing/elevation/range and the tag's pose
in the body frame (`relative_pose`), each drawn with the noise its covariance declares; the two
are independent draws (a back-end uses one or the other).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import numpy as np
from scipy.spatial import cKDTree

from data_tools.scenarios.common import (
    SimulatedRun,
    SimulationOptions,
    blocks,
    detection_frames,
    floats,
    lines_inside,
    noisy_odometry,
    pieces,
    reported_classes,
    truth_landmarks,
    within_reach,
)
from data_tools.scenarios.config import (
    Coordinate,
    Count,
    Distance,
    Length,
    NumClasses,
    Probability,
    Sigma,
    WorldSeed,
    require,
)
from data_tools.scenarios.geometry import (
    bearing_elevation_range,
    inside_any,
    inverse,
    pose_from_rotation_translation,
    quaternion_from_rotation,
    se3_exp,
)
from data_tools.scenarios.noise import OdometryNoiseConfig, random_streams
from data_tools.scenarios.routes import RouteConfig, check_route, drive, junction_route
from pipeline.errors import InputError
from pipeline.frontend.classes import tag_class_names
from pipeline.log import Detection, RelativePose
from pipeline.settings import within

NAME = "indoor-tags"

# Points tested along each line of sight, stopping short of the tag on the wall itself.
LINE_OF_SIGHT_SAMPLES = np.linspace(0.0, 0.97, 48)
# A floor's junctions at the most (a line of sight is tested against every corridor), and the
# route's turns at them.
MAX_JUNCTIONS = 2500
MAX_TURNS = 10**6


@dataclass(frozen=True)
class FloorConfig:
    corridor_x_m: tuple[Coordinate, ...]
    corridor_y_m: tuple[Coordinate, ...]
    corridor_width_m: Length


@dataclass(frozen=True)
class TagConfig:
    count: Count
    min_spacing_m: Distance
    height_min_m: Annotated[float, within(-100.0, 100.0)]
    height_max_m: Annotated[float, within(-100.0, 100.0)]
    junction_clearance_m: Distance


@dataclass(frozen=True)
class TagCameraConfig:
    horizontal_fov_deg: Annotated[float, within(0.0, 180.0, low_open=True, high_open=True)]
    vertical_fov_deg: Annotated[float, within(0.0, 180.0, low_open=True, high_open=True)]
    max_range_m: Length
    max_incidence_deg: Annotated[float, within(0.0, 90.0, low_open=True)]
    detection_probability: Probability


@dataclass(frozen=True)
class TagMeasurementConfig:
    sigma_bearing_rad: Sigma
    sigma_elevation_rad: Sigma
    sigma_range_m: Sigma
    relative_pose_sigma_rotation_rad: Sigma
    relative_pose_sigma_translation_m: Sigma


@dataclass(frozen=True)
class IndoorTagsConfig:
    world_seed: WorldSeed
    num_classes: NumClasses
    floor: FloorConfig
    route: RouteConfig
    tags: TagConfig
    camera: TagCameraConfig
    measurement: TagMeasurementConfig
    odometry: OdometryNoiseConfig

    def check(self, path: Path | str) -> None:
        f = self.floor
        width = f.corridor_width_m + 2 * self.tags.junction_clearance_m
        for key, axis in (("corridor_x_m", f.corridor_x_m), ("corridor_y_m", f.corridor_y_m)):
            require(len(axis) >= 2, path, f"'floor.{key}' needs at least two corridors")
            increasing = bool(np.all(np.diff(axis) > 0))
            require(increasing, path, f"'floor.{key}' must be in increasing order")
            require(
                bool(np.all(np.diff(axis) > width)),
                path,
                f"'floor.{key}': corridors closer than floor.corridor_width_m + 2 "
                f"tags.junction_clearance_m ({width:g} m)",
            )
        junctions = len(f.corridor_x_m) * len(f.corridor_y_m)
        require(
            junctions <= MAX_JUNCTIONS,
            path,
            f"floor.corridor_x_m x corridor_y_m make {junctions} junctions; "
            f"at most {MAX_JUNCTIONS}",
        )
        check_route(self.route, path, require)
        # The route turns at junctions: each turn is a corridor long at least.
        gap = min(np.diff(f.corridor_x_m).min(), np.diff(f.corridor_y_m).min())
        turns = (1.1 * self.route.length_m + 50.0) / gap
        require(
            turns <= MAX_TURNS,
            path,
            f"route.length_m ({self.route.length_m:g} m) between floor corridors {gap:g} m "
            f"apart makes {turns:.3g} turns; at most {MAX_TURNS}",
        )
        require(
            self.route.wander_amplitude_m < self.floor.corridor_width_m / 2,
            path,
            "route.wander_amplitude_m must keep the robot inside its corridor",
        )
        require(
            self.tags.height_min_m <= self.tags.height_max_m,
            path,
            "tags.height_min_m must be <= height_max_m",
        )


# --- the world ------------------------------------------------------------------------------


@dataclass(frozen=True)
class Corridor:
    """One corridor between two neighbouring junctions: start, unit direction, length."""

    start: np.ndarray
    direction: np.ndarray
    length: float


@dataclass(frozen=True)
class IndoorWorld:
    """Everything in floor coordinates (the plan's own frame, not yet the first pose's)."""

    corridors: list[Corridor]
    free_space: np.ndarray  # (K, 4) rectangles [x_min, y_min, x_max, y_max]
    times_ns: np.ndarray  # (N,)
    poses: np.ndarray  # (N, 4, 4) body poses on the floor
    tag_poses: np.ndarray  # (M, 4, 4) tag poses on the floor, row m = tag id m


def corridors_of(floor: FloorConfig) -> list[Corridor]:
    xs, ys = floor.corridor_x_m, floor.corridor_y_m
    out = []
    for y in ys:
        for x0, x1 in itertools.pairwise(xs):
            out.append(Corridor(np.array([x0, y]), np.array([1.0, 0.0]), x1 - x0))
    for x in xs:
        for y0, y1 in itertools.pairwise(ys):
            out.append(Corridor(np.array([x, y0]), np.array([0.0, 1.0]), y1 - y0))
    return out


def free_space_of(corridors: list[Corridor], width: float) -> np.ndarray:
    """Each corridor's floor, junctions at both ends included, as an axis-aligned rectangle."""
    half = width / 2
    rects = []
    for c in corridors:
        end = c.start + c.direction * c.length
        lo, hi = np.minimum(c.start, end) - half, np.maximum(c.start, end) + half
        rects.append([lo[0], lo[1], hi[0], hi[1]])
    return np.array(rects)


def place_tags(
    corridors: list[Corridor], width: float, tags: TagConfig, rng: np.random.Generator
) -> np.ndarray:
    """(M, 4, 4) tag poses on the corridor walls, facing into the corridor; row m is tag m."""
    margin = width / 2 + tags.junction_clearance_m
    # Every usable stretch of wall: (corridor, side), its length.
    walls = [(c, side) for c in corridors for side in (1.0, -1.0)]
    usable = np.array([c.length - 2 * margin for c, _ in walls])
    total = usable.sum()
    free = total - tags.count * tags.min_spacing_m
    if free <= 0:
        raise InputError(f"{NAME} config: walls too short for tags.count at tags.min_spacing_m")
    # Sorted uniform draws stretched by the spacing: uniform positions with a minimum gap.
    along = np.sort(rng.uniform(0.0, free, tags.count)) + np.arange(tags.count) * tags.min_spacing_m
    ends = np.cumsum(usable)
    wall_index = np.minimum(np.searchsorted(ends, along, side="right"), len(walls) - 1)
    offset = along - (ends[wall_index] - usable[wall_index])
    heights = rng.uniform(tags.height_min_m, tags.height_max_m, tags.count)
    poses = np.zeros((tags.count, 4, 4))
    for k, (w, o, h) in enumerate(zip(wall_index, offset, heights, strict=True)):
        corridor, side = walls[w]
        left = np.array([-corridor.direction[1], corridor.direction[0]])
        xy = corridor.start + corridor.direction * (margin + o) + side * (width / 2) * left
        normal = np.array([*(-side * left), 0.0])  # from the wall into the corridor
        up = np.array([0.0, 0.0, 1.0])
        rotation = np.stack([normal, np.cross(up, normal), up], axis=1)
        poses[k] = pose_from_rotation_translation(rotation, np.array([*xy, h]))
    # Tag ids in random order along the walls, as stuck up by hand: id mod C has no pattern.
    return poses[rng.permutation(tags.count)]


def build_world(config: IndoorTagsConfig) -> IndoorWorld:
    rng = np.random.default_rng(config.world_seed)
    corridors = corridors_of(config.floor)
    # Longer than asked: rounding the corners shortens the route.
    floor = config.floor
    length = 1.1 * config.route.length_m + 50.0
    vertices = junction_route(floor.corridor_x_m, floor.corridor_y_m, length, rng)
    times_ns, poses = drive(vertices, config.route, NAME)
    tag_poses = place_tags(corridors, config.floor.corridor_width_m, config.tags, rng)
    free_space = free_space_of(corridors, config.floor.corridor_width_m)
    if not inside_any(poses[:, :2, 3], free_space).all():
        raise InputError(
            f"{NAME} config: the route leaves the corridors; lower route.corner_smoothing_m or "
            "route.wander_amplitude_m"
        )
    return IndoorWorld(
        corridors=corridors,
        free_space=free_space,
        times_ns=times_ns,
        poses=poses,
        tag_poses=tag_poses,
    )


# --- what the camera sees -------------------------------------------------------------------


def visible_tags(
    world: IndoorWorld, camera: TagCameraConfig
) -> Iterator[tuple[slice, tuple[np.ndarray, np.ndarray]]]:
    """For each block of poses, (pose index, tag id) of every tag in view from them: range,
    field of view, facing, no wall between."""
    positions = world.poses[:, :3, 3]
    tags = world.tag_poses[:, :3, 3]
    normals = world.tag_poses[:, :3, 0]
    tree = cKDTree(tags[:, :2])
    for poses in blocks(len(positions), len(tags)):
        near = within_reach(tree, positions[poses], camera.max_range_m)
        offset = tags[None, near, :] - positions[poses, None, :]  # (n, m, 3), world frame
        distance = np.linalg.norm(offset, axis=-1)
        local = np.einsum("nji,nmj->nmi", world.poses[poses, :3, :3], offset)  # body frame
        ber = bearing_elevation_range(local)
        facing = -np.einsum("nmi,mi->nm", offset, normals[near]) / np.maximum(distance, 1e-9)
        mask = (
            (distance <= camera.max_range_m)
            & (local[..., 0] > 0.0)
            & (np.abs(ber[..., 0]) <= math.radians(camera.horizontal_fov_deg) / 2)
            & (np.abs(ber[..., 1]) <= math.radians(camera.vertical_fov_deg) / 2)
            & (facing >= math.cos(math.radians(camera.max_incidence_deg)))
        )
        pose_index, k = np.nonzero(mask)
        pose_index, tag_id = pose_index + poses.start, near[k]
        start, end = positions[pose_index, :2], tags[tag_id, :2]
        # On the floor all the way: no wall between.
        clear = lines_inside(start, end, LINE_OF_SIGHT_SAMPLES, world.free_space, every=True)
        yield poses, (pose_index[clear], tag_id[clear])


# --- the run --------------------------------------------------------------------------------


def simulate(
    config: IndoorTagsConfig, options: SimulationOptions, config_path: Path | None = None
) -> SimulatedRun:
    """The floor's run: the route of `config` walked once, the camera's misses and noise drawn
    from `options.seed`; a detection states the tag's relative pose as well."""
    world = build_world(config)
    streams = random_streams(options.seed)
    num_classes = options.num_classes
    # Everything written is in the frame of the first body pose.
    origin = inverse(world.poses[0])
    poses = origin @ world.poses
    tag_poses = origin @ world.tag_poses

    def detections() -> Iterator[list[Detection]]:
        """Each pose's detections, made a piece of the run at a time."""
        m = config.measurement
        point_sigmas = np.array([m.sigma_bearing_rad, m.sigma_elevation_rad, m.sigma_range_m])
        pose_sigmas = np.array(
            [m.relative_pose_sigma_rotation_rad] * 3 + [m.relative_pose_sigma_translation_m] * 3
        )
        point_covariance = np.diag(point_sigmas**2)
        pose_covariance = floats(np.diag(pose_sigmas**2))
        for piece, (pose_index, tag_id) in pieces(visible_tags(world, config.camera)):
            seen = streams["visibility"].random(len(pose_index))
            detected = seen < config.camera.detection_probability
            pose_index, tag_id = pose_index[detected], tag_id[detected]

            relative = inverse(poses[pose_index]) @ tag_poses[tag_id]  # true, in body frames
            rng = streams["measurement"]
            point_noise = rng.standard_normal((len(tag_id), 3)) * point_sigmas
            pose_noise = rng.standard_normal((len(tag_id), 6)) * pose_sigmas
            measured = bearing_elevation_range(relative[:, :3, 3]) + point_noise
            measured_pose = relative @ se3_exp(pose_noise)
            measured_quaternion = quaternion_from_rotation(measured_pose[:, :3, :3])

            reported = reported_classes(options, tag_id, streams["classes"])
            relative_poses = [
                RelativePose(
                    translation=floats(measured_pose[d, :3, 3]),  # type: ignore[arg-type]
                    rotation=floats(measured_quaternion[d]),  # type: ignore[arg-type]
                    covariance=pose_covariance,
                )
                for d in range(len(tag_id))
            ]
            yield from detection_frames(
                piece,
                pose_index,
                measured,
                point_covariance,
                reported,
                tag_id,
                "apriltag",
                relative_pose=relative_poses,
            )

    return SimulatedRun(
        times_ns=world.times_ns,
        poses=poses,
        odometry=noisy_odometry(config.odometry, options, poses, streams["odometry"]),
        detections=detections(),
        landmarks=truth_landmarks(tag_poses[:, :3, 3], np.arange(len(tag_poses)) % num_classes),
        confusion=options.confusion,
        class_names=tag_class_names(num_classes),
    )
