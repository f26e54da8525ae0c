"""What every association method shares: the graph it edits and the class bookkeeping."""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass, field

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X

from pipeline.backend.association import class_posterior_update
from pipeline.backend.candidates import Candidates, KeyframeCovariance, PosePrediction
from pipeline.backend.decisions import MeasurementSpace, null_cost
from pipeline.backend.hypotheses import AssociationRecord, EstimateCache
from pipeline.backend.landmarks import LandmarkKind, LandmarkMap
from pipeline.backend.measurements import Measurement
from pipeline.backend.movement import MovementTracker, is_landmark_key, key_index
from pipeline.backend.solver import Isam2Solver, movement_thresholds
from pipeline.config import Config


@dataclass(frozen=True)
class Keyframe:
    """The keyframe being added, as the association step gets it: its predicted pose, its
    detections as measurements, each one's candidates and, for a method that associates the
    keyframe jointly, the new pose's joint covariance with every candidate."""

    prediction: PosePrediction
    measurements: list[Measurement]
    candidates: list[Candidates]
    joint: KeyframeCovariance | None = None


def _quiet(doing: str) -> None:
    """A heartbeat nobody hears."""


@dataclass
class BackendContext:
    """The state the methods read and edit: solver, landmarks, what detections have shown."""

    solver: Isam2Solver
    landmarks: LandmarkMap
    confusion: np.ndarray
    config: Config
    movement: MovementTracker = field(init=False)
    # Every record that has a landmark among its components, by landmark id.
    records_of: dict[int, list[AssociationRecord]] = field(
        init=False, default_factory=lambda: defaultdict(list)
    )
    last_seen: dict[int, int] = field(init=False, default_factory=dict)  # latest pose index
    # Landmarks seen or moved since the last merge check: the only ones whose merge test can
    # have changed.
    changed: set[int] = field(init=False, default_factory=set)
    # Where each kind of detection falls: where a landmark not mapped yet could be.
    space: dict[LandmarkKind, MeasurementSpace] = field(init=False)
    # Told now and then what a keyframe is doing, from inside its long loops (a keyframe of a
    # thousand detections): the replay's progress shows it.
    heartbeat: Callable[[str], None] = field(init=False, default_factory=lambda: _quiet)

    def __post_init__(self) -> None:
        self.movement = MovementTracker(movement_thresholds(self.config.isam2))
        self.space = {kind: MeasurementSpace() for kind in LandmarkKind}

    def register(self, record: AssociationRecord) -> None:
        """Index a new record by the landmarks it may be; the one it is was seen now."""
        for j in record.landmark_ids:
            self.records_of[j].append(record)
        self.seen(record)

    def seen(self, record: AssociationRecord) -> None:
        j, pose = record.landmark_id, record.measurement.pose_index
        if j >= 0:
            self.last_seen[j] = max(self.last_seen.get(j, pose), pose)
            self.changed.add(j)

    def seen_lately(self, landmark_id: int, pose_index: int) -> bool:
        """Whether the landmark was seen within the last `[merges] recent_keyframes` keyframes
        before `pose_index`: pairing a landmark not seen lately closes a loop."""
        since = pose_index - self.config.merges.recent_keyframes
        return self.last_seen.get(landmark_id, -1) > since

    def held_detections(self, landmark_id: int) -> list[Measurement]:
        """The detections now associated with the landmark."""
        records = self.records_of.get(landmark_id, ())
        return [r.measurement for r in records if r.landmark_id == landmark_id]

    def observed_at(self, landmark_id: int) -> set[int]:
        """Pose indices of the detections now associated with the landmark."""
        return {m.pose_index for m in self.held_detections(landmark_id)}

    def create_landmark(self, m: Measurement, pose: gtsam.Pose3) -> int:
        """A new landmark initialised from the detection seen from `pose`, with its class
        evidence; its factor is the caller's."""
        value = m.initial_landmark(pose)
        position = value.translation() if hasattr(value, "translation") else value
        landmark = self.landmarks.create(m.kind, position)
        self.solver.insert(L(landmark.id), value)
        if m.kind is LandmarkKind.POINT:
            # A point seen only from where its measurement cannot be projected (behind the
            # virtual camera of every factor on it, after a gross error) would have no
            # information at all; a prior kilometres wide keeps it determined, and weighs
            # nothing otherwise.
            sigma = self.config.landmarks.anchor_sigma_m
            noise = gtsam.noiseModel.Isotropic.Sigma(3, sigma)
            landmark.anchor = self.solver.add(gtsam.PriorFactorPoint3(L(landmark.id), value, noise))
        self.observe_classes(m, [landmark.id], np.ones(1))
        return landmark.id

    def add_factor(self, m: Measurement, landmark_id: int, information_scale: float = 1.0) -> int:
        return self.solver.add(m.factor(X(m.pose_index), L(landmark_id), information_scale))

    def remove_factors(self, record: AssociationRecord) -> None:
        """Take a record's factors out of the graph; its landmarks lose information, so their
        cached covariance bounds no longer hold."""
        for handle in record.handles:
            self.solver.remove(handle)
        record.handles = []
        for j in record.landmark_ids:
            self.landmarks.landmarks[j].covariance_bound = None

    def observe_classes(
        self, m: Measurement, landmark_ids: list[int], weights: np.ndarray, null_weight: float = 0.0
    ) -> None:
        """Update the class posterior of every hypothesised landmark by this detection's report,
        with its association summed out (the paper's product over detections of sums)."""
        column = self.confusion[:, m.detection.class_id]
        lms = [self.landmarks.landmarks[j] for j in landmark_ids]
        semantic = np.array([column @ lm.class_probabilities for lm in lms])
        weights = np.asarray(weights, dtype=float)
        # The association weights already hold each landmark's semantic likelihood; dividing
        # it out leaves the rest of the association's evidence, so that the report is counted
        # once: evidence(c) = (w_k / s_k) P(report | c) + (the other associations' weight).
        # A report the confusion matrix makes impossible for a landmark (s = 0: possible only
        # where the association was not weighed, as known's truth labels decide it) adds no
        # evidence for any of its classes.
        total = float(weights.sum()) + null_weight
        for lm, w, s in zip(lms, weights, semantic, strict=True):
            weight = float(w) / float(s) if s > 0 else 0.0
            lm.class_probabilities = class_posterior_update(
                lm.class_probabilities, column, weight, total - float(w)
            )

    def estimates(self, prediction: PosePrediction | None = None) -> EstimateCache:
        """Current estimates; with `prediction`, its pose (not in iSAM2 yet) included."""
        cache = EstimateCache(self.solver, self.landmarks.is_pose)
        if prediction is not None:
            cache.set_pose(prediction.pose_index, prediction.pose)
        return cache

    def after_update(self, marked: set[int]) -> set[int]:
        """The variables among iSAM2's `marked` ones whose estimate moved by more than the
        relinearisation threshold since they last moved (new variables included); moved
        landmarks are moved in the spatial index too.

        A variable that iSAM2 did not mark kept its linearisation point, so the factors on it,
        and the component a max-mixture would choose, are as they were."""
        # A landmark merged into another is no longer in iSAM2.
        marked = {
            k for k in marked if not is_landmark_key(k) or key_index(k) in self.landmarks.landmarks
        }
        moved, positions = self.movement.moved(self.solver, marked, self.landmarks.is_pose)
        for landmark_id, position in positions.items():
            self.landmarks.move(landmark_id, position)
        self.changed.update(positions)
        return moved


