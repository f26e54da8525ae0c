"""kitti05-cars: the real KITTI odometry 05 path through simulated streets of parked cars.

The path and timestamps are KITTI's own (every frame is a keyframe, ~10 Hz), converted to the
contract's body frame: the left camera's origin with x forward, y left, z up. Cars are parked
on both sides of each street the first time it is driven; a revisited street is not lined
again, so a revisit sees the same cars (the real loop closures of the sequence). The world
comes from the config's `world_seed`; `--seed` draws the detector and the noise.

A detection is the car's centre as bearing/elevation/range: bearing and elevation from the box
centre's pixel noise (through the camera model's Jacobian), range from stereo depth noise
sigma_z = z^2 sigma_d / (f b) taken along the ray; the covariance written is the one the noise
was drawn from, evaluated at the true geometry. Occlusion between cars is not modelled.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import numpy as np
from scipy.spatial import cKDTree

from data_tools.data import KITTI05_DIR
from data_tools.scenarios import config as cfg
from data_tools.scenarios.common import (
    SimulatedRun,
    SimulationOptions,
    blocks,
    detection_frames,
    noisy_odometry,
    pieces,
    reported_classes,
    truth_landmarks,
)
from data_tools.scenarios.config import (
    MAX_LANDMARKS,
    Distance,
    Length,
    PerFrame,
    Sigma,
    WorldSeed,
    require,
)
from data_tools.scenarios.geometry import (
    bearing_elevation_range,
    orthonormalise,
    yaw_rotation,
)
from data_tools.scenarios.noise import OdometryNoiseConfig, logistic, random_streams
from data_tools.scenarios.routes import MAX_KEYFRAMES
from data_tools.scenarios.vehicles import VehicleType, type_shares, vehicle_class_names
from pipeline.datasets.camera import BODY_FROM_CAMERA, StereoIntrinsics
from pipeline.datasets.kitti import (
    camera_poses_to_body,
    read_poses,
    read_times,
)
from pipeline.errors import InputError
from pipeline.log import Detection
from pipeline.settings import PROBABILITY, positive, within

logger = logging.getLogger(__name__)

NAME = "kitti05-cars"

# Unit box corners (x along the car, y across, z up), scaled by each car's size.
_BOX_CORNERS = np.array(
    [[sx, sy, sz] for sx in (-0.5, 0.5) for sy in (-0.5, 0.5) for sz in (-0.5, 0.5)]
)
_NEAR_PLANE_M = 0.1  # box corners closer than this to the image plane are not projected


Logit = Annotated[float, within(-100.0, 100.0)]
# What the parking keys may make of the sequence's path at the most: street samples, and pairs
# of samples (or of cars) within the distances the keys give, which are compared in memory.
MAX_STREET_SAMPLES = 10**6
MAX_NEAR_PAIRS = 10**7
# A line of a KITTI poses file at the most (12 numbers): a file longer than MAX_KEYFRAMES of
# them is refused before it is read.
MAX_POSE_LINE_BYTES = 400


@dataclass(frozen=True)
class SequenceConfig:
    data_dir: str  # "": KITTI 05 as shipped (data_tools/data); else a folder like it
    camera_height_m: Annotated[float, positive(100.0)]


@dataclass(frozen=True)
class VehicleClass(VehicleType):
    """A vehicle type, and its cars' size."""

    length_m: Annotated[float, positive(100.0)]
    width_m: Annotated[float, positive(100.0)]
    height_m: Annotated[float, positive(100.0)]


@dataclass(frozen=True)
class ParkingConfig:
    path_step_m: Length
    revisit_radius_m: Length
    revisit_min_arc_m: Distance
    right_offset_m: Annotated[float, within(-1000.0, 1000.0)]
    left_offset_m: Annotated[float, within(-1000.0, 1000.0)]
    offset_jitter_m: Distance
    heading_jitter_deg: Annotated[float, within(0.0, 180.0)]
    row_mean_cars: Annotated[float, within(1.0, 1000.0)]
    gap_min_m: Distance
    gap_max_m: Distance
    empty_mean_m: Length
    min_path_clearance_m: Distance
    min_separation_m: Distance


@dataclass(frozen=True)
class DetectorConfig:
    max_range_m: Length
    min_depth_m: Length
    score_threshold: Annotated[float, PROBABILITY]
    score_logit_near: Logit
    score_logit_far: Logit
    score_logit_sigma: Sigma
    false_alarms_per_frame: PerFrame
    false_alarm_logit_mean: Logit
    pixel_sigma_px: Annotated[float, positive(1000.0)]
    disparity_sigma_px: Annotated[float, positive(1000.0)]


