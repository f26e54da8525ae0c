"""A simulated run written as a contract-v1 log, with the covariances it states, and the
figures of what was written."""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from data_tools.scenarios.common import MeasuredOdometry, SimulatedRun, SimulationOptions, floats
from data_tools.scenarios.geometry import path_length, quaternion_from_rotation
from data_tools.stated_noise import StatedNoise, restate_detection, restated_covariance
from pipeline.foxglove.log_topics import foxglove_mirror
from pipeline.log import (
    Detection,
    Detections,
    GroundTruthLandmarks,
    GroundTruthPose,
    LogWriter,
    Odometry,
)

logger = logging.getLogger(__name__)


@dataclass
class DetectionCounts:
    """What a run's detections held, counted as they were written."""

    detections: int = 0
    false_positives: int = 0
    landmarks_seen: set[int] = field(default_factory=set)

    def add(self, frame: Sequence[Detection]) -> None:
        self.detections += len(frame)
        for detection in frame:
            if detection.truth_landmark_id == -1:
                self.false_positives += 1
            else:
                self.landmarks_seen.add(detection.truth_landmark_id)


@dataclass(frozen=True)
class SimulationSummary:
    """What `simulate` wrote, in figures."""

    scenario: str
    out: Path
    seed: int
    num_poses: int
    num_detections: int
    num_false_positives: int
    num_landmarks: int
    num_landmarks_seen: int
    num_classes: int
    path_length_m: float
    duration_s: float
    odom_noise_scale: float
    misclassification: float
    true_covariance: bool

    def summary_line(self) -> str:
        return (
            f"{self.scenario}: {self.num_poses} poses over {self.path_length_m:.1f} m "
            f"({self.duration_s:.0f} s), {self.num_detections} detections "
            f"({self.num_false_positives} false) of {self.num_landmarks_seen}/"
            f"{self.num_landmarks} landmarks, {self.num_classes} classes -> {self.out}"
        )


def source_text(scenario: str, options: SimulationOptions, config: Path | None) -> str:
    text = (
        f"mmslam simulate {scenario} --seed {options.seed} --odom-noise-scale "
        f"{options.odom_noise_scale:g} --misclassification {options.misclassification:g} "
        f"--num-classes {options.num_classes}"
    )
    if options.true_covariance:
        text += " --true-covariance"
    if not options.stated.is_identity:
        text += " " + options.stated.describe()
    if config is not None:
        text += f" --config {config}"
    return text


def restated(run: SimulatedRun, stated: StatedNoise) -> SimulatedRun:
    """`run` with its stated covariances scaled as `stated` says (`data_tools.stated_noise`)."""
    if stated.is_identity:
        return run
    stated_now = run.odometry.covariance
    covariance = [
        restated_covariance(tuple(matrix), stated.odometry)
        for matrix in np.reshape(stated_now, (-1, 36))
    ]
    return dataclasses.replace(
        run,
        odometry=MeasuredOdometry(run.odometry.steps, np.reshape(covariance, stated_now.shape)),
        detections=([restate_detection(d, stated) for d in frame] for frame in run.detections),
    )


def write_log(path: Path, run: SimulatedRun, source: str, foxglove: bool = True) -> DetectionCounts:
    """Write `run` as a contract-v1 log made by `source` (`source_text`), messages in time
    order; return what its detections held.

    At the first stamp: ground-truth landmarks (and calibration); then for every pose k, at its
    stamp: the odometry that reaches it (k-1 to k), its ground-truth pose, its detections. A
    detection message is written for every pose, empty or not, so keyframes are explicit. A run
    without `ground_truth` leaves out the landmarks and poses.
    """
    n = len(run.poses)
    quaternions = quaternion_from_rotation(run.poses[:, :3, :3])
    odom_quaternions = quaternion_from_rotation(run.odometry.steps[:, :3, :3])
    covariances = run.odometry.covariance
    shared = floats(covariances) if covariances.ndim == 2 else None
    stamps = [int(t) for t in run.times_ns]
    counts = DetectionCounts()
    frames = iter(run.detections)
    mirror = foxglove_mirror if foxglove else None
    with LogWriter(path, run.metadata(source), mirror) as writer:
        if run.ground_truth:
            landmarks = tuple(run.landmarks)
            writer.write(GroundTruthLandmarks(stamp_ns=stamps[0], landmarks=landmarks))
        if run.calibration is not None:
            writer.write(run.calibration)
        for k, frame in zip(range(n), frames, strict=True):
            if k > 0:
                writer.write(
                    Odometry(
                        stamp_ns=stamps[k],
                        from_index=k - 1,
                        to_index=k,
                        translation=floats(run.odometry.steps[k - 1, :3, 3]),  # type: ignore[arg-type]
                        rotation=floats(odom_quaternions[k - 1]),  # type: ignore[arg-type]
                        covariance=floats(covariances[k - 1]) if shared is None else shared,
                    )
                )
            if run.ground_truth:
                writer.write(
                    GroundTruthPose(
                        stamp_ns=stamps[k],
                        pose_index=k,
                        translation=floats(run.poses[k, :3, 3]),  # type: ignore[arg-type]
                        rotation=floats(quaternions[k]),  # type: ignore[arg-type]
                    )
                )
            writer.write(Detections(stamp_ns=stamps[k], pose_index=k, detections=tuple(frame)))
            counts.add(frame)
    logger.info("wrote %s: %d poses, %d detections", path, n, counts.detections)
    return counts


def summarise(
    scenario: str,
    out: Path,
    options: SimulationOptions,
    run: SimulatedRun,
    counts: DetectionCounts,
) -> SimulationSummary:
    return SimulationSummary(
        scenario=scenario,
        out=out,
        seed=options.seed,
        num_poses=len(run.poses),
        num_detections=counts.detections,
        num_false_positives=counts.false_positives,
        num_landmarks=len(run.landmarks),
        num_landmarks_seen=len(counts.landmarks_seen),
        num_classes=options.num_classes,
        path_length_m=path_length(run.poses[:, :3, 3]),
        duration_s=float(run.times_ns[-1] - run.times_ns[0]) * 1e-9,
        odom_noise_scale=options.odom_noise_scale,
        misclassification=options.misclassification,
        true_covariance=options.true_covariance,
    )