class AssociationMethod(ABC):
    """Turns a detection and its scored candidates into factors, and keeps them right.

    What a method is, the back-end reads off these traits (a subclass overrides them):
    - `uses_candidates`: it scores the landmarks a detection could be (known is told);
    - `wants_joint`: it associates a keyframe's detections jointly, and needs the keyframe's
      joint covariance and every candidate's residual (`Keyframe.joint`); such a method also
      sees the sure pairings that tell the noise (`noise.py`);
    - `wide_gate`: its candidates pass the joint test's wider gate, though it decides alone;
    - `merges_landmarks`: duplicated landmarks are merged (`merges.py`), by `merge`."""

    name: str = ""
    uses_candidates: bool = True
    wants_joint: bool = False
    wide_gate: bool = False
    merges_landmarks: bool = False

    def __init__(self, context: BackendContext):
        self.context = context
        self.config = context.config

    @abstractmethod
    def associate(
        self, m: Measurement, candidates: Candidates, keyframe: Keyframe
    ) -> AssociationRecord:
        """Add the detection's factors (pending in the solver) and return its record."""

    def associate_keyframe(self, keyframe: Keyframe) -> list[AssociationRecord]:
        """All the detections of one keyframe; by default one at a time."""
        return [
            self.associate(m, c, keyframe)
            for m, c in zip(keyframe.measurements, keyframe.candidates, strict=True)
        ]

    def refine(self, moved: set[int]) -> list[AssociationRecord]:
        """After an iSAM2 update that moved `moved`: revisit associations; returns the records
        whose landmark changed (in the order of their changes)."""
        return []

    def finish(self) -> None:  # noqa: B027 - most methods have nothing to settle
        """Settle the final associations once every keyframe is in."""

    def merge(self, survivor: int, duplicate: int) -> None:
        """Make `duplicate` one with `survivor` (for a method that `merges_landmarks`)."""
        raise NotImplementedError(f"{self.name} does not merge landmarks")

    def restate(self, records: list[AssociationRecord], scale: np.ndarray) -> None:
        """Every factor of `records` again with the detections' covariance at `scale` (the
        noise scales learnt: `noise.NoiseScales.measurement_matrix`), pending in the solver;
        for a method that `wants_joint`, the one that learns the noise."""
        raise NotImplementedError(f"{self.name} does not learn the noise")

    def single(self, m: Measurement, landmark_id: int, weight: float = 1.0) -> AssociationRecord:
        """A plain association: one factor to one landmark."""
        handle = self.context.add_factor(m, landmark_id)
        return AssociationRecord(m, [landmark_id], np.array([weight]), handles=[handle])

    def new_landmark(self, m: Measurement, keyframe: Keyframe) -> AssociationRecord:
        """A landmark of its own, seen from the keyframe's predicted pose."""
        landmark_id = self.context.create_landmark(m, keyframe.prediction.pose)
        return self.single(m, landmark_id)


