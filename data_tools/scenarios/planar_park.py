"""planar-park: a 2-D laser scanner's view of tree trunks from a car driving loops in a park.

Modelled on the real planar datasets of range-bearing SLAM (Victoria Park): everything lies in
one plane, so every detection has elevation 0 and the odometry never moves in z, roll or pitch;
the log still states a small variance for them and a sigma for the elevation, as a converted
real dataset does. The odometry's error is mostly a slow bias (wheel radius, yaw-rate drift),
strongly correlated from one keyframe to the next, while the log states white per-step sigmas:
the drift over a loop is far larger than the stated covariance implies. The bearing sigma the
log states is larger than the scanner's real one. One class (trees), clutter from other objects.

The world comes from the config's `world_seed`; `--seed` draws the odometry noise, the missed
detections, the measurement noise and the clutter.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import numpy as np
from scipy.spatial import cKDTree

from data_tools.scenarios.common import (
    MeasuredOdometry,
    SimulatedRun,
    SimulationOptions,
    blocks,
    detection_frames,
    first_pose_frame,
    pieces,
    truth_landmarks,
    within_reach,
)
from data_tools.scenarios.config import (
    MAX_NOISE_SCALE,
    Distance,
    Length,
    PerFrame,
    Probability,
    Sigma,
    Spread,
    WorldSeed,
    require,
)
from data_tools.scenarios.geometry import (
    bearing_elevation_range,
    pose_from_rotation_translation,
    relative_poses,
    yaw_rotation,
)
from data_tools.scenarios.noise import random_streams
from data_tools.scenarios.routes import RouteConfig, check_route, drive
from pipeline.errors import InputError
from pipeline.log import Detection
from pipeline.settings import positive, within

NAME = "planar-park"
# The route's turns (places visited) at the most.
MAX_TURNS = 10**6


@dataclass(frozen=True)
class ParkConfig:
    size_m: Length
    tree_count: Annotated[int, within(1, 10**5)]
    min_spacing_m: Distance
    path_clearance_m: Distance
    places: Annotated[int, within(3, 1000)]
    margin_m: Distance
    next_choices: Annotated[int, within(1, 1000)]


@dataclass(frozen=True)
class ScannerConfig:
    fov_deg: Annotated[float, positive(360.0)]
    min_range_m: Length
    max_range_m: Length
    detection_probability: Probability
    clutter_per_frame: PerFrame
    sigma_bearing_rad: Sigma
    sigma_range_m: Sigma
    stated_sigma_bearing_rad: Sigma
    stated_sigma_elevation_rad: Sigma
    stated_sigma_range_m: Sigma


@dataclass(frozen=True)
class BiasedOdometryConfig:
    white_sigma_x_m: Sigma
    white_sigma_y_m: Sigma
    white_sigma_yaw_rad: Sigma
    bias_scale_sigma: Spread
    bias_yaw_sigma_rad: Spread
    bias_correlation: Annotated[float, within(0.0, 1.0, high_open=True)]
    default_noise_scale: Annotated[float, within(0.0, MAX_NOISE_SCALE)]
    stated_sigma_x_m: Sigma
    stated_sigma_y_m: Sigma
    stated_sigma_yaw_rad: Sigma
    stated_flat_variance: Annotated[float, positive(1e4)]


@dataclass(frozen=True)
class PlanarParkConfig:
    world_seed: WorldSeed
    num_classes: Annotated[int, within(1, 1)]  # trees
    park: ParkConfig
    route: RouteConfig
    scanner: ScannerConfig
    odometry: BiasedOdometryConfig

    def check(self, path: Path | str) -> None:
        p, s = self.park, self.scanner
        require(p.size_m > 2 * p.margin_m, path, "park.size_m must exceed 2 margin_m")
        require(p.next_choices < p.places, path, "park.next_choices must be < places")
        check_route(self.route, path, require)
        require(s.min_range_m < s.max_range_m, path, "scanner ranges: min_range_m < max_range_m")


# --- the world ------------------------------------------------------------------------------


@dataclass(frozen=True)
class ParkWorld:
    times_ns: np.ndarray  # (N,)
    poses: np.ndarray  # (N, 4, 4) planar scanner poses
    trees: np.ndarray  # (M, 3) trunk positions at the scanner's height, row m = landmark m


def place_route(park: ParkConfig, length: float, rng: np.random.Generator) -> np.ndarray:
    """Route vertices (K, 2): from place to place until `length`, each time to the least
    visited of the `next_choices` nearest other places (never straight back), so the park is
    covered and then driven again in overlapping loops."""
    places = rng.uniform(park.margin_m, park.size_m - park.margin_m, (park.places, 2))
    distances = np.linalg.norm(places[:, None] - places[None], axis=-1)
    nearest = np.argsort(distances, axis=1)[:, 1 : park.next_choices + 1]
    visits = np.zeros(park.places, dtype=int)
    current, previous = 0, -1
    route, total = [places[0]], 0.0
    while total < length:
        if len(route) > MAX_TURNS:
            raise InputError(
                f"{NAME} config: route.length_m ({length:.0f} m) between park.places "
                f"{float(distances[distances > 0].min()):.3g} m apart at the closest makes more "
                f"than {MAX_TURNS} turns; a larger park.size_m or fewer places"
            )
        options = [int(n) for n in nearest[current] if n != previous]
        fewest = min(visits[options])
        options = [n for n in options if visits[n] == fewest]
        step = options[int(rng.integers(len(options)))]
        visits[step] += 1
        total += float(distances[current, step])
        previous, current = current, step
        route.append(places[current])
    return np.array(route)


def plant_trees(park: ParkConfig, path_xy: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(M, 3) trunks: uniform in the park, min_spacing_m apart, clear of the path."""
    path_tree = cKDTree(path_xy)
    trees: list[np.ndarray] = []
    # Trees by square cell of min_spacing_m: only the 3 x 3 cells around a new one can hold a
    # tree closer than that, so each draw is checked against those alone.
    cells: dict[tuple[int, int], list[np.ndarray]] = {}
    for _ in range(50 * park.tree_count):
        if len(trees) == park.tree_count:
            break
        xy = rng.uniform(0.0, park.size_m, 2)
        if path_tree.query(xy)[0] < park.path_clearance_m:
            continue
        if park.min_spacing_m > 0:
            i, j = (int(v) for v in np.floor(xy / park.min_spacing_m))
            near = [
                t for a in (-1, 0, 1) for b in (-1, 0, 1) for t in cells.get((i + a, j + b), ())
            ]
            if near and np.min(np.linalg.norm(np.array(near) - xy, axis=1)) < park.min_spacing_m:
                continue
            cells.setdefault((i, j), []).append(xy)
        trees.append(xy)
    xy = np.array(trees)
    return np.concatenate([xy, np.zeros((len(xy), 1))], axis=1)