@dataclass(frozen=True)
class Kitti05CarsConfig:
    world_seed: WorldSeed
    sequence: SequenceConfig
    camera: StereoIntrinsics
    vehicles: tuple[VehicleClass, ...]
    parking: ParkingConfig
    detector: DetectorConfig
    odometry: OdometryNoiseConfig

    @property
    def num_classes(self) -> int:
        """One class per vehicle class by default."""
        return len(self.vehicles)

    def check(self, path: Path | str) -> None:
        require(len(self.vehicles) >= 1, path, "at least one vehicle class is needed")
        p, d = self.parking, self.detector
        require(p.gap_min_m <= p.gap_max_m, path, "parking gaps: gap_min_m <= gap_max_m")
        require(d.min_depth_m < d.max_range_m, path, "detector: min_depth_m < max_range_m")


# --- the world ------------------------------------------------------------------------------


@dataclass(frozen=True)
class Street:
    """The driven path resampled by arc length: where the kerbs are."""

    s: np.ndarray  # (S,) arc length
    points: np.ndarray  # (S, 3)
    heading: np.ndarray  # (S,) yaw of the direction of travel
    first_visit: np.ndarray  # (S,) bool: no earlier pass nearby


@dataclass(frozen=True)
class Kitti05World:
    times_ns: np.ndarray  # (N,)
    poses: np.ndarray  # (N, 4, 4) body poses, pose 0 at identity
    car_poses: np.ndarray  # (M, 4, 4) box centre and heading
    car_types: np.ndarray  # (M,) index into config.vehicles
    car_sizes: np.ndarray  # (M, 3) length, width, height


def sequence_dir(sequence: SequenceConfig) -> Path:
    """The folder of poses.txt and times.txt: package data unless the config names another."""
    return Path(sequence.data_dir) if sequence.data_dir else KITTI05_DIR


def read_sequence(sequence: SequenceConfig) -> tuple[np.ndarray, np.ndarray]:
    """Times (ns) and body poses of the KITTI sequence (poses.txt, times.txt)."""
    folder = sequence_dir(sequence)
    try:
        size = (folder / "poses.txt").stat().st_size
    except OSError:
        size = 0  # read_poses says what is wrong
    if size > MAX_KEYFRAMES * MAX_POSE_LINE_BYTES:
        raise InputError(
            f"sequence {folder}: poses.txt of {size} bytes holds more than {MAX_KEYFRAMES} poses"
        )
    camera_poses = read_poses(folder / "poses.txt")
    times = read_times(folder / "times.txt")
    if len(times) != len(camera_poses):
        raise InputError(f"sequence {folder}: {len(camera_poses)} poses but {len(times)} times")
    times_ns = np.round((times - times[0]) * 1e9).astype(np.int64)
    # KITTI's rotations are printed to 7 digits: make them exact, as the truth written will be.
    return times_ns, orthonormalise(camera_poses_to_body(camera_poses))


def street_of(positions: np.ndarray, parking: ParkingConfig) -> Street:
    keep = np.concatenate([[True], np.linalg.norm(np.diff(positions, axis=0), axis=1) > 1e-6])
    positions = positions[keep]  # standing still adds nothing to a street
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(positions, axis=0), axis=1))])
    s = np.arange(0.0, arc[-1], parking.path_step_m)
    points = np.stack([np.interp(s, arc, positions[:, k]) for k in range(3)], axis=-1)
    direction = np.gradient(points[:, :2], axis=0)
    heading = np.arctan2(direction[:, 1], direction[:, 0])
    pairs = cKDTree(points[:, :2]).query_pairs(parking.revisit_radius_m, output_type="ndarray")
    first_visit = np.ones(len(s), dtype=bool)
    if len(pairs):
        i, j = pairs.min(axis=1), pairs.max(axis=1)
        revisit = s[j] - s[i] > parking.revisit_min_arc_m
        first_visit[j[revisit]] = False
    return Street(s=s, points=points, heading=heading, first_visit=first_visit)


