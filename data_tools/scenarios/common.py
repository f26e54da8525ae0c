"""What every scenario shares: the run options, the simulated run, and the making of it.

A run's memory is bounded whatever its length: landmark-keyframe pairs are tested for
visibility in blocks (`blocks`), and the detections are made piece by piece as the log is
written (`pieces`), a piece being consecutive keyframes whose candidate detections number at
most `DETECTIONS_PER_PIECE`. A piece's random draws are made in one go, in the order a whole
run's would be, so a run of one piece (every shipped configuration) draws as it always has.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from scipy.spatial import cKDTree

from data_tools.scenarios.geometry import inside_any, relative_poses
from data_tools.scenarios.noise import (
    OdometryNoiseConfig,
    confusion_matrix,
    corrupt_odometry,
    odometry_covariances,
    sample_reported_classes,
)
from data_tools.stated_noise import StatedNoise
from pipeline.log import (
    Detection,
    GroundTruthLandmark,
    LogMetadata,
    RelativePose,
    StereoCalibration,
)


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

    @property
    def confusion(self) -> np.ndarray:
        """The detector's confusion matrix: each of `num_classes` classes reported as another
        with probability `misclassification` (`noise.confusion_matrix`)."""
        return confusion_matrix(self.num_classes, self.misclassification)


def reported_classes(
    options: SimulationOptions, kinds: np.ndarray, rng: np.random.Generator
) -> np.ndarray:
    """The classes a detector reports for objects of `kinds` (kind k is class k mod C), each
    drawn from `rng` through the options' confusion matrix."""
    return sample_reported_classes(rng, kinds % options.num_classes, options.confusion)


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


def lines_inside(
    start: np.ndarray,
    end: np.ndarray,
    fractions: np.ndarray,
    rectangles: np.ndarray,
    *,
    every: bool,
) -> np.ndarray:
    """(n,) whether the (n, 2) lines from `start` to `end`, sampled at `fractions` of the way,
    have every sample (`every`), or any sample, inside one of the (K, 4) `rectangles`: a line
    of sight that stays on a floor, or one that meets a building. Tested in blocks."""
    result = np.empty(len(start), dtype=bool)
    for rows in blocks(len(start), len(fractions) * len(rectangles)):
        a, b = start[rows], end[rows]
        inside = inside_any(a[:, None] + fractions[None, :, None] * (b - a)[:, None], rectangles)
        result[rows] = inside.all(axis=1) if every else inside.any(axis=1)
    return result


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


@dataclass(frozen=True)
class MeasuredOdometry:
    """The odometry as a log states it: each step's measured motion, and the covariance stated
    for it."""

    steps: np.ndarray  # (N-1, 4, 4) measured motion of pose k+1 in the frame of pose k
    covariance: np.ndarray  # (6, 6) stated for every step, or (N-1, 6, 6) one a step


@dataclass
class SimulatedRun:
    """A simulated run, ready to be written: truth, odometry, and the detections of each pose
    in order (made piece by piece as they are read, once)."""

    times_ns: np.ndarray  # (N,) int
    poses: np.ndarray  # (N, 4, 4) true body poses, pose 0 at identity
    odometry: MeasuredOdometry
    detections: Iterable[list[Detection]]  # per pose
    landmarks: list[GroundTruthLandmark]
    confusion: np.ndarray  # (C, C) the detector's, as the log states it
    class_names: list[str]  # C of them
    calibration: StereoCalibration | None = None
    ground_truth: bool = True  # False: the log holds no truth (poses, landmarks), as a robot's

    def metadata(self, source: str) -> LogMetadata:
        """The log's metadata record: the run's classes, and `source`, what made it."""
        return LogMetadata(
            num_classes=len(self.class_names),
            confusion_matrix=tuple(floats(row) for row in self.confusion),
            class_names=tuple(self.class_names),
            source=source,
        )


def floats(values: np.ndarray) -> tuple[float, ...]:
    """Plain Python floats for the JSON encoder (the same bits, whatever numpy's type)."""
    return tuple(float(v) for v in np.ravel(values))


def noisy_odometry(
    config: OdometryNoiseConfig,
    options: SimulationOptions,
    poses: np.ndarray,
    rng: np.random.Generator,
) -> MeasuredOdometry:
    """The odometry between consecutive `poses` with the noise `config` (scaled as `options`
    say) drawn from `rng`, and the covariance the log states for it: the calibrated model's, or
    with `true_covariance` that of the noise drawn."""
    calibrated, true = odometry_covariances(config, options.odom_noise_scale)
    steps = corrupt_odometry(rng, relative_poses(poses), true)
    return MeasuredOdometry(steps, true if options.true_covariance else calibrated)


def first_pose_frame(poses: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 4, 4) `poses` and (M, 3) `points` in the frame of the first pose, where a log's
    trajectory starts."""
    origin = np.linalg.inv(poses[0])
    return origin @ poses, points @ origin[:3, :3].T + origin[:3, 3]


def detection_frames(
    piece: slice,
    pose_index: np.ndarray,
    measured: np.ndarray,
    covariance: np.ndarray,
    class_id: np.ndarray,
    truth: np.ndarray,
    source: Literal["apriltag", "bbox"],
    *,
    score: np.ndarray | None = None,
    bbox: np.ndarray | None = None,
    relative_pose: Sequence[RelativePose] | None = None,
) -> list[list[Detection]]:
    """A piece's detections keyframe by keyframe, each keyframe's left to right by bearing, as
    in an image or as a scanner sweeps, so that their order gives no hint of the truth.

    Detection k, made at keyframe `pose_index[k]`, is `measured[k]` (bearing, elevation,
    range) with `covariance` (one (3, 3) for all, or `covariance[k]`), reported as `class_id[k]`
    and truly landmark `truth[k]` (-1: a false alarm); scored 1 unless `score` says, with
    `bbox[k]` and `relative_pose[k]` where given.
    """
    shared = floats(covariance) if covariance.ndim == 2 else None
    detections = [
        Detection(
            class_id=int(class_id[k]),
            score=1.0 if score is None else float(score[k]),
            bearing=float(measured[k, 0]),
            elevation=float(measured[k, 1]),
            range=float(measured[k, 2]),
            covariance=floats(covariance[k]) if shared is None else shared,  # type: ignore[arg-type]
            source=source,
            bbox=None if bbox is None else floats(bbox[k]),  # type: ignore[arg-type]
            relative_pose=None if relative_pose is None else relative_pose[k],
            truth_landmark_id=int(truth[k]),
        )
        for k in range(len(pose_index))
    ]
    frames: list[list[Detection]] = [[] for _ in range(piece.stop - piece.start)]
    for k in np.lexsort((-measured[:, 0], pose_index)):
        frames[pose_index[k] - piece.start].append(detections[k])
    return frames


def truth_landmarks(positions: np.ndarray, classes: Iterable[int]) -> list[GroundTruthLandmark]:
    """The true landmarks, landmark m at `positions[m]` of class `classes[m]`."""
    return [
        GroundTruthLandmark(id=m, class_id=int(c), position=floats(p))  # type: ignore[arg-type]
        for m, (p, c) in enumerate(zip(positions, classes, strict=True))
    ]
