"""Discrete-continuous smoothing and mapping (DC-SAM; Doherty, Lu, Singh and Leonard, RA-L
2022), the 2020 paper's first author's later method, as a sixth way to use the candidates.

Every detection with candidates gets a discrete association over its candidates, a landmark of
its own and the null hypothesis (`dcsam_model.py` says what each mode costs), and with more
than one class every landmark a discrete class. DC-SAM alternates: the discrete variables set
to their most probable explanation given the continuous estimate (`discrete_step.py`, GTSAM's
discrete solver), then iSAM2 given the discrete ones, each detection's factor the one its mode
selects (a native factor, `Measurement.factor`). Here the discrete step is taken for a new
keyframe's detections at the predicted pose, after every iSAM2 update for the detections whose
variables moved (until no mode changes, or `[dcsam] max_alternations` rounds), and at the end
for every detection: the associations reported are that last discrete solution.

A detection's own landmark is made when its mode is first chosen, at the detection. A landmark
that no detection holds any more leaves the spatial index, so it is no later detection's
candidate, and the map at the end. Landmarks are not merged, and the noise is the log's.

GTSAM 4.3's `gtsam.DCSAM` cannot run this incrementally (docs/dcsam.md): each update adds
every hybrid factor's selected component to its iSAM2 again and keeps the old ones, it gives no
marginals for the candidate gate, and `HybridNonlinearFactor` takes components over the same
variables only. So the alternation is run over the back-end's own iSAM2 (`Isam2Solver`, the
same `[isam2]` settings and handles to swap factors); `tests/test_dcsam.py` checks one step of
it against `gtsam.DCSAM`'s first update.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X

from pipeline.backend.candidates import Candidates, PosePrediction
from pipeline.backend.hypotheses import NULL, AssociationRecord
from pipeline.backend.landmarks import LandmarkKind
from pipeline.backend.measurements import Measurement
from pipeline.backend.methods.base import BackendContext, Keyframe, MixtureMethod
from pipeline.backend.methods.dcsam import discrete_step
from pipeline.backend.methods.dcsam.model import (
    class_log_evidence,
    class_posterior,
    geometric_weights,
    mode_constants,
    new_landmark_log_volume,
)


@dataclass
class HybridRecord(AssociationRecord):
    """A detection with a discrete association. Its modes: `num_candidates` candidates (the
    first landmark ids), its own landmark (the next id, once made), the null. `weights` and
    `null_weight` hold each mode's probability at the last discrete step."""

    num_candidates: int = 0
    constants: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (K + 2,) costs
    factors: list = field(default_factory=list)  # each landmark mode's measurement factor
    report: np.ndarray = field(default_factory=lambda: np.zeros(0))  # P(reported | c)

    @property
    def mode(self) -> int:
        return self.num_candidates + 1 if self.active == NULL else self.active

    @property
    def mode_landmarks(self) -> tuple[int | None, ...]:
        """Each mode's landmark but the null's; None for a landmark of its own not made yet."""
        own = self.landmark_ids[self.num_candidates :] or [None]
        return (*self.landmark_ids[: self.num_candidates], *own)


