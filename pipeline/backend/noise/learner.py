"""When and how the noise scales a replay uses are learnt: the policy over the estimators."""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal, Protocol

import gtsam
import numpy as np
from gtsam.symbol_shorthand import X

from pipeline.backend.hypotheses import NULL, AssociationRecord
from pipeline.backend.landmarks import LandmarkKind
from pipeline.backend.noise.components import ScaleLikelihood
from pipeline.backend.noise.drift import DriftWindows
from pipeline.backend.noise.innovations import STEP_DIRECTIONS, innovation_observation
from pipeline.backend.noise.scales import MEASUREMENT_COMPONENTS, ODOMETRY_AXES, NoiseScales
from pipeline.config import NoiseConfig

if TYPE_CHECKING:
    from pipeline.backend.methods.base import Keyframe

logger = logging.getLogger(__name__)

# A keyframe's innovations tell the detections' noise from at most this many pairings: a few
# detections show what they share and what they do not, and each more costs its square.
MAX_PAIRINGS = 4

Source = Literal["drift windows", "innovations"]


class EstimateReader(Protocol):
    """What the learner reads of the estimate: poses and their joint covariance."""

    def pose(self, key: int) -> gtsam.Pose3: ...

    def joint_covariance(self, keys: list[int]) -> np.ndarray: ...


@dataclass(frozen=True)
class NoiseMove:
    """One change of the noise scales of `names`: at which keyframe, on whose evidence (the
    odometry's drift windows, or the detections' innovations), each direction's scale before
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
    associates keyframes jointly and so sees sure pairings), how they are learnt: every
    `update_every` keyframes, the odometry's from its drift windows (`drift.py`) and the
    detections' from the innovations of sure pairings (`innovations.py`), each direction moved
    only on clear evidence (`components.ScaleLikelihood.reading`)."""

    def __init__(self, config: NoiseConfig, enabled: bool):
        n = self.config = config
        self.enabled = enabled and n.estimate
        self.scales = NoiseScales(tuple(n.odometry_scale), tuple(n.measurement_scale))
        self.bounds = (n.min_scale, n.max_scale)
        self.moves: list[NoiseMove] = []  # in order
        self.drift = DriftWindows(n.drift_window, n.long_drift_window)
        self.windows = ScaleLikelihood(ODOMETRY_AXES, n.drift_windows)
        step_names = tuple(f"step {a}" for a in ODOMETRY_AXES)
        self.innovations = ScaleLikelihood((*step_names, *MEASUREMENT_COMPONENTS), n.innovations)
        self._step_stated: np.ndarray | None = None
        self._fresh = {"drift windows": 0, "innovations": 0}  # observations since a reading

    @property
    def watches_drift(self) -> bool:
        """Whether the odometry's steps are wanted (`add_step`)."""
        return self.enabled

    def add_step(self, step: gtsam.Pose3, stated: np.ndarray) -> None:
        """The odometry's next step and its stated covariance."""
        self.drift.add_step(step, stated)
        self._step_stated = np.asarray(stated, dtype=float)

    def samples(self, pose_index: int) -> bool:
        """Whether keyframe `pose_index` gets the whole joint test even where every pairing is
        sure, so that sure pairings tell the noise too."""
        return self.config.estimate and pose_index % self.config.sample_every == 0

    def observe_keyframe(
        self,
        keyframe: Keyframe,
        records: Sequence[AssociationRecord],
        last_seen: Mapping[int, int],
    ) -> None:
        """The innovations of the keyframe's pairings with point landmarks seen at the keyframe
        before (`last_seen`, before this keyframe's), where it was associated jointly."""
        if not self.enabled or keyframe.joint is None or self._step_stated is None:
            return
        pose_index = keyframe.prediction.pose_index
        rows = []
        for record, c, m in zip(records, keyframe.candidates, keyframe.measurements, strict=True):
            k = record.active
            if m.kind is not LandmarkKind.POINT or k == NULL or k >= len(c) or c.residuals is None:
                continue
            j = int(c.landmark_ids[k])
            if record.landmark_ids[k] != j or last_seen.get(j) != pose_index - 1:
                continue
            rows.append((c.residuals[k], c.pose_jacobians[k], c.landmark_jacobians[k], j, m))
        if not rows:
            return
        rows = rows[:MAX_PAIRINGS]
        residuals, H_x, H_l, ids, ms = zip(*rows, strict=True)
        observation = innovation_observation(
            np.array(residuals),
            np.array(H_x),
            np.array(H_l),
            np.array([keyframe.joint.offsets[j] for j in ids]),
            keyframe.joint.matrix,
            keyframe.prediction.process,
            self._step_stated,
            np.array([np.reshape(m.detection.covariance, (3, 3)) for m in ms]),
            np.array([*self.scales.odometry, *self.scales.measurement]),
        )
        self.innovations.add(observation)
        self._fresh["innovations"] += 1

    def learn(self, pose_index: int, estimate: EstimateReader) -> NoiseChange:
        """Every `update_every` keyframes: the drift windows ending now taken from `estimate`,
        and each estimator read where it has new observations; what moved."""
        n = self.config
        if not self.enabled or pose_index % n.update_every:
            return NoiseChange()
        last = X(pose_index)
        last_pose = estimate.pose(last)
        for length in self.drift.due(pose_index, n.update_every):
            first = X(pose_index - length)
            relative = estimate.pose(first).between(last_pose)
            joint = estimate.joint_covariance([first, last])
            used = np.array(self.scales.odometry)
            self.windows.add(self.drift.observe(relative, joint, used, length))
            self._fresh["drift windows"] += 1
        odometry = self._read_odometry(pose_index)
        measurement = self._read_measurement(pose_index)
        return NoiseChange(odometry, measurement)

    def _ready(self, source: Source, likelihood: ScaleLikelihood, least: int) -> bool:
        if not self._fresh[source] or len(likelihood) < least:
            return False
        self._fresh[source] = 0
        return True

    def _read_odometry(self, pose_index: int) -> bool:
        n = self.config
        if not self._ready("drift windows", self.windows, n.min_drift_windows):
            return False
        current = np.array(self.scales.odometry)
        reading = self.windows.reading(current, self.bounds, n.evidence, n.deadband, n.drop)
        if reading.scales is None:
            return False
        after = tuple(float(s) for s in reading.scales)
        self._moved(pose_index, "drift windows", ODOMETRY_AXES, current, after, reading.evidence)
        self.scales = NoiseScales(after, self.scales.measurement)
        return True

    def _read_measurement(self, pose_index: int) -> bool:
        n = self.config
        if not self._ready("innovations", self.innovations, n.min_innovations):
            return False
        current = np.array([*self.scales.odometry, *self.scales.measurement])
        tested = np.arange(len(current)) >= STEP_DIRECTIONS
        reading = self.innovations.reading(
            current, self.bounds, n.evidence, n.deadband, n.drop, tested=tested
        )
        if reading.scales is None:
            return False
        after = tuple(float(s) for s in reading.scales[tested])
        self._moved(
            pose_index,
            "innovations",
            MEASUREMENT_COMPONENTS,
            current[tested],
            after,
            reading.evidence[tested],
        )
        self.scales = NoiseScales(self.scales.odometry, after)
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
