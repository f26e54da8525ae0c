"""Which variables moved since the association step last looked at them.

After an iSAM2 update, only the variables iSAM2 marked (relinearised, or touched by new or
removed factors) can have moved past the relinearisation threshold. Their estimates are fetched
in one call and compared, vectorised, with the values kept from the last time they moved.
"""

from __future__ import annotations

import numpy as np

_INDEX_MASK = (1 << 56) - 1
_POSE = ord("x")


def split_keys(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Symbol keys (uint64) to (is a robot pose X(i), index i or landmark id)."""
    keys = np.asarray(keys, dtype=np.uint64)
    return (keys >> np.uint64(56)).astype(np.int64) == _POSE, (
        keys & np.uint64(_INDEX_MASK)
    ).astype(np.int64)


def is_landmark_key(key: int) -> bool:
    return (int(key) >> 56) != _POSE


def key_index(key: int) -> int:
    return int(key) & _INDEX_MASK


class MovementTracker:
    def __init__(self, threshold: float):
        self.threshold = threshold
        # Rows: [R (9, row-major), t (3)] per pose index / landmark id; NaN = never seen.
        self._poses = np.full((0, 12), np.nan)
        self._landmarks = np.full((0, 12), np.nan)

    @staticmethod
    def _grow(table: np.ndarray, size: int) -> np.ndarray:
        if size <= len(table):
            return table
        grown = np.full((max(size, 2 * len(table)), 12), np.nan)
        grown[: len(table)] = table
        return grown

    def moved(
        self, solver, marked: set[int], landmark_is_pose: np.ndarray
    ) -> tuple[set[int], dict[int, np.ndarray]]:
        """The marked keys that moved, and the new positions of the landmarks among them.

        `landmark_is_pose[j]` tells whether landmark j is a Pose3 (else a Point3)."""
        if not marked:
            return set(), {}
        keys = np.array(sorted(marked), dtype=np.uint64)
        is_robot, index = split_keys(keys)
        is_pose3 = is_robot.copy()
        is_pose3[~is_robot] = landmark_is_pose[index[~is_robot]]
        current = solver.flat_estimates([int(k) for k in keys], is_pose3)

        self._poses = self._grow(self._poses, int(index[is_robot].max(initial=-1)) + 1)
        self._landmarks = self._grow(self._landmarks, int(index[~is_robot].max(initial=-1)) + 1)
        last = np.full_like(current, np.nan)
        last[is_robot] = self._poses[index[is_robot]]
        last[~is_robot] = self._landmarks[index[~is_robot]]
        with np.errstate(invalid="ignore"):
            stayed = np.max(np.abs(current - last), axis=1) <= self.threshold  # NaN: new
        moved = ~stayed
        self._poses[index[moved & is_robot]] = current[moved & is_robot]
        self._landmarks[index[moved & ~is_robot]] = current[moved & ~is_robot]
        positions = {
            int(j): current[row, 9:]
            for row, j in enumerate(index)
            if moved[row] and not is_robot[row]
        }
        return {int(k) for k in keys[moved]}, positions
