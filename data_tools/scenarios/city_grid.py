"""city-grid: an aliased city, a regular grid of streets lined with regularly parked vehicles.

The world: streets on a regular grid (`grid`), a route that covers every street and then
drives them again in overlapping loops (`route`), and vehicles in parking slots at a regular
spacing along both kerbs, a slot occupied at random (`parking`). Every block looks like every
other: what tells two streets apart is the odometry, the pattern of empty slots and the vehicle
classes, and the detector confuses classes. Buildings fill the blocks and hide what is behind
them. The world comes from the config's `world_seed`; `--seed` draws the odometry noise, the
missed detections, the measurement noise, the false alarms and the reported classes.

A detection is the vehicle's centre as bearing/elevation/range from a roof camera, drawn with
the noise its covariance declares (range noise grows with the square of the range, as stereo
depth does).
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
    first_pose_frame,
    lines_inside,
    noisy_odometry,
    pieces,
    reported_classes,
    truth_landmarks,
    within_reach,
)
from data_tools.scenarios.config import (
    MAX_LANDMARKS,
    Distance,
    Length,
    NumClasses,
    PerFrame,
    Probability,
    Sigma,
    WorldSeed,
    require,
)
from data_tools.scenarios.geometry import bearing_elevation_range
from data_tools.scenarios.noise import OdometryNoiseConfig, random_streams
from data_tools.scenarios.routes import RouteConfig, check_route, drive, junction_route
from data_tools.scenarios.vehicles import VehicleType, type_shares, vehicle_class_names
from pipeline.log import Detection
from pipeline.settings import within

NAME = "city-grid"

# Points tested along each line of sight against the buildings.
LINE_OF_SIGHT_SAMPLES = np.linspace(0.05, 0.95, 24)
# Buildings stand this far back from the kerb line of parked vehicles.
PAVEMENT_M = 2.0


@dataclass(frozen=True)
class GridConfig:
    streets_x: Annotated[int, within(2, 100)]
    streets_y: Annotated[int, within(2, 100)]
    block_x_m: Length
    block_y_m: Length


@dataclass(frozen=True)
class ParkingConfig:
    slot_spacing_m: Length
    kerb_offset_m: Length
    corner_clearance_m: Distance
    occupancy: Probability
    slot_jitter_m: Distance
    centre_height_m: Annotated[float, within(-100.0, 100.0)]


@dataclass(frozen=True)
class SensorConfig:
    camera_height_m: Annotated[float, within(-100.0, 100.0)]
    horizontal_fov_deg: Annotated[float, within(0.0, 180.0, low_open=True, high_open=True)]
    min_range_m: Length
    max_range_m: Length
    detection_probability_near: Probability
    detection_probability_far: Probability
    sigma_bearing_rad: Sigma
    sigma_elevation_rad: Sigma
    sigma_range_m: Sigma
    sigma_range_per_m2: Annotated[float, within(0.0, 1.0)]
    false_alarms_per_frame: PerFrame


@dataclass(frozen=True)
class CityGridConfig:
    world_seed: WorldSeed
    num_classes: NumClasses
    grid: GridConfig
    route: RouteConfig
    vehicles: tuple[VehicleType, ...]
    parking: ParkingConfig
    sensor: SensorConfig
    odometry: OdometryNoiseConfig

    def check(self, path: Path | str) -> None:
        g, p, s = self.grid, self.parking, self.sensor
        street_half = p.kerb_offset_m + PAVEMENT_M
        require(
            min(g.block_x_m, g.block_y_m) > 2 * max(street_half, p.corner_clearance_m),
            path,
            "grid blocks are too small for the streets and their corner clearance",
        )
        check_route(self.route, path, require)
        require(len(self.vehicles) >= 1, path, "at least one [[vehicles]] entry")
        slots = parking_slots(g, p)
        require(
            slots <= MAX_LANDMARKS,
            path,
            f"grid.streets_x, streets_y, block_x_m, block_y_m and parking.slot_spacing_m "
            f"({p.slot_spacing_m:g} m) make {slots:.3g} parking slots; at most {MAX_LANDMARKS}",
        )
        require(
            p.slot_jitter_m < p.slot_spacing_m / 2,
            path,
            f"'parking.slot_jitter_m' ({p.slot_jitter_m:g} m) must be < slot_spacing_m / 2 "
            f"({p.slot_spacing_m / 2:g} m)",
        )
        require(s.min_range_m < s.max_range_m, path, "sensor ranges: min_range_m < max_range_m")


# --- the world ------------------------------------------------------------------------------


@dataclass(frozen=True)
class CityWorld:
    times_ns: np.ndarray  # (N,)
    poses: np.ndarray  # (N, 4, 4) body (camera) poses, camera_height_m above the road
    vehicles: np.ndarray  # (M, 3) vehicle centres, row m = landmark id m
    vehicle_types: np.ndarray  # (M,) index into config.vehicles
    buildings: np.ndarray  # (K, 4) rectangles [x_min, y_min, x_max, y_max]


def street_lines(grid: GridConfig) -> tuple[tuple[float, ...], tuple[float, ...]]:
    xs = tuple(float(i * grid.block_x_m) for i in range(grid.streets_x))
    ys = tuple(float(j * grid.block_y_m) for j in range(grid.streets_y))
    return xs, ys


def buildings_of(xs: tuple[float, ...], ys: tuple[float, ...], half_street: float) -> np.ndarray:
    return np.array(
        [
            [x0 + half_street, y0 + half_street, x1 - half_street, y1 - half_street]
            for x0, x1 in itertools.pairwise(xs)
            for y0, y1 in itertools.pairwise(ys)
        ]
    )


def parking_slots(grid: GridConfig, parking: ParkingConfig) -> float:
    """How many parking slots `park_vehicles` lines the streets with (both kerbs)."""
    per_street = [
        math.floor((block - 2 * parking.corner_clearance_m) / parking.slot_spacing_m) + 1
        for block in (grid.block_x_m, grid.block_y_m)
    ]
    streets_along_x = grid.streets_y * (grid.streets_x - 1)
    streets_along_y = grid.streets_x * (grid.streets_y - 1)
    return 2.0 * (streets_along_x * per_street[0] + streets_along_y * per_street[1])


def park_vehicles(
    xs: tuple[float, ...],
    ys: tuple[float, ...],
    parking: ParkingConfig,
    shares: np.ndarray,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """Vehicle centres (M, 3) and types (M,): slots along both kerbs of every street segment."""
    segments = [((x0, y), (x1, y)) for y in ys for x0, x1 in itertools.pairwise(xs)]
    segments += [((x, y0), (x, y1)) for x in xs for y0, y1 in itertools.pairwise(ys)]
    centres = []
    for start, end in segments:
        start, end = np.array(start), np.array(end)
        length = float(np.linalg.norm(end - start))
        direction = (end - start) / length
        left = np.array([-direction[1], direction[0]])
        usable = length - 2 * parking.corner_clearance_m
        count = math.floor(usable / parking.slot_spacing_m) + 1
        along = parking.corner_clearance_m + np.arange(count) * parking.slot_spacing_m
        along += (usable - along[-1] + parking.corner_clearance_m) / 2  # centre the row
        for side in (1.0, -1.0):
            taken = rng.random(count) < parking.occupancy
            jitter = rng.uniform(-parking.slot_jitter_m, parking.slot_jitter_m, count)
            s = along[taken] + jitter[taken]
            centres.append(start + s[:, None] * direction + side * parking.kerb_offset_m * left)
    xy = np.concatenate(centres)
    types = rng.choice(len(shares), size=len(xy), p=shares)
    heights = np.full((len(xy), 1), parking.centre_height_m)
    return np.concatenate([xy, heights], axis=1), types


def build_world(config: CityGridConfig) -> CityWorld:
    rng = np.random.default_rng(config.world_seed)
    xs, ys = street_lines(config.grid)
    # Longer than asked: rounding the corners shortens the route.
    vertices = junction_route(xs, ys, 1.05 * config.route.length_m + 100.0, rng)
    times_ns, poses = drive(vertices, config.route, NAME)
    poses[:, 2, 3] = config.sensor.camera_height_m
    vehicles, types = park_vehicles(xs, ys, config.parking, type_shares(config.vehicles), rng)
    buildings = buildings_of(xs, ys, config.parking.kerb_offset_m + PAVEMENT_M)
    return CityWorld(times_ns, poses, vehicles, types, buildings)


# --- what the camera sees -------------------------------------------------------------------


def vehicles_in_view(
    world: CityWorld, sensor: SensorConfig
) -> Iterator[tuple[slice, tuple[np.ndarray, np.ndarray, np.ndarray]]]:
    """For each block of poses, (pose index, vehicle id, body-frame position) of every vehicle
    in view and range from them and not behind a building."""
    half_fov = math.radians(sensor.horizontal_fov_deg) / 2
    tree = cKDTree(world.vehicles[:, :2])
    for block in blocks(len(world.poses), len(world.vehicles)):
        poses = world.poses[block]
        near = within_reach(tree, poses[:, :3, 3], sensor.max_range_m)
        offset = world.vehicles[None, near] - poses[:, None, :3, 3]  # (n, m, 3)
        local = np.einsum("nji,nmj->nmi", poses[:, :3, :3], offset)
        distance = np.linalg.norm(local, axis=-1)
        bearing = np.arctan2(local[..., 1], local[..., 0])
        in_view = (
            (distance >= sensor.min_range_m)
            & (distance <= sensor.max_range_m)
            & (local[..., 0] > 0)
            & (np.abs(bearing) <= half_fov)
        )
        pose_index, k = np.nonzero(in_view)
        vehicle = near[k]
        start, end = poses[pose_index, :2, 3], world.vehicles[vehicle, :2]
        clear = ~lines_inside(start, end, LINE_OF_SIGHT_SAMPLES, world.buildings, every=False)
        pose_index, vehicle, k = pose_index[clear], vehicle[clear], k[clear]
        yield block, (pose_index + block.start, vehicle, local[pose_index, k])


def detected(local: np.ndarray, sensor: SensorConfig, rng: np.random.Generator) -> np.ndarray:
    """Which vehicles in view (body-frame positions) are detected: the probability falls
    linearly with range."""
    fraction = (np.linalg.norm(local, axis=1) - sensor.min_range_m) / (
        sensor.max_range_m - sensor.min_range_m
    )
    near, far = sensor.detection_probability_near, sensor.detection_probability_far
    return rng.random(len(local)) < near + (far - near) * fraction


def measurement_sigmas(sensor: SensorConfig, ranges: np.ndarray) -> np.ndarray:
    """(n, 3) sigmas of (bearing, elevation, range) for true ranges."""
    sigmas = np.empty((len(ranges), 3))
    sigmas[:, 0] = sensor.sigma_bearing_rad
    sigmas[:, 1] = sensor.sigma_elevation_rad
    sigmas[:, 2] = sensor.sigma_range_m + sensor.sigma_range_per_m2 * ranges**2
    return sigmas


def false_alarms(
    num_frames: int, config: CityGridConfig, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(pose index, type, body-frame position) of phantom vehicles, uniform in view and range."""
    s = config.sensor
    count = rng.poisson(s.false_alarms_per_frame, num_frames)
    pose_index = np.repeat(np.arange(num_frames), count)
    n = len(pose_index)
    kinds = rng.choice(len(config.vehicles), size=n, p=type_shares(config.vehicles))
    half_fov = math.radians(s.horizontal_fov_deg) / 2
    bearing = rng.uniform(-half_fov, half_fov, n)
    distance = rng.uniform(s.min_range_m, s.max_range_m, n)
    height = config.parking.centre_height_m - s.camera_height_m
    local = np.stack(
        [distance * np.cos(bearing), distance * np.sin(bearing), np.full(n, height)], axis=1
    )
    return pose_index, kinds, local


