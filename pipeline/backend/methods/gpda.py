"""Gaussian probabilistic data association (Bowman et al. 2017), by expectation-maximisation.

Every gated candidate gets a factor whose information is scaled by its association weight.
After each update the weights of the records iSAM2 marked are recomputed from the current
point estimate (E-step: semantic likelihood times N(h(x, l_k) - z; 0, Gamma)), their factors
are replaced where a weight moved by more than the tolerance, and iSAM2 updates again (M-step),
until the weights settle or the iteration limit is reached.
"""

from __future__ import annotations

import numpy as np

from pipeline.backend.candidates import Candidates
from pipeline.backend.hypotheses import AssociationRecord, component_mahalanobis
from pipeline.backend.measurements import Measurement
from pipeline.backend.methods.base import Keyframe, MixtureMethod
from pipeline.backend.mixture import em_weights


class GaussianPDA(MixtureMethod):
    name = "gpda"

    def associate(
        self, m: Measurement, candidates: Candidates, keyframe: Keyframe
    ) -> AssociationRecord:
        if len(candidates) == 0:
            return self.new_landmark(m, keyframe)
        ids = [int(j) for j in candidates.landmark_ids]
        self.context.observe_classes(m, ids, candidates.weights)
        # The record's fixed `weights` hold the semantic likelihoods: the E-step's prior.
        record = AssociationRecord(m, ids, candidates.semantic.copy())
        self._put_factors(record, candidates.weights)
        return self.track(record) if len(ids) > 1 else record

    def _put_factors(self, record: AssociationRecord, weights: np.ndarray) -> None:
        self.context.remove_factors(record)
        record.handles = [
            self.context.add_factor(record.measurement, j, float(w))
            for j, w in zip(record.landmark_ids, weights, strict=True)
            if w >= self.config.association.min_weight
        ]
        record.graph_weights = np.asarray(weights, dtype=float)

    def refine(self, moved: set[int]) -> list[AssociationRecord]:
        solver = self.context.solver
        tolerance = self.config.gpda.weight_tolerance
        changed: list[AssociationRecord] = []
        for _ in range(self.config.gpda.max_iterations):
            records = self.affected(moved)
            if not records:
                break
            reweighted = 0
            mahalanobis = component_mahalanobis(records, self.context.estimates())
            for record, maha in zip(records, mahalanobis, strict=True):
                # Components share Gamma, so the Gaussian's normaliser cancels.
                weights = em_weights(np.log(record.weights)[None], -0.5 * maha[None])[0]
                if np.max(np.abs(weights - record.graph_weights)) <= tolerance:
                    continue
                if np.argmax(weights) != np.argmax(record.graph_weights):
                    record.switches += 1
                    changed.append(record)
                self._put_factors(record, weights)
                reweighted += 1
            if not reweighted:
                break
            moved = self.context.after_update(solver.update())
        return changed
