"""What every scenario shares: the run options, the simulated run, and writing it as a log.

A run's memory is bounded whatever its length: landmark-keyframe pairs are tested for
visibility in blocks (`blocks`), and the detections are made piece by piece as the log is
written (`pieces`), a piece being consecutive keyframes whose candidate detections number at
most `DETECTIONS_PER_PIECE`. A piece's random draws are made in one go, in the order a whole
run's would be, so a run of one piece (every shipped configuration) draws as it always has.
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from data_tools.scenarios.geometry import path_length, quaternion_from_rotation, relative_poses
from data_tools.scenarios.noise import OdometryNoiseConfig, corrupt_odometry, odometry_covariances
from data_tools.stated_noise import StatedNoise, restate_detection, restated_covariance
from pipeline.foxglove.log_topics import foxglove_mirror
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


# Array elements (landmark-keyframe pairs, line-of-sight samples against walls) computed at once.
ELEMENTS_PER_BLOCK = 2**20
# Candidate detections (and false alarms expected) made and held at once.
DETECTIONS_PER_PIECE = 100_000


def blocks(rows: int, elements_per_row: int) -> Iterator[slice]:
    """Consecutive slices of `rows` rows of `elements_per_row` elements each, at most
    `ELEMENTS_PER_BLOCK` elements a slice (one row at least)."""
    step = max(1, ELEMENTS_PER_BLOCK // max(elements_per_row, 1))
    for first in range(0, rows, step):
        yield slice(first, min(first + step, rows))


def within_reach(landmarks: cKDTree, positions: np.ndarray, reach: float) -> np.ndarray:
    """Sorted indices of the landmarks (a tree of their x, y) within `reach` (a little more)
    of any of the (n, 3) `positions` in x, y: those a sensor of that range there may see,
    whatever the heights. The rest need not be tested."""
    found = landmarks.query_ball_point(positions[:, :2], reach * (1 + 1e-9) + 1e-9)
    return np.unique(np.fromiter(itertools.chain.from_iterable(found), dtype=np.intp))


Candidates = tuple[np.ndarray, ...]  # arrays of one row a candidate; the first, its pose index


def _joined(parts: list[Candidates]) -> Candidates:
    return tuple(np.concatenate(columns) for columns in zip(*parts, strict=True))


def pieces(
    chunks: Iterable[tuple[slice, Candidates]], extra_per_pose: float = 0.0
) -> Iterator[tuple[slice, Candidates]]:
    """Regroup the candidates of consecutive keyframe blocks (`chunks`: the poses of a block
    and its candidates, ordered by pose) into pieces of consecutive keyframes, each holding at
    most `DETECTIONS_PER_PIECE` candidates and expected false alarms (`extra_per_pose` each)
    unless one keyframe alone holds more. The pieces do not depend on the blocks."""
    held: list[Candidates] = []
    start, cost, end = 0, 0.0, 0
    for poses, candidates in chunks:
        counts = np.bincount(candidates[0] - poses.start, minlength=poses.stop - poses.start)
        for pose, count in enumerate(counts.tolist(), start=poses.start):
            if cost > 0 and cost + count + extra_per_pose > DETECTIONS_PER_PIECE:
                cut = int(np.searchsorted(candidates[0], pose))
                yield slice(start, pose), _joined([*held, tuple(a[:cut] for a in candidates)])
                candidates = tuple(a[cut:] for a in candidates)
                held, start, cost = [], pose, 0.0
            cost += count + extra_per_pose
        held.append(candidates)
        end = poses.stop
    if held:
        yield slice(start, end), _joined(held)


@dataclass
class SimulatedRun:
    """A simulated run, ready to be written: truth, odometry, and the detections of each pose
    in order (made piece by piece as they are read, once)."""

    times_ns: np.ndarray  # (N,) int
    poses: np.ndarray  # (N, 4, 4) true body poses, pose 0 at identity
    odometry: np.ndarray  # (N-1, 4, 4) measured motion of pose k+1 in the frame of pose k
    odometry_covariance: np.ndarray  # (6, 6), as written to the log
    detections: Iterable[list[Detection]]  # per pose
    landmarks: list[GroundTruthLandmark]
    metadata: LogMetadata
    calibration: StereoCalibration | None = None


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


def noisy_odometry(
    config: OdometryNoiseConfig,
    options: SimulationOptions,
    poses: np.ndarray,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """The odometry between consecutive `poses` with the noise `config` (scaled as `options`
    say) drawn from `rng`, and the covariance the log states for it: the calibrated model's, or
    with `true_covariance` that of the noise drawn."""
    calibrated, true = odometry_covariances(config, options.odom_noise_scale)
    odometry = corrupt_odometry(rng, relative_poses(poses), true)
    return odometry, true if options.true_covariance else calibrated


def frames_by_bearing(
    piece: slice, pose_index: np.ndarray, bearing: np.ndarray, detections: Sequence[Detection]
) -> list[list[Detection]]:
    """A piece's `detections` keyframe by keyframe (candidate k at `pose_index[k]`), each
    keyframe's left to right by `bearing`, as in an image or as a scanner sweeps, so that
    their order gives no hint of the truth."""
    frames: list[list[Detection]] = [[] for _ in range(piece.stop - piece.start)]
    for k in np.lexsort((-bearing, pose_index)):
        frames[pose_index[k] - piece.start].append(detections[k])
    return frames


def truth_landmarks(positions: np.ndarray, classes: Iterable[int]) -> list[GroundTruthLandmark]:
    """The true landmarks, landmark m at `positions[m]` of class `classes[m]`."""
    return [
        GroundTruthLandmark(id=m, class_id=int(c), position=floats(p))  # type: ignore[arg-type]
        for m, (p, c) in enumerate(zip(positions, classes, strict=True))
    ]


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
        detections=([restate_detection(d, stated) for d in frame] for frame in run.detections),
    )


def write_log(path: Path, run: SimulatedRun, foxglove: bool = True) -> DetectionCounts:
    """Write `run` as a contract-v1 log, messages in time order; return what its detections
    held.

    At the first stamp: ground-truth landmarks (and calibration); then for every pose k, at its
    stamp: the odometry that reaches it (k-1 to k), its ground-truth pose, its detections. A
    detection message is written for every pose, empty or not, so keyframes are explicit.
    """
    n = len(run.poses)
    quaternions = quaternion_from_rotation(run.poses[:, :3, :3])
    odom_quaternions = quaternion_from_rotation(run.odometry[:, :3, :3])
    covariance = floats(run.odometry_covariance)
    stamps = [int(t) for t in run.times_ns]
    counts = DetectionCounts()
    frames = iter(run.detections)
    mirror = foxglove_mirror if foxglove else None
    with LogWriter(path, run.metadata, mirror) as writer:
        writer.write(GroundTruthLandmarks(stamp_ns=stamps[0], landmarks=tuple(run.landmarks)))
        if run.calibration is not None:
            writer.write(run.calibration)
        for k, frame in zip(range(n), frames, strict=True):
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