class MixtureMethod(AssociationMethod):
    """Methods whose records keep several components and are revisited after updates."""

    def __init__(self, context: BackendContext):
        super().__init__(context)
        self._records: list[AssociationRecord] = []
        self._by_key: dict[int, list[int]] = defaultdict(list)
        self._index_of: dict[int, int] = {}  # id(record) -> its index in _records

    def track(self, record: AssociationRecord) -> AssociationRecord:
        index = len(self._records)
        self._records.append(record)
        self._index_of[id(record)] = index
        for key in record.keys:
            self._by_key[key].append(index)
        return record

    def retrack(self, record: AssociationRecord, key: int) -> None:
        """A tracked record now also has `key` among its variables (after a merge)."""
        index = self._index_of.get(id(record))
        if index is not None and index not in self._by_key[key]:
            self._by_key[key].append(index)

    def null_cost(self, m: Measurement, null_weight: float) -> float:
        """The null hypothesis's cost for detection `m`, at prior weight `null_weight`
        (`decisions.null_cost` with the `[association]` settings)."""
        a = self.config.association
        return null_cost(
            a.null_model, null_weight, a.null_sigma, a.null_crossover_sq, m.dim, m.log_normaliser
        )

    def affected(self, moved: set[int]) -> list[AssociationRecord]:
        """Tracked records with a variable among `moved`, in creation order."""
        indices = sorted({i for key in moved for i in self._by_key.get(key, ())})
        return [self._records[i] for i in indices]