def build_world(config: PlanarParkConfig) -> ParkWorld:
    rng = np.random.default_rng(config.world_seed)
    vertices = place_route(config.park, 1.05 * config.route.length_m + 100.0, rng)
    times_ns, poses = drive(vertices, config.route, NAME)
    trees = plant_trees(config.park, poses[:, :2, 3], rng)
    return ParkWorld(times_ns, poses, trees)


# --- odometry --------------------------------------------------------------------------------


def biased_planar_odometry(
    true_motion: np.ndarray, o: BiasedOdometryConfig, scale: float, rng: np.random.Generator
) -> np.ndarray:
    """Measured (N, 4, 4) planar motions: the true ones with white noise and a slow bias.

    The bias is an AR(1) process b_k = rho b_{k-1} + sqrt(1 - rho^2) sigma n_k on the forward
    scale and on the yaw; z, roll and pitch are exact (a flat park)."""
    n = len(true_motion)
    rho = o.bias_correlation
    innovations = rng.standard_normal((n, 2)) * np.array([o.bias_scale_sigma, o.bias_yaw_sigma_rad])
    bias = np.empty((n, 2))
    state = innovations[0]
    for k in range(n):
        state = rho * state + math.sqrt(1 - rho * rho) * innovations[k] if k else state
        bias[k] = state
    bias *= scale
    white = rng.standard_normal((n, 3)) * np.array(
        [o.white_sigma_x_m, o.white_sigma_y_m, o.white_sigma_yaw_rad]
    )
    dx = true_motion[:, 0, 3] * (1.0 + bias[:, 0]) + white[:, 0]
    dy = true_motion[:, 1, 3] + white[:, 1]
    dyaw = np.arctan2(true_motion[:, 1, 0], true_motion[:, 0, 0]) + bias[:, 1] + white[:, 2]
    translation = np.stack([dx, dy, np.zeros(n)], axis=1)
    return pose_from_rotation_translation(yaw_rotation(dyaw), translation)


def stated_odometry_covariance(o: BiasedOdometryConfig, scale: float, true: bool) -> np.ndarray:
    """What the log says, in Pose3 tangent order: the stated sigmas (and, with `true`, the
    bias's stationary sigmas added as if white) plus the flat variances."""
    yaw = o.stated_sigma_yaw_rad**2
    x = o.stated_sigma_x_m**2
    if true:
        yaw += (scale * o.bias_yaw_sigma_rad) ** 2
        x += (scale * o.bias_scale_sigma) ** 2  # per metre of step; steps are ~1 m or less
    flat = o.stated_flat_variance
    return np.diag([flat, flat, yaw, x, o.stated_sigma_y_m**2, flat])


