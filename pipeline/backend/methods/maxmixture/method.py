"""Semantic max-mixture factors (`mm`), with the null hypothesis (`mm-nh`).

A detection's factor is max_k w_k N(h(x, l_k) - z; 0, Gamma): the component with the smallest
negative log-likelihood, normalisers included, is the one in the graph. With the null
hypothesis, a component of weight `null_weight` competes (`decisions.py` says what it costs):
when it wins, the detection pulls on nothing, and a wrong loop closure is rejected.

The component is first chosen where the factor is first linearised, at the predicted pose
(`[mixture] first_choice = "prediction"`), and revisited after every update that moves its
variables (`pipeline/backend/hypotheses.py`). With mmslam's defaults, a detection whose null
wins at the prediction starts a landmark of its own instead of pulling on nothing, and
`merge` joins such landmarks to the ones they duplicate once a joint test is sure of it.
"""

from __future__ import annotations

import math

import numpy as np
from gtsam.symbol_shorthand import L, X

from pipeline.backend.association import with_null_hypothesis
from pipeline.backend.budget import SearchBudget
from pipeline.backend.candidates import Candidates, KeyframeCovariance
from pipeline.backend.decisions import (
    clutter_log_density,
    first_component,
    loop_pairs_needed,
)
from pipeline.backend.hypotheses import NULL, AssociationRecord, component_mahalanobis
from pipeline.backend.landmarks import LandmarkKind
from pipeline.backend.measurements import Measurement, make_measurement
from pipeline.backend.methods.base import BackendContext, Keyframe, MixtureMethod
from pipeline.backend.methods.maxmixture.joint_association import (
    NONE,
    DetectionOptions,
    KeyframeProblem,
    associate_keyframe,
)
from pipeline.backend.methods.maxmixture.mixture_factor import MaxMixtureFactor, component
from pipeline.backend.mixture import component_nll


