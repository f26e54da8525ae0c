"""Crowded keyframes, for measuring what a keyframe's number of detections costs: a drive round
a square past point landmarks, whose last keyframe holds `--detections` detections
(`pipeline/log/limits.py`: MAX_DETECTIONS_PER_POSE, 1,000, at most): its own and clutter,
either crowded about the landmarks it sees (boxes on the cars in view, each within reach of
their candidates) or, with `--spread`, false detections spread over the view. The keyframe is
the log's last and a merge check's (every 5th): a replay's time is that of the keyframes
before it (a few seconds) and its own.

    python -m data_tools.crowded_log --detections 1000 --out CROWDED.mcap
    python -m data_tools.crowded_log --detections 1000 --spread --out SPREAD.mcap
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from pipeline.geometry import bearing_elevation_range, quaternion_from_rotation
from pipeline.log import (
    Detection,
    Detections,
    GroundTruthLandmark,
    GroundTruthLandmarks,
    GroundTruthPose,
    LogMetadata,
    LogWriter,
    Odometry,
)

ODOMETRY_SIGMAS = np.array([1e-3, 1e-3, 2e-3, 0.02, 0.01, 0.005])  # rx ry rz tx ty tz
DETECTION_SIGMAS = np.array([0.01, 0.01, 0.1])  # bearing, elevation, range
SIDE_M = 20.0
MAX_RANGE_M = 15.0
CLUTTER_SPREAD_M = 1.0  # clutter lies about this far from a landmark in view
VIEW_HALF_ANGLE = np.pi / 3  # spread clutter: within this bearing either side, ahead


def yaw_pose(x: float, y: float, yaw: float) -> np.ndarray:
    T = np.eye(4)
    T[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
    T[:2, 3] = x, y
    return T


def square_drive(count: int) -> list[np.ndarray]:
    """`count` poses a metre apart counter-clockwise round the square, turning at its corners."""
    poses, x, y, yaw = [], 0.0, 0.0, 0.0
    for k in range(count):
        poses.append(yaw_pose(x, y, yaw))
        x, y = x + np.cos(yaw), y + np.sin(yaw)
        if (k + 1) % int(SIDE_M) == 0:
            yaw += np.pi / 2
    return poses


def landmarks_about(rng: np.random.Generator) -> np.ndarray:
    """(n, 3) landmarks 3-6 m either side of the square's sides, 2 m apart along them."""
    along = np.arange(1.0, SIDE_M, 2.0)
    points = []
    for side in range(4):
        for s in along:
            offset = rng.uniform(3.0, 6.0) * rng.choice([-1.0, 1.0])
            local = np.array([s, offset, rng.uniform(-0.5, 0.5)])
            corner = yaw_pose(*[(0, 0), (SIDE_M, 0), (SIDE_M, SIDE_M), (0, SIDE_M)][side], 0.0)
            R = yaw_pose(0.0, 0.0, side * np.pi / 2)[:3, :3]
            points.append(corner[:3, 3] + R @ local)
    return np.array(points)


