"""Semantic max-mixture factors (`mm`), with the null hypothesis (`mm-nh`).

A detection's factor is max_k w_k N(h(x, l_k) - z; 0, Gamma): the component with the smallest
negative log-likelihood, normalisers included, is the one in the graph. With the null
hypothesis, a component of weight `null_weight` and standard deviation `null_sigma` competes:
when it wins, the detection pulls on nothing, and a wrong loop closure is rejected.
See `pipeline/backend/hypotheses.py` for how the component is kept current.
"""

from __future__ import annotations

import numpy as np
from gtsam.symbol_shorthand import L, X

from pipeline.backend.association import with_null_hypothesis
from pipeline.backend.candidates import Candidates
from pipeline.backend.hypotheses import NULL, AssociationRecord, component_mahalanobis
from pipeline.backend.measurements import Measurement
from pipeline.backend.methods.base import BackendContext, MixtureMethod
from pipeline.backend.mixture import component_nll, null_component_nll
from pipeline.backend.mixture_factor import MaxMixtureFactor, component


class MaxMixture(MixtureMethod):
    name = "mm"

    def __init__(self, context: BackendContext, null_hypothesis: bool = False):
        super().__init__(context)
        a = self.config.association
        self.null_weight = a.null_weight if null_hypothesis else 0.0
        self.null_sigma = a.null_sigma
        self.name = "mm-nh" if null_hypothesis else "mm"
        self.in_factor = self.config.mixture.selection == "custom-factor"
        self._mixture_factors: list[tuple[AssociationRecord, MaxMixtureFactor]] = []

    def associate(self, m: Measurement, candidates: Candidates) -> AssociationRecord:
        if len(candidates) == 0:
            return self.new_landmark(m)
        weights = candidates.weights
        if self.null_weight > 0:
            weights, _ = with_null_hypothesis(weights, self.null_weight)
        ids = [int(j) for j in candidates.landmark_ids]
        self.context.observe_classes(m, ids, weights, self.null_weight)
        record = AssociationRecord(m, ids, weights, null_weight=self.null_weight, active=NULL)
        if not record.is_mixture:
            record.active = 0
            record.handles = [self.context.add_factor(m, ids[0])]
            return record
        if self.in_factor:
            return self._custom_factor(record)
        # The first choice is the most probable association, the pose and landmarks
        # marginalised out (the weights); measured at the predicted pose alone, a detection
        # after a large odometry error would look like an outlier to every landmark.
        best = int(np.argmax(weights))
        record.active = NULL if self.null_weight > weights[best] else best
        if record.active != NULL:
            record.handles = [self.context.add_factor(m, ids[record.active])]
        return self.track(record)

    def _custom_factor(self, record: AssociationRecord) -> AssociationRecord:
        """The mixture as one CustomFactor choosing at every linearisation (no `refine`)."""
        m = record.measurement
        components = [
            component(m.factor(X(m.pose_index), L(j)), float(w))
            for j, w in zip(record.landmark_ids, record.weights, strict=True)
        ]
        mixture = MaxMixtureFactor(
            X(m.pose_index), components, m.dim, self.null_weight, self.null_sigma
        )
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
                row[-1] = null_component_nll(record.null_weight, self.null_sigma, m.dim)
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