class MaxMixture(MixtureMethod):
    name = "mm"

    def __init__(self, context: BackendContext, null_hypothesis: bool = False):
        super().__init__(context)
        a = self.config.association
        self.null_weight = a.null_weight if null_hypothesis else 0.0
        self.name = "mm-nh" if null_hypothesis else "mm"
        self.in_factor = self.config.mixture.selection == "custom-factor"
        choice = self.config.mixture.first_choice
        self.wants_joint = choice == "joint" and null_hypothesis and not self.in_factor
        self.at_prediction = choice in ("joint", "prediction")
        self.merges_landmarks = (
            null_hypothesis and self.config.merges.enabled and not self.in_factor
        )
        self._mixture_factors: list[tuple[AssociationRecord, MaxMixtureFactor]] = []

    def null_nll(self, m: Measurement) -> float:
        """The null component's cost for this detection (inf without a null hypothesis)."""
        return math.inf if self.null_weight <= 0 else self.null_cost(m, self.null_weight)

    def associate(
        self, m: Measurement, candidates: Candidates, keyframe: Keyframe
    ) -> AssociationRecord:
        if len(candidates) == 0:
            return self.new_landmark(m, keyframe)
        weights = candidates.weights
        if self.null_weight > 0:
            weights, _ = with_null_hypothesis(weights, self.null_weight)
        ids = [int(j) for j in candidates.landmark_ids]
        if self.in_factor:
            self.context.observe_classes(m, ids, weights, self.null_weight)
            record = AssociationRecord(m, ids, weights, null_weight=self.null_weight)
            return self._custom_factor(record)
        if self.at_prediction:
            first = first_component(weights, candidates.fit_sq, m.log_normaliser, self.null_nll(m))
            if first == NULL and self.merges_landmarks:
                # Nothing fits where the odometry puts the detection: a landmark of its own,
                # until a merge shows which landmark it duplicates.
                return self.new_landmark(m, keyframe)
        else:
            # The most probable association, pose and landmarks marginalised out (the weights).
            best = int(np.argmax(weights))
            first = NULL if self.null_weight > weights[best] else best
        self.context.observe_classes(m, ids, weights, self.null_weight)
        record = AssociationRecord(m, ids, weights, null_weight=self.null_weight, active=first)
        if record.active != NULL:
            record.handles = [self.context.add_factor(m, ids[record.active])]
        return self.track(record) if record.is_mixture else record

    def associate_keyframe(self, keyframe: Keyframe) -> list[AssociationRecord]:
        """The keyframe's detections chosen together (`joint_association.py`): a pairing that
        is best and unambiguous becomes the record's first component; every other detection
        starts a landmark of its own."""
        measurements, candidates, joint = keyframe.measurements, keyframe.candidates, keyframe.joint
        if not self.wants_joint or joint is None or not any(len(c) for c in candidates):
            # Without a joint (every detection sure, or none near anything), one at a time.
            return super().associate_keyframe(keyframe)
        a = self.config.association
        options = [
            self._options(m, c, joint) for m, c in zip(measurements, candidates, strict=True)
        ]
        kept = [np.arange(len(c)) for c in candidates]  # candidate index of each option
        pose_index = measurements[0].pose_index
        # One budget for all of the keyframe's searches, however many detections it holds.
        budget = SearchBudget(a.max_keyframe_nodes)
        while True:
            problem = KeyframeProblem(
                detections=[o.subset(k) for o, k in zip(options, kept, strict=True)],
                covariance=joint.matrix,
                block_offsets=np.array(list(joint.offsets.values())),
                block_dims=np.diff([*joint.offsets.values(), joint.matrix.shape[0]]),
                gate_confidence=a.joint_confidence,
            )
            decision = associate_keyframe(
                problem,
                a.ambiguity_log_odds,
                a.max_search_nodes,
                a.max_joint_detections,
                budget,
                self.context.heartbeat,
            )
            chosen = [
                int(kept[i][k]) if k != NONE and unique else NONE
                for i, (k, unique) in enumerate(
                    zip(decision.assignment, decision.unique, strict=True)
                )
            ]
            # A loop is closed by enough landmarks agreeing (`loop_pairs_needed`), or by a merge
            # later (`merges.py`): too few loop-closing pairings are taken out, and the
            # keyframe decided again.
            loops = [
                i
                for i, k in enumerate(chosen)
                if k != NONE
                and not self.context.seen_lately(int(candidates[i].landmark_ids[k]), pose_index)
            ]
            if not loops or len(loops) >= loop_pairs_needed(
                [float(candidates[i].weights[chosen[i]]) for i in loops],
                a.min_loop_pairs,
                a.crowded_loop_pairs,
            ):
                break
            for i in loops:
                kept[i] = kept[i][kept[i] != chosen[i]]
        records = []
        for m, c, k in zip(measurements, candidates, chosen, strict=True):
            if k == NONE:
                records.append(self.new_landmark(m, keyframe))
                continue
            weights, _ = with_null_hypothesis(c.weights, self.null_weight)
            ids = [int(j) for j in c.landmark_ids]
            self.context.observe_classes(m, ids, weights, self.null_weight)
            record = AssociationRecord(m, ids, weights, null_weight=self.null_weight, active=k)
            record.handles = [self.context.add_factor(m, ids[k])]
            records.append(self.track(record))
        return records

    def restate(self, records: list[AssociationRecord], scale: np.ndarray) -> None:
        """Each record's detection at the detections' noise `scale`, its one factor (the
        active component's) swapped for one at that noise."""
        use_pose = self.config.landmarks.use_relative_pose
        for record in records:
            m = record.measurement
            record.measurement = make_measurement(
                m.pose_index, m.detection_index, m.detection, use_pose, scale
            )
            if record.handles:
                self.context.remove_factors(record)
                record.handles = [self.context.add_factor(record.measurement, record.landmark_id)]

    def _null_log_density(self, m: Measurement) -> float:
        """A point detection's null: a new landmark or clutter, anywhere in the measurement
        space; a pose landmark's: the max-mixture's null (`null_nll`)."""
        if m.kind is not LandmarkKind.POINT:
            return -self.null_nll(m)
        report = float(self.context.confusion[:, m.detection.class_id].mean())
        volume = self.context.space[m.kind].log_volume()
        return clutter_log_density(self.null_weight, report, volume)

    def _seniority(self, landmark_id: int, pose_index: int) -> float:
        """How established a candidate is: its detections so far; none if it was not seen
        lately (pairing it would close a loop, which seniority must not decide)."""
        if not self.context.seen_lately(landmark_id, pose_index):
            return 0.0
        return float(len(self.context.records_of.get(landmark_id, ())))

    def _options(
        self, m: Measurement, c: Candidates, joint: KeyframeCovariance
    ) -> DetectionOptions:
        slot_of = {j: s for s, j in enumerate(joint.offsets)}
        if len(c) == 0:
            empty = np.zeros((0, m.dim))
            return DetectionOptions(
                empty, np.zeros((0, m.dim, 6)), np.zeros((0, m.dim, 3)), np.zeros(0, dtype=int),
                np.zeros(0), m.covariance, self._null_log_density(m),
            )  # fmt: skip
        return DetectionOptions(
            residuals=c.residuals,
            pose_jacobians=c.pose_jacobians,
            landmark_jacobians=c.landmark_jacobians,
            slots=np.array([slot_of[int(j)] for j in c.landmark_ids]),
            log_prior=np.log((1.0 - self.null_weight) * c.semantic),
            covariance=m.covariance,
            null_log_density=self._null_log_density(m),
            seniority=np.array([self._seniority(int(j), m.pose_index) for j in c.landmark_ids]),
        )

    def _custom_factor(self, record: AssociationRecord) -> AssociationRecord:
        """The mixture as one CustomFactor choosing at every linearisation (no `refine`)."""
        m = record.measurement
        components = [
            component(m.factor(X(m.pose_index), L(j)), float(w), m.log_normaliser)
            for j, w in zip(record.landmark_ids, record.weights, strict=True)
        ]
        mixture = MaxMixtureFactor(X(m.pose_index), components, m.dim, self.null_nll(m))
        record.handles = [self.context.solver.add(mixture.factor())]
        record.active = int(np.argmax(record.weights))
        self._mixture_factors.append((record, mixture))
        return record

    def finish(self) -> None:
        """With CustomFactors, each record's final component is the one chosen at the end."""
        if not self._mixture_factors:
            return
        values = self.context.solver.estimate()
        for record, mixture in self._mixture_factors:
            costs = mixture.nll(values)
            best = int(np.argmin(costs))
            winner = NULL if best == len(record.landmark_ids) else best
            if winner != record.active:
                record.switches += 1
            record.active = winner

    def _best(self, records: list[AssociationRecord], estimates) -> list[int]:
        """Index of each record's winning component (NULL for the null hypothesis)."""
        mahalanobis = component_mahalanobis(records, estimates)
        # One row a record: its components' negative log-likelihoods, then the null's.
        table = np.full((len(records), 1 + max(len(m) for m in mahalanobis)), np.inf)
        for row, record, maha in zip(table, records, mahalanobis, strict=True):
            m = record.measurement
            row[: len(maha)] = component_nll(np.log(record.weights), maha, m.log_normaliser)
            if record.null_weight > 0:
                row[-1] = self.null_nll(m)
        best = np.argmin(table, axis=1)
        return [NULL if b == table.shape[1] - 1 else int(b) for b in best]

    def refine(self, moved: set[int]) -> list[AssociationRecord]:
        """Swap in the winning component wherever it changed, until none changes."""
        if self.in_factor:
            return []
        solver = self.context.solver
        changed: list[AssociationRecord] = []
        for _ in range(self.config.mixture.max_switch_rounds):
            records = self.affected(moved)
            if not records:
                break
            switched = []
            for record, winner in zip(
                records, self._best(records, self.context.estimates()), strict=True
            ):
                if winner == record.active:
                    continue
                self.context.remove_factors(record)
                if winner != NULL:
                    record.handles = [
                        self.context.add_factor(record.measurement, record.landmark_ids[winner])
                    ]
                record.active = winner
                record.switches += 1
                switched.append(record)
            if not switched:
                break
            changed += switched
            moved = self.context.after_update(solver.update())
        return changed

    def merge(self, survivor: int, duplicate: int) -> None:
        """Make `duplicate` one with `survivor`: every record that may be the duplicate now
        may be the survivor instead (components joined, weights summed), its factors
        re-pointed; the duplicate's variable leaves iSAM2 with its last factor."""
        context = self.context
        lms = context.landmarks.landmarks
        product = lms[survivor].class_probabilities * lms[duplicate].class_probabilities
        if product.sum() > 0:  # both posteriors hold the prior once too much; it is uniform
            lms[survivor].class_probabilities = product / product.sum()
        for record in context.records_of.pop(duplicate, []):
            context.remove_factors(record)
            active = record.landmark_id if record.active != NULL else NULL
            ids = [survivor if j == duplicate else j for j in record.landmark_ids]
            unique = list(dict.fromkeys(ids))
            weights = np.zeros(len(unique))
            for j, w in zip(ids, record.weights, strict=True):
                weights[unique.index(j)] += w
            record.landmark_ids, record.weights = unique, weights
            record.active = (
                NULL
                if active == NULL
                else unique.index(survivor if active == duplicate else active)
            )
            if record.active != NULL:
                record.handles = [context.add_factor(record.measurement, unique[record.active])]
            if record not in context.records_of[survivor]:
                context.records_of[survivor].append(record)
            self.retrack(record, L(survivor))
        anchor = lms[duplicate].anchor
        if anchor is not None:
            context.solver.remove(anchor)
        context.last_seen[survivor] = max(
            context.last_seen.get(survivor, -1), context.last_seen.pop(duplicate, -1)
        )
        context.landmarks.merge(duplicate, survivor)
