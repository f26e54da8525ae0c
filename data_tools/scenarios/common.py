"""What every scenario shares: the run options, the simulated run, and writing it as a log."""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from data_tools.scenarios.geometry import path_length, quaternion_from_rotation
from data_tools.stated_noise import StatedNoise, restate_detection, restated_covariance
from pipeline.log import (
    Detection,
    Detections,
    GroundTruthLandmark,
    GroundTruthLandmarks,
    GroundTruthPose,
    LogMetadata,
    LogWriter,
    Odometry,
    StereoCalibration,
)

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class SimulationOptions:
    """The command-line knobs of `mmslam simulate`, checked by `simulate`."""

    seed: int
    odom_noise_scale: float
    misclassification: float
    num_classes: int
    true_covariance: bool
    # what the log states over the covariance it would state (the truth's or the calibrated)
    stated: StatedNoise = field(default_factory=StatedNoise)


@dataclass
class SimulatedRun:
    """A whole simulated run, ready to be written: truth, odometry and detections."""

    times_ns: np.ndarray  # (N,) int
    poses: np.ndarray  # (N, 4, 4) true body poses, pose 0 at identity
    odometry: np.ndarray  # (N-1, 4, 4) measured motion of pose k+1 in the frame of pose k
    odometry_covariance: np.ndarray  # (6, 6), as written to the log
    detections: list[list[Detection]]  # per pose
    landmarks: list[GroundTruthLandmark]
    metadata: LogMetadata
    calibration: StereoCalibration | None = None

    @property
    def num_detections(self) -> int:
        return sum(len(d) for d in self.detections)

    @property
    def num_false_positives(self) -> int:
        return sum(1 for frame in self.detections for d in frame if d.truth_landmark_id == -1)

    @property
    def num_landmarks_seen(self) -> int:
        seen = {d.truth_landmark_id for frame in self.detections for d in frame}
        seen.discard(-1)
        return len(seen)


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


def vehicle_class_names(vehicles: Sequence, num_classes: int) -> list[str]:
    """Vehicle type k (anything with a `name`) is class k mod C; a class's name lists the
    types it holds."""
    names = []
    for c in range(num_classes):
        members = [v.name for k, v in enumerate(vehicles) if k % num_classes == c]
        names.append("+".join(members) if members else f"class-{c}")
    return names


def floats(values: np.ndarray) -> tuple[float, ...]:
    """Plain Python floats for the JSON encoder (the same bits, whatever numpy's type)."""
    return tuple(float(v) for v in np.ravel(values))


def metadata_for(
    num_classes: int, confusion: np.ndarray, class_names: list[str], source: str
) -> LogMetadata:
    return LogMetadata(
        num_classes=num_classes,
        confusion_matrix=tuple(floats(row) for row in confusion),
        class_names=tuple(class_names),
        source=source,
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
    covariance = restated_covariance(tuple(np.ravel(run.odometry_covariance)), stated.odometry)
    return dataclasses.replace(
        run,
        odometry_covariance=np.reshape(covariance, (6, 6)),
        detections=[[restate_detection(d, stated) for d in frame] for frame in run.detections],
    )


def write_log(path: Path, run: SimulatedRun, foxglove: bool = True) -> None:
    """Write `run` as a contract-v1 log, messages in time order.

    At the first stamp: ground-truth landmarks (and calibration); then for every pose k, at its
    stamp: the odometry that reaches it (k-1 to k), its ground-truth pose, its detections. A
    detection message is written for every pose, empty or not, so keyframes are explicit.
    """
    n = len(run.poses)
    quaternions = quaternion_from_rotation(run.poses[:, :3, :3])
    odom_quaternions = quaternion_from_rotation(run.odometry[:, :3, :3])
    covariance = floats(run.odometry_covariance)
    stamps = [int(t) for t in run.times_ns]
    with LogWriter(path, run.metadata, foxglove=foxglove) as writer:
        writer.write(GroundTruthLandmarks(stamp_ns=stamps[0], landmarks=tuple(run.landmarks)))
        if run.calibration is not None:
            writer.write(run.calibration)
        for k in range(n):
            if k > 0:
                writer.write(
                    Odometry(
                        stamp_ns=stamps[k],
                        from_index=k - 1,
                        to_index=k,
                        translation=floats(run.odometry[k - 1, :3, 3]),  # type: ignore[arg-type]
                        rotation=floats(odom_quaternions[k - 1]),  # type: ignore[arg-type]
                        covariance=covariance,
                    )
                )
            writer.write(
                GroundTruthPose(
                    stamp_ns=stamps[k],
                    pose_index=k,
                    translation=floats(run.poses[k, :3, 3]),  # type: ignore[arg-type]
                    rotation=floats(quaternions[k]),  # type: ignore[arg-type]
                )
            )
            writer.write(
                Detections(stamp_ns=stamps[k], pose_index=k, detections=tuple(run.detections[k]))
            )
    logger.info("wrote %s: %d poses, %d detections", path, n, run.num_detections)


def summarise(
    scenario: str, out: Path, options: SimulationOptions, run: SimulatedRun
) -> SimulationSummary:
    return SimulationSummary(
        scenario=scenario,
        out=out,
        seed=options.seed,
        num_poses=len(run.poses),
        num_detections=run.num_detections,
        num_false_positives=run.num_false_positives,
        num_landmarks=len(run.landmarks),
        num_landmarks_seen=run.num_landmarks_seen,
        num_classes=options.num_classes,
        path_length_m=path_length(run.poses[:, :3, 3]),
        duration_s=float(run.times_ns[-1] - run.times_ns[0]) * 1e-9,
        odom_noise_scale=options.odom_noise_scale,
        misclassification=options.misclassification,
        true_covariance=options.true_covariance,
    )
