"""Known data association: the log's `truth_landmark_id` decides. The reference."""

from __future__ import annotations

import numpy as np

from pipeline.backend.candidates import Candidates
from pipeline.backend.hypotheses import NULL, AssociationRecord
from pipeline.backend.measurements import Measurement
from pipeline.backend.methods.base import AssociationMethod, BackendContext, Keyframe
from pipeline.errors import InputError


class KnownAssociation(AssociationMethod):
    name = "known"
    uses_candidates = False

    def __init__(self, context: BackendContext):
        super().__init__(context)
        self._landmark_of_truth: dict[int, int] = {}

    def associate(
        self, m: Measurement, candidates: Candidates, keyframe: Keyframe
    ) -> AssociationRecord:
        truth = m.detection.truth_landmark_id
        if truth is None:
            raise InputError(
                f"method 'known' needs truth_landmark_id on every detection; detection "
                f"{m.detection_index} of pose {m.pose_index} has none"
            )
        if truth == NULL:  # a false positive: known association leaves it out
            return AssociationRecord(m, [], np.zeros(0), null_weight=1.0, active=NULL)
        if truth in self._landmark_of_truth:
            landmark_id = self._landmark_of_truth[truth]
            self.context.observe_classes(m, [landmark_id], np.ones(1))
            return self.single(m, landmark_id)
        record = self.new_landmark(m, keyframe)
        self._landmark_of_truth[truth] = record.landmark_ids[0]
        return record
