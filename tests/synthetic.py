"""Small logs the tests write themselves: a path, point landmarks, and what a robot sees."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import gtsam
import numpy as np

from data_tools.scenarios.common import MeasuredOdometry, SimulatedRun, truth_landmarks
from data_tools.scenarios.writing import write_log
from pipeline.geometry import bearing_elevation_range
from pipeline.log import Detection

ODOM_SIGMAS = np.array([1e-3, 1e-3, 2e-3, 0.02, 0.01, 0.005])  # rx ry rz tx ty tz
MEAS_SIGMAS = np.array([0.01, 0.01, 0.1])  # bearing, elevation, range


@dataclass
class Scene:
    poses: list[gtsam.Pose3]
    landmarks: np.ndarray  # (M, 3)
    classes: np.ndarray  # (M,)
    num_classes: int = 2
    confusion: np.ndarray | None = None
    max_range: float = 12.0
    # (pose index, landmark) pairs to observe; None: every landmark within range.
    sightings: list[tuple[int, int]] | None = None
    # (pose index, landmark) pairs whose detection reports another class
    misreports: set[tuple[int, int]] = field(default_factory=set)
    # pose index -> (odometry the log reports reaching it, its 6 tangent sigmas), for steps
    # where the odometry is wrong and says how uncertain it is
    odometry_overrides: dict[int, tuple[gtsam.Pose3, np.ndarray]] = field(default_factory=dict)

    def visible(self) -> list[tuple[int, int]]:
        if self.sightings is not None:
            return self.sightings
        out = []
        for i, pose in enumerate(self.poses):
            for j, lm in enumerate(self.landmarks):
                p = pose.transformTo(lm)
                if np.linalg.norm(p) < self.max_range and p[0] > 0.5:
                    out.append((i, j))
        return out


def square_loop(side: float = 20.0, step: float = 1.0, laps: float = 1.0) -> list[gtsam.Pose3]:
    """A square driven counter-clockwise, poses every `step` metres, turning at the corners."""
    poses = [gtsam.Pose3()]
    per_side = round(side / step)
    total_sides = round(4 * laps)
    for _ in range(total_sides):
        for k in range(per_side):
            turn = np.pi / 2 if k == per_side - 1 else 0.0
            delta = gtsam.Pose3(gtsam.Rot3.Yaw(turn), np.array([step, 0.0, 0.0]))
            poses.append(poses[-1].compose(delta))
    return poses


def write_scene(
    path: Path,
    scene: Scene,
    seed: int = 0,
    odom_noise: float = 1.0,
    meas_noise: float = 1.0,
    truth_ids: bool = True,
    ground_truth: bool = True,
    start_ns: int = 1_000_000_000,
) -> Path:
    """Write the scene as a contract-v1 log, its poses 0.1 s apart from `start_ns`; noise
    scales 0 give exact measurements."""
    rng = np.random.default_rng(seed)
    C = scene.num_classes
    meas_cov = tuple(np.diag(MEAS_SIGMAS**2).ravel())
    by_pose: dict[int, list[int]] = {}
    for i, j in scene.visible():
        by_pose.setdefault(i, []).append(j)
    steps, step_sigmas, frames = [], [], []
    # Pose by pose, its odometry's noise drawn before its detections'.
    for i, pose in enumerate(scene.poses):
        if i in scene.odometry_overrides:
            reported, sigmas = scene.odometry_overrides[i]
            steps.append(reported.matrix())
            step_sigmas.append(sigmas)
        elif i > 0:
            true_step = scene.poses[i - 1].between(pose)
            noise = gtsam.Pose3.Expmap(rng.normal(size=6) * ODOM_SIGMAS * odom_noise)
            steps.append(true_step.compose(noise).matrix())
            step_sigmas.append(ODOM_SIGMAS)
        dets = []
        for j in by_pose.get(i, []):
            z = bearing_elevation_range(pose.transformTo(scene.landmarks[j]))
            z = z + rng.normal(size=3) * MEAS_SIGMAS * meas_noise
            reported = int(scene.classes[j])
            if (i, j) in scene.misreports:
                reported = (reported + 1) % C
            dets.append(
                Detection(
                    class_id=reported,
                    score=0.9,
                    bearing=float(z[0]),
                    elevation=float(z[1]),
                    range=float(z[2]),
                    covariance=meas_cov,
                    source="bbox",
                    truth_landmark_id=j if truth_ids else None,
                )
            )
        frames.append(dets)
    run = SimulatedRun(
        times_ns=start_ns + np.arange(len(scene.poses)) * 100_000_000,
        poses=np.array([pose.matrix() for pose in scene.poses]),
        odometry=MeasuredOdometry(
            np.reshape(steps, (-1, 4, 4)),
            np.reshape([np.diag(sigmas**2) for sigmas in step_sigmas], (-1, 6, 6)),
        ),
        detections=frames,
        landmarks=truth_landmarks(scene.landmarks, scene.classes),
        confusion=scene.confusion if scene.confusion is not None else np.eye(C),
        class_names=[f"class{c}" for c in range(C)],
        ground_truth=ground_truth,
    )
    write_log(path, run, "tests/synthetic.py")
    return path


KIDNAP_POSE = 5
KIDNAP_SHIFT_M = 6.0


def kidnap_scene(alias_seen_before: bool, shift: float = KIDNAP_SHIFT_M) -> tuple[Scene, int, int]:
    """A robot that slides `shift` metres sideways at pose 5 while its odometry says it went
    straight (and admits that much uncertainty). From there, landmark `alias` (class 0) appears
    exactly where the drifted estimate expects landmark `lookalike`, also class 0, seen before
    the slide; seven class-1 landmarks seen before and after the slide tell the truth.

    `alias_seen_before`: the alias was mapped before the slide too (a choice between two known
    landmarks, which a max-mixture resolves by switching), or it is new (only a wrong loop
    closure or the null hypothesis explain it). Returns (scene, lookalike id, alias id).
    """
    straight = gtsam.Pose3(gtsam.Rot3(), np.array([1.0, 0.0, 0.0]))
    poses = [gtsam.Pose3()]
    for i in range(1, 10):
        slide = shift if i == KIDNAP_POSE else 0.0
        poses.append(poses[-1].compose(gtsam.Pose3(gtsam.Rot3(), np.array([1.0, slide, 0.0]))))
    lookalike = np.array([40.0, 6.0, 0.0])
    alias = lookalike + np.array([0.0, shift, 0.0])
    truthful = [[36.0, -8.0, 0.0], [41.0, -12.0, 0.0], [46.0, -6.0, 0.0], [51.0, -13.0, 0.0],
                [56.0, -5.0, 0.0], [61.0, -10.0, 0.0], [66.0, -7.0, 0.0]]  # fmt: skip
    landmarks = np.array([lookalike, alias, *truthful])
    classes = np.array([0, 0] + [1] * len(truthful))
    sightings = []
    for i in range(len(poses)):
        seen = [0 if i < KIDNAP_POSE else 1, *range(2, len(landmarks))]
        if alias_seen_before and i < KIDNAP_POSE:
            seen.append(1)
        sightings += [(i, j) for j in seen]
    sigmas = np.array([1e-3, 1e-3, 1e-3, 0.05, shift, 0.05])
    scene = Scene(
        poses,
        landmarks,
        classes,
        max_range=80.0,
        sightings=sightings,
        odometry_overrides={KIDNAP_POSE: (straight, sigmas)},
    )
    return scene, 0, 1


def small_square_log(path: Path) -> Path:
    """Half a lap of a 6 m square past three landmarks of two classes: a log of a few
    keyframes, for tests of files rather than of the estimate."""
    landmarks = np.array([[5.0, 3.0, 0.0], [9.0, -3.0, 0.0], [3.0, 9.0, 0.0]])
    scene = Scene(square_loop(6.0, 1.0, laps=0.5), landmarks, np.array([0, 1, 0]))
    return write_scene(path, scene, seed=3)