class DiscreteContinuous(MixtureMethod):
    name = "dcsam"
    # mm-nh's candidate gate (`[association] joint_candidate_confidence`): the discrete step,
    # not the gate, weighs a candidate against a landmark of the detection's own.
    wide_gate = True

    def __init__(self, context: BackendContext):
        super().__init__(context)
        self.null_weight = self.config.association.null_weight
        self.new_weight = self.config.dcsam.new_landmark_weight
        self.num_classes = context.confusion.shape[0]
        # Per landmark: how many detections hold it, and how many reported each class.
        self.holders: dict[int, int] = defaultdict(int)
        self.report_counts: dict[int, np.ndarray] = {}

    def null_nll(self, m: Measurement) -> float:
        """The null mode's cost: mm-nh's."""
        return self.null_cost(m, self.null_weight)

    def associate(
        self, m: Measurement, candidates: Candidates, keyframe: Keyframe
    ) -> AssociationRecord:
        one = Keyframe(keyframe.prediction, [m], [candidates], keyframe.joint)
        return self.associate_keyframe(one)[0]

    def associate_keyframe(self, keyframe: Keyframe) -> list[AssociationRecord]:
        """A detection without candidates is a new landmark; the others' modes are chosen
        together, at the predicted pose."""
        records: list[AssociationRecord] = []
        hybrid: list[HybridRecord] = []
        for m, c in zip(keyframe.measurements, keyframe.candidates, strict=True):
            if len(c) == 0:
                record = self.new_landmark(m, keyframe)
                self._hold(record.landmark_id, m)
            else:
                record = self._hybrid_record(m, c)
                hybrid.append(record)
            records.append(record)
        if hybrid:
            prediction = keyframe.prediction
            solution = self._solve(hybrid, prediction)
            for record, mode, p in zip(hybrid, solution.modes, solution.probabilities, strict=True):
                self._enter(record, mode, prediction.pose)
                self._set_weights(record, p)
                self.track(record)
        return records

    def _hybrid_record(self, m: Measurement, c: Candidates) -> HybridRecord:
        constants = mode_constants(
            geometric_weights(c.weights, c.semantic),
            self.null_weight,
            self.new_weight,
            m.log_normaliser,
            new_landmark_log_volume(m.kind, self.context.space[m.kind]),
            self.null_nll(m),
        )
        ids = [int(j) for j in c.landmark_ids]
        return HybridRecord(
            m,
            ids,
            np.zeros(len(ids)),
            active=NULL,
            num_candidates=len(ids),
            constants=constants,
            factors=[m.factor(X(m.pose_index), L(j)) for j in ids],
            report=self.context.confusion[:, m.detection.class_id].copy(),
        )

    def refine(self, moved: set[int]) -> list[AssociationRecord]:
        """Alternate: the modes of the detections whose variables moved, then iSAM2."""
        changed: list[AssociationRecord] = []
        for _ in range(self.config.dcsam.max_alternations):
            records = self.affected(moved)
            if not records:
                break
            switched = self._step(records)
            if not switched:
                break
            changed += switched
            moved = self.context.after_update(self.context.solver.update())
        return changed

    def finish(self) -> None:
        """Every detection's mode solved again at the final estimate (the associations
        reported), alternating with iSAM2 while modes change; landmarks no detection holds
        leave the map."""
        for _ in range(self.config.dcsam.max_alternations):
            if not self._step(self._records):
                break
            self.context.after_update(self.context.solver.update())
        for j in sorted(self.context.landmarks.withdrawn):
            self.context.landmarks.discard(j)

    def _step(self, records: list[AssociationRecord]) -> list[AssociationRecord]:
        """The discrete step for `records` at the current estimate; their factors follow.
        Returns the records whose mode changed."""
        hybrid = [r for r in records if isinstance(r, HybridRecord)]
        solution = self._solve(hybrid)
        switched = []
        for record, mode, p in zip(hybrid, solution.modes, solution.probabilities, strict=True):
            if mode != record.mode:
                self._switch(record, mode)
                switched.append(record)
            self._set_weights(record, p)
        return switched

    def _solve(
        self, records: list[HybridRecord], prediction: PosePrediction | None = None
    ) -> discrete_step.DiscreteSolution:
        values = self._values(records, prediction)
        detections = []
        for r in records:
            costs = r.constants.copy()
            for mode, factor in enumerate(r.factors):
                costs[mode] += factor.error(values)
            detections.append(discrete_step.DetectionModes(costs, r.mode_landmarks, r.report))
        evidence = self._evidence_outside(records) if self.num_classes > 1 else None
        return discrete_step.solve(detections, evidence, self.config.dcsam.exact_class_variables)

    def _values(
        self, records: list[HybridRecord], prediction: PosePrediction | None
    ) -> gtsam.Values:
        """The estimates the records' factors need; the new pose at its prediction."""
        keys = {X(r.measurement.pose_index) for r in records}
        keys |= {L(j) for r in records for j in r.landmark_ids}
        if prediction is not None:
            keys.discard(X(prediction.pose_index))
        values = self.context.solver.estimate_of(sorted(keys))
        if prediction is not None:
            values.insert(X(prediction.pose_index), prediction.pose)
        return values

    def _evidence_outside(self, records: list[HybridRecord]) -> dict[int, np.ndarray]:
        """log P(reports | c) of each landmark among the records' modes, from the detections it
        holds that are not among `records`."""
        counts = {
            j: self.report_counts.get(j, np.zeros(self.num_classes)).copy()
            for r in records
            for j in r.landmark_ids
        }
        for r in records:
            if r.active != NULL:
                counts[r.landmark_id][r.measurement.detection.class_id] -= 1
        return {j: class_log_evidence(n, self.context.confusion) for j, n in counts.items()}

    def _enter(self, record: HybridRecord, mode: int, pose: gtsam.Pose3) -> None:
        """Put the mode's factor in the graph (its landmark made first if it is the
        detection's own and not made yet, seen from `pose`)."""
        if mode == record.num_candidates + 1:
            record.active = NULL
            return
        if mode == len(record.landmark_ids):
            self._make_own_landmark(record, pose)
        record.active = mode
        record.handles = [self.context.solver.add(record.factors[mode])]
        self._hold(record.landmark_ids[mode], record.measurement)

    def _switch(self, record: HybridRecord, mode: int) -> None:
        m = record.measurement
        if record.active != NULL:
            self._release(record.landmark_id, m)
        self.context.remove_factors(record)
        self._enter(record, mode, self.context.solver.pose(X(m.pose_index)))
        record.switches += 1

    def _make_own_landmark(self, record: HybridRecord, pose: gtsam.Pose3) -> None:
        m = record.measurement
        context = self.context
        j = context.create_landmark(m, pose)
        if m.kind is LandmarkKind.POSE:
            # Every detection may leave it: a prior that weighs nothing keeps it determined
            # (a point landmark has one already).
            sigma = self.config.landmarks.anchor_sigma_m
            value = m.initial_landmark(pose)
            noise = gtsam.noiseModel.Isotropic.Sigma(6, sigma)
            context.landmarks.landmarks[j].anchor = context.solver.add(
                gtsam.PriorFactorPose3(L(j), value, noise)
            )
        record.landmark_ids.append(j)
        record.factors.append(m.factor(X(m.pose_index), L(j)))
        record.weights = np.append(record.weights, 0.0)
        if id(record) in self._index_of:  # tracked (and registered) already
            context.records_of[j].append(record)
            self.retrack(record, L(j))

    def _hold(self, landmark_id: int, m: Measurement) -> None:
        self.holders[landmark_id] += 1
        counts = self.report_counts.setdefault(landmark_id, np.zeros(self.num_classes))
        counts[m.detection.class_id] += 1
        self._update_class(landmark_id)
        landmarks = self.context.landmarks
        if landmark_id in landmarks.withdrawn:
            landmarks.reinstate(landmark_id, self._position(landmark_id))

    def _release(self, landmark_id: int, m: Measurement) -> None:
        self.holders[landmark_id] -= 1
        self.report_counts[landmark_id][m.detection.class_id] -= 1
        self._update_class(landmark_id)
        if self.holders[landmark_id] == 0:
            self.context.landmarks.withdraw(landmark_id)

    def _update_class(self, landmark_id: int) -> None:
        landmark = self.context.landmarks.landmarks[landmark_id]
        evidence = class_log_evidence(self.report_counts[landmark_id], self.context.confusion)
        landmark.class_probabilities = class_posterior(evidence)

    def _position(self, landmark_id: int) -> np.ndarray:
        solver = self.context.solver
        if self.context.landmarks.landmarks[landmark_id].kind is LandmarkKind.POSE:
            return solver.pose(L(landmark_id)).translation()
        return solver.point(L(landmark_id))

    def _set_weights(self, record: HybridRecord, probabilities: np.ndarray) -> None:
        record.weights = np.asarray(probabilities[: len(record.landmark_ids)], dtype=float)
        record.null_weight = float(probabilities[-1])