# --- what the scanner sees --------------------------------------------------------------------


def trees_in_view(
    world: ParkWorld, s: ScannerConfig
) -> Iterator[tuple[slice, tuple[np.ndarray, np.ndarray, np.ndarray]]]:
    """For each block of poses, (pose index, tree id, body-frame position) of every trunk in
    the scanner's field of view and range from them."""
    trunks = cKDTree(world.trees[:, :2])
    for poses in blocks(len(world.poses), len(world.trees)):
        near = within_reach(trunks, world.poses[poses, :3, 3], s.max_range_m)
        offset = world.trees[None, near] - world.poses[poses, None, :3, 3]
        local = np.einsum("nji,nmj->nmi", world.poses[poses, :3, :3], offset)
        distance = np.linalg.norm(local, axis=-1)
        bearing = np.arctan2(local[..., 1], local[..., 0])
        in_view = (
            (distance >= s.min_range_m)
            & (distance <= s.max_range_m)
            & (np.abs(bearing) <= math.radians(s.fov_deg) / 2)
        )
        pose_index, k = np.nonzero(in_view)
        yield poses, (pose_index + poses.start, near[k], local[pose_index, k])


def clutter(
    num_frames: int, s: ScannerConfig, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """(pose index, body-frame position) of returns from things that are not trees."""
    count = rng.poisson(s.clutter_per_frame, num_frames)
    pose_index = np.repeat(np.arange(num_frames), count)
    n = len(pose_index)
    half = math.radians(s.fov_deg) / 2
    bearing = rng.uniform(-half, half, n)
    distance = rng.uniform(s.min_range_m, s.max_range_m, n)
    local = np.stack([distance * np.cos(bearing), distance * np.sin(bearing), np.zeros(n)], 1)
    return pose_index, local


# --- the run --------------------------------------------------------------------------------


def simulate(
    config: PlanarParkConfig, options: SimulationOptions, config_path: Path | None = None
) -> SimulatedRun:
    """The park's run: the loops of `config` driven once, the odometry's bias and noise, the
    scanner's misses, noise and clutter drawn from `options.seed`; one class, trees."""
    world = build_world(config)
    streams = random_streams(options.seed)
    poses, trees = first_pose_frame(world.poses, world.trees)
    o, s = config.odometry, config.scanner

    scale = options.odom_noise_scale
    odometry = MeasuredOdometry(
        biased_planar_odometry(relative_poses(poses), o, scale, streams["odometry"]),
        stated_odometry_covariance(o, scale, options.true_covariance),
    )
    stated = (
        np.diag([s.stated_sigma_bearing_rad, s.stated_sigma_elevation_rad, s.stated_sigma_range_m])
        ** 2
    )

    def detections() -> Iterator[list[Detection]]:
        """Each pose's detections, made a piece of the run at a time."""
        for piece, (pose_index, tree, local) in pieces(
            trees_in_view(world, s), s.clutter_per_frame
        ):
            seen = streams["visibility"].random(len(tree)) < s.detection_probability
            pose_index, tree, local = pose_index[seen], tree[seen], local[seen]
            clutter_pose, clutter_local = clutter(
                piece.stop - piece.start, s, streams["false_positives"]
            )
            pose_index = np.concatenate([pose_index, clutter_pose + piece.start])
            truth = np.concatenate([tree, np.full(len(clutter_pose), -1)])
            measured = bearing_elevation_range(np.concatenate([local, clutter_local]))
            noise = streams["measurement"].standard_normal((len(truth), 2))
            measured[:, 0] += s.sigma_bearing_rad * noise[:, 0]
            measured[:, 1] = 0.0  # a planar scanner
            measured[:, 2] = np.maximum(measured[:, 2] + s.sigma_range_m * noise[:, 1], 0.1)
            trunk = np.zeros(len(truth), dtype=int)
            # The contract knows tags and detector boxes: a trunk is boxed.
            yield from detection_frames(piece, pose_index, measured, stated, trunk, truth, "bbox")

    return SimulatedRun(
        times_ns=world.times_ns,
        poses=poses,
        odometry=odometry,
        detections=detections(),
        landmarks=truth_landmarks(trees, [0] * len(trees)),
        confusion=np.ones((1, 1)),
        class_names=["tree"],
    )
