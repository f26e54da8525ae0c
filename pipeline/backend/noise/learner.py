"""When and how the noise scales a replay uses are learnt: the policy over the estimators."""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal, Protocol

import gtsam
import numpy as np
from gtsam.symbol_shorthand import X

from pipeline.backend.noise.components import ScaleLikelihood, ScaleObservation
from pipeline.backend.noise.contrasts import contrast_observation
from pipeline.backend.noise.drift import DriftWindows
from pipeline.backend.noise.scales import MEASUREMENT_COMPONENTS, ODOMETRY_AXES, NoiseScales
from pipeline.config import NoiseConfig

logger = logging.getLogger(__name__)

Source = Literal["drift windows", "detections"]


class EstimateReader(Protocol):
    """What the learner reads of the estimate: poses and their joint covariance."""

    def pose(self, key: int) -> gtsam.Pose3: ...

    def joint_covariance(self, keys: list[int]) -> np.ndarray: ...


@dataclass(frozen=True)
class HeldDetections:
    """A keyframe's point detections held by landmarks, at the current estimate: the pose,
    each detection's landmark, measurement and stated covariance, and how many detections
    each landmark holds."""

    rotation: np.ndarray  # (3, 3)
    translation: np.ndarray  # (3,)
    landmarks: np.ndarray  # (K, 3)
    measured: np.ndarray  # (K, 3)
    stated: np.ndarray  # (K, 3, 3)
    sightings: np.ndarray  # (K,)


@dataclass(frozen=True)
class NoiseMove:
    """One change of the noise scales of `names`: at which keyframe, on whose evidence (the
    odometry's drift windows, or the disagreement of the detections), each direction's scale before
    and after, and each direction's evidence for leaving its scale (nats; 0: not far enough
    from it to ask)."""

    pose_index: int
    source: Source
    names: tuple[str, ...]
    before: tuple[float, ...]
    after: tuple[float, ...]
    evidence: tuple[float, ...]

    def report(self) -> dict:
        """For metrics.json."""
        return {
            "pose_index": self.pose_index,
            "source": self.source,
            "scales": {
                n: {"from": b, "to": a, "evidence_nats": round(e, 3)}
                for n, b, a, e in zip(
                    self.names, self.before, self.after, self.evidence, strict=True
                )
            },
        }


@dataclass(frozen=True)
class NoiseChange:
    """What a keyframe's learning changed: the odometry's scales, the detections'."""

    odometry: bool = False
    measurement: bool = False

    def __bool__(self) -> bool:
        return self.odometry or self.measurement