def kerb_rows(
    length: float,
    parking: ParkingConfig,
    vehicles: tuple[VehicleClass, ...],
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """Arc positions and vehicle types of cars along one kerb: rows split by empty stretches."""
    lengths = np.array([v.length_m for v in vehicles])
    shares = type_shares(vehicles)
    centres, types = [], []
    s = rng.exponential(parking.empty_mean_m)
    while s < length:
        for _ in range(rng.geometric(1.0 / parking.row_mean_cars)):
            kind = int(rng.choice(len(vehicles), p=shares))
            centres.append(s + lengths[kind] / 2)
            types.append(kind)
            s += lengths[kind] + rng.uniform(parking.gap_min_m, parking.gap_max_m)
        s += rng.exponential(parking.empty_mean_m)
    centres_a, types_a = np.array(centres), np.array(types, dtype=int)
    inside = centres_a < length
    return centres_a[inside], types_a[inside]


def park_cars(
    street: Street,
    camera_height: float,
    parking: ParkingConfig,
    vehicles: tuple[VehicleClass, ...],
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(poses (M, 4, 4), types (M,), sizes (M, 3)) of the parked cars."""
    sizes_by_type = np.array([[v.length_m, v.width_m, v.height_m] for v in vehicles])
    poses, types = [], []
    for side, offset in ((-1.0, parking.right_offset_m), (1.0, parking.left_offset_m)):
        centres, kinds = kerb_rows(street.s[-1], parking, vehicles, rng)
        index = np.minimum(np.round(centres / parking.path_step_m).astype(int), len(street.s) - 1)
        lateral = offset + parking.offset_jitter_m * rng.standard_normal(len(centres))
        yaw = street.heading[index] + np.radians(parking.heading_jitter_deg) * rng.standard_normal(
            len(centres)
        )
        kinds, index, lateral, yaw = (
            a[street.first_visit[index]] for a in (kinds, index, lateral, yaw)
        )
        heading = street.heading[index]
        left = np.stack([-np.sin(heading), np.cos(heading)], axis=-1)
        xy = street.points[index, :2] + side * lateral[:, None] * left
        z = street.points[index, 2] - camera_height + sizes_by_type[kinds, 2] / 2
        pose = np.tile(np.eye(4), (len(kinds), 1, 1))
        pose[:, :3, :3] = yaw_rotation(yaw)
        pose[:, :3, 3] = np.concatenate([xy, z[:, None]], axis=1)
        poses.append(pose)
        types.append(kinds)
    car_poses, car_types = np.concatenate(poses), np.concatenate(types)
    # Off the road that is driven, and no two cars on one spot (kerbs of crossing streets).
    clearance, _ = cKDTree(street.points[:, :2]).query(car_poses[:, :2, 3])
    keep = clearance >= parking.min_path_clearance_m
    car_poses, car_types = car_poses[keep], car_types[keep]
    keep = _spread_out(car_poses[:, :2, 3], parking.min_separation_m)
    return car_poses[keep], car_types[keep], sizes_by_type[car_types[keep]]


def _spread_out(points: np.ndarray, distance: float) -> np.ndarray:
    """Greedy: keep a point unless an earlier kept one is closer than `distance`."""
    tree = cKDTree(points)
    keep = np.ones(len(points), dtype=bool)
    for i, j in sorted(tree.query_pairs(distance)):
        if keep[i] and keep[j]:
            keep[j] = False
    return keep


def check_world_size(config: Kitti05CarsConfig, positions: np.ndarray, path: Path | str) -> None:
    """What the keys' ranges cannot say until the sequence is read: the keyframes, and what
    the parking keys make of its path (street samples, their revisit pairs, cars and their
    neighbours), refused before any of it is made."""
    p = config.parking
    require(
        len(positions) <= MAX_KEYFRAMES,
        path,
        f"sequence.data_dir holds {len(positions)} poses; at most {MAX_KEYFRAMES}",
    )
    length = float(np.linalg.norm(np.diff(positions, axis=0), axis=1).sum())
    samples = length / p.path_step_m
    require(
        samples <= MAX_STREET_SAMPLES,
        path,
        f"parking.path_step_m ({p.path_step_m:g} m) cuts the {length:.0f} m path into "
        f"{samples:.3g} samples; at most {MAX_STREET_SAMPLES}",
    )
    pairs = samples * p.revisit_radius_m / p.path_step_m
    require(
        pairs <= MAX_NEAR_PAIRS,
        path,
        f"parking.revisit_radius_m / path_step_m ({p.revisit_radius_m:g} / {p.path_step_m:g}) "
        f"over {samples:.3g} samples makes {pairs:.3g} pairs to compare; at most {MAX_NEAR_PAIRS}",
    )
    spacing = min(v.length_m for v in config.vehicles) + p.gap_min_m
    cars = 2 * length / spacing
    require(
        cars <= MAX_LANDMARKS,
        path,
        f"[[vehicles]] length_m and parking.gap_min_m (a car every {spacing:g} m at the closest) "
        f"could park {cars:.3g} cars along the {length:.0f} m path; at most {MAX_LANDMARKS}",
    )
    pairs = cars * (2 * p.min_separation_m / spacing + 1)
    require(
        pairs <= MAX_NEAR_PAIRS,
        path,
        f"parking.min_separation_m ({p.min_separation_m:g} m) over cars {spacing:g} m apart "
        f"makes {pairs:.3g} pairs to compare; at most {MAX_NEAR_PAIRS}",
    )


def build_world(config: Kitti05CarsConfig, path: Path | str) -> Kitti05World:
    times_ns, poses = read_sequence(config.sequence)
    check_world_size(config, poses[:, :3, 3], path)
    street = street_of(poses[:, :3, 3], config.parking)
    rng = np.random.default_rng(config.world_seed)
    car_poses, car_types, car_sizes = park_cars(
        street, config.sequence.camera_height_m, config.parking, config.vehicles, rng
    )
    logger.debug(
        "%s: %d cars along %.0f m of new street", NAME, len(car_types), street.first_visit.sum()
    )
    return Kitti05World(times_ns, poses, car_poses, car_types, car_sizes)


# --- the camera and the detector ------------------------------------------------------------

CAMERA_FROM_BODY_ROTATION = BODY_FROM_CAMERA[:3, :3].T


def project(points_body: np.ndarray, camera: StereoIntrinsics) -> tuple[np.ndarray, np.ndarray]:
    """Body-frame points (..., 3) to pixels (..., 2) and depths (...,) of the left camera."""
    c = points_body @ CAMERA_FROM_BODY_ROTATION.T
    depth = c[..., 2]
    safe = np.where(np.abs(depth) < 1e-9, 1e-9, depth)
    u = camera.fx * c[..., 0] / safe + camera.cx
    v = camera.fy * c[..., 1] / safe + camera.cy
    return np.stack([u, v], axis=-1), depth


def in_image(pixels: np.ndarray, camera: StereoIntrinsics) -> np.ndarray:
    u, v = pixels[..., 0], pixels[..., 1]
    return (u >= 0) & (u <= camera.width) & (v >= 0) & (v <= camera.height)


def bearing_elevation_pixel_jacobian(pixels: np.ndarray, camera: StereoIntrinsics) -> np.ndarray:
    """d(bearing, elevation) / d(u, v) at (N, 2) pixels, (N, 2, 2).

    With a = (u - cx)/fx and c = (v - cy)/fy: bearing = -atan(a) and
    elevation = -atan(c / sqrt(1 + a^2)) (body x = camera z, y = -camera x, z = -camera y).
    """
    a = (pixels[:, 0] - camera.cx) / camera.fx
    c = (pixels[:, 1] - camera.cy) / camera.fy
    q2 = 1.0 + a * a
    q = np.sqrt(q2)
    jac = np.zeros((len(a), 2, 2))
    jac[:, 0, 0] = -1.0 / (q2 * camera.fx)
    jac[:, 1, 0] = a * c / (q * (q2 + c * c) * camera.fx)
    jac[:, 1, 1] = -q / ((q2 + c * c) * camera.fy)
    return jac


def stereo_range_sigma(
    depth: np.ndarray, distance: np.ndarray, camera: StereoIntrinsics, sigma_d: float
) -> np.ndarray:
    """sigma of the range: sigma_z = z^2 sigma_d / (f b), stretched along the ray by r / z."""
    sigma_z = depth**2 * sigma_d / (camera.fx * camera.baseline)
    return sigma_z * distance / depth


def measurement_covariances(
    pixels: np.ndarray,
    depth: np.ndarray,
    distance: np.ndarray,
    camera: StereoIntrinsics,
    d: DetectorConfig,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(covariances (N, 3, 3), pixel Jacobians (N, 2, 2), range sigmas (N,)) of detections."""
    jac = bearing_elevation_pixel_jacobian(pixels, camera)
    sigma_r = stereo_range_sigma(depth, distance, camera, d.disparity_sigma_px)
    cov = np.zeros((len(depth), 3, 3))
    cov[:, :2, :2] = d.pixel_sigma_px**2 * jac @ np.swapaxes(jac, 1, 2)
    cov[:, 2, 2] = sigma_r**2
    return cov, jac, sigma_r


def box_corners(poses: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    """(N, 8, 3) corners of boxes with centre/heading `poses` and (length, width, height)."""
    local = _BOX_CORNERS[None, :, :] * sizes[:, None, :]
    return np.einsum("nij,nkj->nki", poses[:, :3, :3], local) + poses[:, None, :3, 3]


def bounding_boxes(corners_body: np.ndarray, camera: StereoIntrinsics) -> np.ndarray:
    """(N, 4) image boxes [u_min, v_min, u_max, v_max] of body-frame corners, clipped."""
    pixels, depth = project(corners_body, camera)
    front = (depth > _NEAR_PLANE_M)[..., None]
    lo = np.where(front, pixels, np.inf).min(axis=1)
    hi = np.where(front, pixels, -np.inf).max(axis=1)
    size = np.array([camera.width, camera.height], dtype=float)
    lo, hi = np.clip(lo, 0.0, size), np.clip(hi, 0.0, size)
    return np.concatenate([lo, hi], axis=1)


@dataclass
class DetectionBatch:
    """Detections as arrays, one row each (true ones and false alarms alike)."""

    pose_index: np.ndarray
    truth: np.ndarray  # landmark id, -1 for a false alarm
    kind: np.ndarray  # vehicle type (true, or the phantom's)
    measured: np.ndarray  # (n, 3) bearing, elevation, range
    covariance: np.ndarray  # (n, 3, 3)
    bbox: np.ndarray  # (n, 4)
    score: np.ndarray


def cars_in_view(
    world: Kitti05World, camera: StereoIntrinsics, d: DetectorConfig
) -> Iterator[tuple[slice, tuple[np.ndarray, ...]]]:
    """For each block of poses, (pose index, car, body-frame centre, pixel, depth, distance)
    of every car whose centre is in view and range from them."""
    centres = world.car_poses[:, :3, 3]
    for poses in blocks(len(world.poses), len(centres)):
        rotations, origins = world.poses[poses, :3, :3], world.poses[poses, :3, 3]
        local = np.einsum("nji,nmj->nmi", rotations, centres[None] - origins[:, None])  # (n, M, 3)
        pixels, depth = project(local, camera)
        distance = np.linalg.norm(local, axis=-1)
        candidate = (
            (depth >= d.min_depth_m) & (distance <= d.max_range_m) & in_image(pixels, camera)
        )
        pose_index, car = np.nonzero(candidate)
        yield (
            poses,
            (
                pose_index + poses.start,
                car,
                local[pose_index, car],
                pixels[pose_index, car],
                depth[pose_index, car],
                distance[pose_index, car],
            ),
        )


def detect_cars(
    world: Kitti05World,
    camera: StereoIntrinsics,
    d: DetectorConfig,
    streams: dict[str, np.random.Generator],
    candidates: tuple[np.ndarray, ...],
) -> DetectionBatch:
    """The cars in view (`candidates`, from `cars_in_view`) that the detector scores above its
    threshold, with noise."""
    rotations, origins = world.poses[:, :3, :3], world.poses[:, :3, 3]
    pose_index, car, local, pixels, depth, distance = candidates
    # Confidence falls with range; below the threshold the car is missed.
    mean = d.score_logit_near + (d.score_logit_far - d.score_logit_near) * distance / d.max_range_m
    score = logistic(mean + d.score_logit_sigma * streams["visibility"].standard_normal(len(car)))
    kept = score >= d.score_threshold
    pose_index, car, local, pixels, depth, distance, score = (
        a[kept] for a in (pose_index, car, local, pixels, depth, distance, score)
    )
    cov, jac, sigma_r = measurement_covariances(pixels, depth, distance, camera, d)
    rng = streams["measurement"]
    pixel_noise = d.pixel_sigma_px * rng.standard_normal((len(car), 2))
    range_noise = sigma_r * rng.standard_normal(len(car))
    measured = bearing_elevation_range(local)
    measured[:, :2] += np.einsum("nij,nj->ni", jac, pixel_noise)
    measured[:, 2] += range_noise
    corners = box_corners(world.car_poses[car], world.car_sizes[car])
    corners_body = np.einsum(
        "nji,nkj->nki", rotations[pose_index], corners - origins[pose_index][:, None, :]
    )
    size = np.array([camera.width, camera.height, camera.width, camera.height], dtype=float)
    bbox = np.clip(bounding_boxes(corners_body, camera) + np.tile(pixel_noise, 2), 0.0, size)
    return DetectionBatch(pose_index, car, world.car_types[car], measured, cov, bbox, score)


def false_alarms(
    num_frames: int, config: Kitti05CarsConfig, rng: np.random.Generator
) -> DetectionBatch:
    """Phantom car-sized boxes standing on the road plane in view, scored like any detection."""
    camera, d = config.camera, config.detector
    count = rng.poisson(d.false_alarms_per_frame, num_frames)
    pose_index = np.repeat(np.arange(num_frames), count)
    n = len(pose_index)
    kind = rng.choice(len(config.vehicles), size=n, p=type_shares(config.vehicles))
    sizes = np.array([[v.length_m, v.width_m, v.height_m] for v in config.vehicles])[kind]
    u = rng.uniform(0.0, camera.width, n)
    depth = rng.uniform(d.min_depth_m, d.max_range_m, n)
    score = logistic(d.false_alarm_logit_mean + d.score_logit_sigma * rng.standard_normal(n))
    height_below = config.sequence.camera_height_m - sizes[:, 2] / 2
    camera_points = np.stack([(u - camera.cx) * depth / camera.fx, height_below, depth], -1)
    local = camera_points @ BODY_FROM_CAMERA[:3, :3].T
    pixels, _ = project(local, camera)
    distance = np.linalg.norm(local, axis=-1)
    kept = (score >= d.score_threshold) & in_image(pixels, camera) & (distance <= d.max_range_m)
    pose_index, kind, sizes, local, pixels, depth, distance, score = (
        a[kept] for a in (pose_index, kind, sizes, local, pixels, depth, distance, score)
    )
    cov, _, _ = measurement_covariances(pixels, depth, distance, camera, d)
    boxes = np.tile(np.eye(4), (len(kind), 1, 1))
    boxes[:, :3, 3] = local  # facing the camera, in the body frame of the frame's pose
    bbox = bounding_boxes(box_corners(boxes, sizes), camera)
    truth = np.full(len(kind), -1)
    return DetectionBatch(pose_index, truth, kind, bearing_elevation_range(local), cov, bbox, score)


def _concatenate(a: DetectionBatch, b: DetectionBatch) -> DetectionBatch:
    return DetectionBatch(
        *(
            np.concatenate([getattr(a, f), getattr(b, f)])
            for f in DetectionBatch.__dataclass_fields__
        )
    )


# --- the run --------------------------------------------------------------------------------


def simulate(
    config: Kitti05CarsConfig, options: SimulationOptions, config_path: Path | None = None
) -> SimulatedRun:
    """The sequence's run: KITTI's own path past the cars parked for `config`, the detector's
    scores, misses, noise and false alarms drawn from `options.seed`."""
    world = build_world(config, config_path or cfg.default_config_path(NAME))
    streams = random_streams(options.seed)
    num_classes = options.num_classes

    def detections() -> Iterator[list[Detection]]:
        """Each pose's detections, made a piece of the run at a time."""
        d = config.detector
        in_view = cars_in_view(world, config.camera, d)
        for piece, candidates in pieces(in_view, d.false_alarms_per_frame):
            phantoms = false_alarms(piece.stop - piece.start, config, streams["false_positives"])
            phantoms.pose_index += piece.start
            batch = _concatenate(
                detect_cars(world, config.camera, d, streams, candidates), phantoms
            )
            reported = reported_classes(options, batch.kind, streams["classes"])
            yield from detection_frames(
                piece,
                batch.pose_index,
                batch.measured,
                batch.covariance,
                reported,
                batch.truth,
                "bbox",
                score=batch.score,
                bbox=batch.bbox,
            )

    return SimulatedRun(
        times_ns=world.times_ns,
        poses=world.poses,
        odometry=noisy_odometry(config.odometry, options, world.poses, streams["odometry"]),
        detections=detections(),
        landmarks=truth_landmarks(world.car_poses[:, :3, 3], world.car_types % num_classes),
        confusion=options.confusion,
        class_names=vehicle_class_names(config.vehicles, num_classes),
        calibration=config.camera.calibration_message(int(world.times_ns[0])),
    )
