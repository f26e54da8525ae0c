"""Maximum-likelihood association: commit to the most likely candidate, for good."""

from __future__ import annotations

import numpy as np

from pipeline.backend.candidates import Candidates
from pipeline.backend.hypotheses import AssociationRecord
from pipeline.backend.measurements import Measurement
from pipeline.backend.methods.base import AssociationMethod, Keyframe


class MaximumLikelihood(AssociationMethod):
    name = "ml"

    def associate(
        self, m: Measurement, candidates: Candidates, keyframe: Keyframe
    ) -> AssociationRecord:
        if len(candidates) == 0:
            return self.new_landmark(m, keyframe)
        best = int(np.argmax(candidates.weights))
        landmark_id = int(candidates.landmark_ids[best])
        self.context.observe_classes(m, [landmark_id], np.ones(1))
        return self.single(m, landmark_id, float(candidates.weights[best]))
