"""A thin iSAM2 wrapper: batched factor additions and removals, handles for factors, and the
estimates and marginals the association step asks for."""

from __future__ import annotations

import gtsam
import numpy as np

from pipeline.config import Isam2Config
from pipeline.errors import SolverError, first_line


class Isam2Solver:
    """Collects factors and values, then applies them in one iSAM2 update.

    Factors are named by handles (ints given by `add`), because iSAM2 only tells a factor's slot
    after the update that inserts it; `remove` takes a handle of an already committed factor.
    """

    def __init__(self, config: Isam2Config):
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(config.relinearize_threshold)
        params.relinearizeSkip = config.relinearize_skip
        params.setFactorization(config.factorization)
        self.isam = gtsam.ISAM2(params)
        self._pending: dict[int, gtsam.NonlinearFactor] = {}  # handle -> factor, in order
        self._values = gtsam.Values()
        self._removals: list[int] = []
        self._slots: dict[int, int] = {}
        self._next_handle = 0
        self.num_updates = 0

    def add(self, factor: gtsam.NonlinearFactor) -> int:
        handle = self._next_handle
        self._next_handle += 1
        self._pending[handle] = factor
        return handle

    def insert(self, key: int, value) -> None:
        self._values.insert(key, value)

    def remove(self, handle: int) -> None:
        """Take a factor out: a committed one at the next update, a pending one at once."""
        if self._pending.pop(handle, None) is None:
            self._removals.append(self._slots.pop(handle))

    @property
    def has_pending(self) -> bool:
        return bool(self._pending) or bool(self._removals)

    def update(self) -> set[int]:
        """Apply what is pending; returns iSAM2's marked keys (new factors' keys, removed
        factors' keys and every relinearised variable): the variables whose estimate moved."""
        graph = gtsam.NonlinearFactorGraph()
        for factor in self._pending.values():
            graph.add(factor)
        try:
            result = self.isam.update(graph, self._values, self._removals)
        except RuntimeError as exc:
            message = f"iSAM2 update {self.num_updates} failed: {first_line(str(exc))}"
            raise SolverError(message) from exc
        for handle, slot in zip(self._pending, result.getNewFactorsIndices(), strict=True):
            self._slots[handle] = slot
        self._values = gtsam.Values()
        self._pending = {}
        self._removals = []
        self.num_updates += 1
        return set(result.getMarkedKeys())

    def pose(self, key: int) -> gtsam.Pose3:
        return self.isam.calculateEstimatePose3(key)

    def point(self, key: int) -> np.ndarray:
        return self.isam.calculateEstimatePoint3(key)

    def estimate(self) -> gtsam.Values:
        return self.isam.calculateEstimate()

    def flat_estimates(self, keys: list[int], is_pose3: np.ndarray) -> np.ndarray:
        """Estimates of `keys` (sorted, unique) in one call, as rows [R (9, row-major), t (3)];
        a point's rotation part is zero. `is_pose3[i]` tells a Pose3 from a Point3."""
        out = np.zeros((len(keys), 12))
        if not keys:
            return out
        values = self.isam.calculateEstimate(keys)
        if np.any(is_pose3):
            out[is_pose3] = gtsam.utilities.extractPose3(values)
        if not np.all(is_pose3):
            out[~is_pose3, 9:] = gtsam.utilities.extractPoint3(values)
        return out

    def marginal_covariance(self, key: int) -> np.ndarray:
        return self.isam.marginalCovariance(key)

    def joint_covariance(self, keys: list[int]) -> np.ndarray:
        """Joint marginal covariance of `keys`, blocks in the order given."""
        return self.isam.jointMarginalCovariance(keys).fullMatrix()