def in_view(pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Indices of the points ahead of the pose and within range."""
    local = (points - pose[:3, 3]) @ pose[:3, :3]
    return np.flatnonzero((local[:, 0] > 0.5) & (np.linalg.norm(local, axis=1) < MAX_RANGE_M))


def detection(
    pose: np.ndarray, point: np.ndarray, class_id: int, truth: int, rng: np.random.Generator
) -> Detection:
    z = bearing_elevation_range((point - pose[:3, 3]) @ pose[:3, :3])
    z = z + rng.normal(size=3) * DETECTION_SIGMAS
    return Detection(
        class_id=class_id,
        score=0.9,
        bearing=float(z[0]),
        elevation=float(z[1]),
        range=float(z[2]),
        covariance=tuple(np.diag(DETECTION_SIGMAS**2).ravel()),
        source="bbox",
        truth_landmark_id=truth,
    )


def keyframe_detections(
    pose: np.ndarray,
    landmarks: np.ndarray,
    classes: np.ndarray,
    count: int,
    rng: np.random.Generator,
    spread: bool = False,
) -> tuple[Detection, ...]:
    """The landmarks in view, and clutter until the keyframe holds `count` detections (0: no
    clutter): each about a landmark in view, of its class; or, `spread`, anywhere in the view
    (1-15 m ahead, within `VIEW_HALF_ANGLE` either side), of any class."""
    seen = in_view(pose, landmarks)
    own = [detection(pose, landmarks[j], int(classes[j]), int(j), rng) for j in seen]
    clutter = []
    for _ in range(max(0, count - len(own))):
        if spread:
            distance = rng.uniform(1.0, MAX_RANGE_M)
            bearing = rng.uniform(-VIEW_HALF_ANGLE, VIEW_HALF_ANGLE)
            local = [distance * np.cos(bearing), distance * np.sin(bearing), rng.uniform(-0.5, 0.5)]
            point = pose[:3, :3] @ np.array(local) + pose[:3, 3]
            class_id = int(rng.integers(classes.max() + 1))
        else:
            j = int(rng.choice(seen))
            point = landmarks[j] + rng.normal(size=3) * CLUTTER_SPREAD_M * [1.0, 1.0, 0.2]
            class_id = int(classes[j])
        clutter.append(detection(pose, point, class_id, -1, rng))
    return tuple(own + clutter)


def write_crowded_log(
    path: Path,
    detections: int,
    crowded_pose: int = 45,
    classes: int = 2,
    seed: int = 0,
    spread: bool = False,
) -> Path:
    """Write the log: every keyframe sees the landmarks in view; the last, `crowded_pose`,
    holds `detections` detections (by default one on the square's third side, whose
    landmarks in view the keyframes before mapped: its detections have candidates), its
    clutter `spread` over the view or crowded about the landmarks."""
    rng = np.random.default_rng(seed)
    poses = square_drive(crowded_pose + 1)
    landmarks = landmarks_about(rng)
    landmark_classes = np.arange(len(landmarks)) % classes
    identity = tuple(tuple(float(i == j) for j in range(classes)) for i in range(classes))
    metadata = LogMetadata(
        num_classes=classes,
        confusion_matrix=identity,
        class_names=tuple(f"class{c}" for c in range(classes)),
        source="data_tools/crowded_log.py",
    )
    stamp = lambda i: 1_000_000_000 + i * 100_000_000  # noqa: E731
    odometry_covariance = tuple(np.diag(ODOMETRY_SIGMAS**2).ravel())

    def parts(T: np.ndarray) -> tuple[tuple[float, ...], tuple[float, ...]]:
        q = quaternion_from_rotation(T[:3, :3])
        return tuple(float(v) for v in T[:3, 3]), tuple(float(v) for v in q)

    with LogWriter(path, metadata) as writer:
        writer.write(
            GroundTruthLandmarks(
                stamp(0),
                tuple(
                    GroundTruthLandmark(j, int(c), tuple(float(v) for v in p))
                    for j, (p, c) in enumerate(zip(landmarks, landmark_classes, strict=True))
                ),
            )
        )
        for i, pose in enumerate(poses):
            if i > 0:
                step = np.linalg.inv(poses[i - 1]) @ pose
                noise = rng.normal(size=6) * ODOMETRY_SIGMAS
                step = step @ yaw_pose(noise[3], noise[4], noise[2])
                writer.write(Odometry(stamp(i), i - 1, i, *parts(step), odometry_covariance))
            writer.write(GroundTruthPose(stamp(i), i, *parts(pose)))
            count = detections if i == crowded_pose else 0
            seen = keyframe_detections(pose, landmarks, landmark_classes, count, rng, spread)
            writer.write(Detections(stamp(i), i, seen))
    return path


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--detections", type=int, default=1000, help="at the crowded keyframe")
    parser.add_argument("--crowded-pose", type=int, default=45)
    parser.add_argument("--classes", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--spread", action="store_true", help="clutter over the view, not about the landmarks"
    )
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    write_crowded_log(
        args.out, args.detections, args.crowded_pose, args.classes, args.seed, args.spread
    )


if __name__ == "__main__":
    main()