class NoiseLearner:
    """The noise scales a replay uses and, where `enabled` (`[noise] estimate`, a method that
    learns them), how they are learnt: every `update_every` keyframes, the odometry's from its
    drift windows (`drift.py`) and the detections' from what each keyframe's detections
    disagree about (`contrasts.py`), each direction moved only on clear evidence
    (`components.ScaleLikelihood.reading`)."""

    def __init__(self, config: NoiseConfig, enabled: bool, planar: bool = False):
        """`planar`: the poses are held in a plane (`planar.py`): a pose's error lies in its
        yaw and its horizontal position only."""
        n = self.config = config
        self.pose_free = np.array([not planar] * 2 + [True] * 3 + [not planar])
        self.enabled = enabled and n.estimate
        self.scales = NoiseScales(tuple(n.odometry_scale), tuple(n.measurement_scale))
        self.bounds = (n.min_scale, n.max_scale)
        self.moves: list[NoiseMove] = []  # in order
        self.drift = DriftWindows(n.drift_window, n.long_drift_window, n.drift_windows)
        self.windows = ScaleLikelihood(ODOMETRY_AXES, n.drift_windows)
        self.contrasts = ScaleLikelihood(MEASUREMENT_COMPONENTS, n.contrasts)
        self._observed_to = 0  # keyframes before this one were looked at for contrasts
        self._fresh = {"drift windows": 0, "detections": 0}  # observations since a reading

    @property
    def watches_drift(self) -> bool:
        """Whether the odometry's steps are wanted (`add_step`)."""
        return self.enabled

    def add_step(self, step: gtsam.Pose3, stated: np.ndarray) -> None:
        """The odometry's next step and its stated covariance."""
        self.drift.add_step(step, stated)

    def learn(
        self,
        pose_index: int,
        estimate: EstimateReader,
        held: Callable[[range], list[HeldDetections]],
    ) -> NoiseChange:
        """Every `update_every` keyframes: the drift windows ending now taken from `estimate`,
        the keyframes since the last time as `held` gives their detections, and each
        estimator read where it has new observations; what moved."""
        n = self.config
        if not self.enabled or pose_index % n.update_every:
            return NoiseChange()
        used = np.array(self.scales.measurement)
        for keyframe in held(range(self._observed_to, pose_index + 1)):
            observation = contrast_observation(
                keyframe.rotation,
                keyframe.translation,
                keyframe.landmarks,
                keyframe.measured,
                keyframe.stated,
                keyframe.sightings,
                used,
                self.pose_free,
            )
            if observation is not None:
                self.contrasts.add(observation)
                self._fresh["detections"] += 1
        self._observed_to = pose_index + 1
        self.drift.open(pose_index, self.drift.due(pose_index, n.update_every))
        if self.drift.windows:
            # Read again after a move too, at the estimate solved under the new scales: where
            # landmarks decide part of a window, a reading lies between the scales in use and
            # the truth (`drift.py`), so that each reading goes on from the last. Kept as read
            # before the move, the windows held the fit back: indoors the yaw was learnt in
            # steps each short of the truth (31, 95, 266 for 325), while wrong closures bent
            # the map.
            self.windows.replace(self._drift_observations(pose_index, estimate))
            self._fresh["drift windows"] += 1
        odometry = self._read(pose_index, "drift windows")
        measurement = self._read(pose_index, "detections")
        return NoiseChange(odometry, measurement)

    def _drift_observations(
        self, pose_index: int, estimate: EstimateReader
    ) -> list[ScaleObservation]:
        """Every open window read at the current estimate (the poses read once for all)."""
        start = min(first for first, _ in self.drift.windows)
        poses = [estimate.pose(X(k)) for k in range(start, pose_index + 1)]
        used = np.array(self.scales.odometry)
        # One joint of all the windows' ends, each window's two blocks taken from it: asked
        # window by window, the README's session spent 3.1 s in 570 of them.
        ends = sorted({k for window in self.drift.windows for k in window})
        joint = estimate.joint_covariance([X(k) for k in ends])
        rows = {k: np.arange(6 * n, 6 * n + 6) for n, k in enumerate(ends)}
        return [
            self.drift.observe(
                first,
                poses[first - start : last - start + 1],
                joint[np.ix_(np.r_[rows[first], rows[last]], np.r_[rows[first], rows[last]])],
                used,
            )
            for first, last in self.drift.windows
        ]

    def _read(self, pose_index: int, source: Source) -> bool:
        """Read `source`'s estimator if it has new observations, enough of them; whether its
        scales moved."""
        n = self.config
        odometry = source == "drift windows"
        likelihood = self.windows if odometry else self.contrasts
        least = n.min_drift_windows if odometry else n.min_contrasts
        if not self._fresh[source] or len(likelihood) < least:
            return False
        self._fresh[source] = 0
        current = np.array(self.scales.odometry if odometry else self.scales.measurement)
        reading = likelihood.reading(current, self.bounds, n.evidence, n.deadband, n.drop)
        if reading.scales is None:
            return False
        after = tuple(float(s) for s in reading.scales)
        self._moved(pose_index, source, likelihood.names, current, after, reading.evidence)
        self.scales = (
            NoiseScales(after, self.scales.measurement)
            if odometry
            else NoiseScales(self.scales.odometry, after)
        )
        return True

    def _moved(
        self,
        pose_index: int,
        source: Source,
        names: tuple[str, ...],
        before: np.ndarray,
        after: tuple[float, ...],
        evidence: np.ndarray,
    ) -> None:
        move = NoiseMove(
            pose_index,
            source,
            names,
            tuple(float(b) for b in before),
            after,
            tuple(float(e) for e in evidence),
        )
        self.moves.append(move)
        logger.debug("pose %d: %s moved the noise scales %s", pose_index, source, move.report())