# --- the run --------------------------------------------------------------------------------


def simulate(
    config: CityGridConfig, options: SimulationOptions, config_path: Path | None = None
) -> SimulatedRun:
    """The city's run: the world of `config` driven once, the detector's misses, noise and
    false alarms drawn from `options.seed`."""
    world = build_world(config)
    streams = random_streams(options.seed)
    num_classes = options.num_classes
    poses, vehicles = first_pose_frame(world.poses, world.vehicles)

    def detections() -> Iterator[list[Detection]]:
        """Each pose's detections, made a piece of the run at a time."""
        seen = vehicles_in_view(world, config.sensor)
        for piece, (pose_index, vehicle, local) in pieces(
            seen, config.sensor.false_alarms_per_frame
        ):
            found = detected(local, config.sensor, streams["visibility"])
            pose_index, vehicle, local = pose_index[found], vehicle[found], local[found]
            fa_pose, fa_kind, fa_local = false_alarms(
                piece.stop - piece.start, config, streams["false_positives"]
            )
            pose_index = np.concatenate([pose_index, fa_pose + piece.start])
            truth = np.concatenate([vehicle, np.full(len(fa_pose), -1)])
            kinds = np.concatenate([world.vehicle_types[vehicle], fa_kind])
            local = np.concatenate([local, fa_local])

            true_ber = bearing_elevation_range(local)
            sigmas = measurement_sigmas(config.sensor, true_ber[:, 2])
            measured = true_ber + sigmas * streams["measurement"].standard_normal(sigmas.shape)
            measured[:, 2] = np.maximum(measured[:, 2], 0.1)  # a range is positive
            covariances = np.zeros((len(sigmas), 3, 3))
            covariances[:, [0, 1, 2], [0, 1, 2]] = sigmas**2

            reported = reported_classes(options, kinds, streams["classes"])
            yield from detection_frames(
                piece, pose_index, measured, covariances, reported, truth, "bbox"
            )

    return SimulatedRun(
        times_ns=world.times_ns,
        poses=poses,
        odometry=noisy_odometry(config.odometry, options, poses, streams["odometry"]),
        detections=detections(),
        landmarks=truth_landmarks(vehicles, world.vehicle_types % num_classes),
        confusion=options.confusion,
        class_names=vehicle_class_names(config.vehicles, num_classes),
    )
