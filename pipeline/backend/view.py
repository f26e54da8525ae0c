"""The back-end's map as viewers may see it: estimates, covariances, counts; nothing to edit.

A sink (`pipeline/viz`, `pipeline/foxglove`) gets one with every keyframe's report. It reads
the map as it stands after the keyframe; what it asks is answered from iSAM2's current estimate
and the covariances the association already computed, so that watching a replay does not
change it.
"""

from __future__ import annotations

import numpy as np
from gtsam.symbol_shorthand import L

from pipeline.backend.landmarks import LandmarkMap
from pipeline.backend.solver import Isam2Solver


class ReadOnlyMap:
    def __init__(self, solver: Isam2Solver, landmarks: LandmarkMap, switches: int, merges: int):
        self._solver = solver
        self._landmarks = landmarks
        self.switches = switches  # associations changed so far
        self.merges = merges  # landmarks merged so far

    @property
    def landmarks(self) -> LandmarkMap:
        """The landmark table: each landmark's kind, class posterior, last covariance; merged
        ids resolved (`resolve`). To read, never to edit."""
        return self._landmarks

    def flat_estimates(self, keys: list[int], is_pose3: np.ndarray) -> np.ndarray:
        """Estimates of `keys` (sorted, unique) as rows [R (9, row-major), t (3)]
        (`Isam2Solver.flat_estimates`)."""
        return self._solver.flat_estimates(keys, is_pose3)

    def landmark_covariance(self, landmark_id: int, fresh: bool = False) -> np.ndarray | None:
        """The landmark's covariance as the association last computed it (an upper bound, or
        its marginal), or None if none is held; `fresh`: its marginal now, from iSAM2."""
        if fresh:
            return self._solver.marginal_covariance(L(landmark_id))
        return self._landmarks.landmarks[landmark_id].covariance_bound
