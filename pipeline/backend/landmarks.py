"""Landmarks: their class posterior, their kind, and a spatial index of their estimates.

The index is a uniform grid (a dict from cell to ids), updated incrementally as estimates move,
so that finding candidates near a detection costs the cells it covers, not the size of the map.
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass, field
from enum import Enum

import numpy as np


class LandmarkKind(Enum):
    POINT = "point"  # position, measured by bearing/elevation/range
    POSE = "pose"  # 6-DoF (tags with relative_pose)


@dataclass
class Landmark:
    id: int
    kind: LandmarkKind
    class_probabilities: np.ndarray
    # The marginal covariance when last computed: an upper bound while no factor is removed.
    covariance_bound: np.ndarray | None = None
    anchor: int | None = None  # solver handle of its weak prior (point landmarks)

    @property
    def map_class(self) -> int:
        return int(np.argmax(self.class_probabilities))


class SpatialHash:
    """Ids at 3-D positions, bucketed into cubic cells of side `cell_size`."""

    def __init__(self, cell_size: float):
        if cell_size <= 0:
            raise ValueError("cell_size must be positive")
        self.cell_size = cell_size
        self._cells: dict[tuple[int, int, int], set[int]] = defaultdict(set)
        self._where: dict[int, tuple[int, int, int]] = {}
        self.positions: dict[int, np.ndarray] = {}

    def _cell(self, position: np.ndarray) -> tuple[int, int, int]:
        return tuple(math.floor(c / self.cell_size) for c in position)  # type: ignore[return-value]

    def __len__(self) -> int:
        return len(self.positions)

    def set(self, item: int, position: np.ndarray) -> None:
        position = np.asarray(position, dtype=float)
        cell = self._cell(position)
        old = self._where.get(item)
        if old != cell:
            if old is not None:
                self._cells[old].discard(item)
                if not self._cells[old]:
                    del self._cells[old]
            self._cells[cell].add(item)
            self._where[item] = cell
        self.positions[item] = position

    def remove(self, item: int) -> None:
        cell = self._where.pop(item)
        self._cells[cell].discard(item)
        if not self._cells[cell]:
            del self._cells[cell]
        del self.positions[item]

    def query(self, center: np.ndarray, radius: float) -> list[int]:
        """Ids within `radius` of `center`, in increasing order (deterministic)."""
        center = np.asarray(center, dtype=float)
        lo = self._cell(center - radius)
        hi = self._cell(center + radius)
        span = [high - low + 1 for low, high in zip(lo, hi, strict=True)]
        if span[0] * span[1] * span[2] > len(self._cells):
            # A radius wider than the occupied map: every item is a candidate.
            items = list(self.positions)
        else:
            items = [
                item
                for i in range(lo[0], hi[0] + 1)
                for j in range(lo[1], hi[1] + 1)
                for k in range(lo[2], hi[2] + 1)
                for item in self._cells.get((i, j, k), ())
            ]
        if not items:
            return []
        offsets = np.array([self.positions[item] for item in items]) - center
        inside = np.einsum("ij,ij->i", offsets, offsets) <= radius * radius
        return sorted(item for item, keep in zip(items, inside, strict=True) if keep)


@dataclass
class LandmarkMap:
    num_classes: int
    cell_size: float
    landmarks: dict[int, Landmark] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self._index = {kind: SpatialHash(self.cell_size) for kind in LandmarkKind}
        self._is_pose: list[bool] = []
        self.merged_into: dict[int, int] = {}  # duplicate id -> the landmark it was merged into
        # Landmarks out of the spatial index while no detection holds them (`withdraw`)
        self.withdrawn: set[int] = set()

    @property
    def next_id(self) -> int:
        return len(self._is_pose)

    def resolve(self, landmark_id: int) -> int:
        """The landmark that stands for `landmark_id` now (itself unless merged)."""
        while landmark_id in self.merged_into:
            landmark_id = self.merged_into[landmark_id]
        return landmark_id

    @property
    def is_pose(self) -> np.ndarray:
        """Per landmark id: whether it is a 6-DoF landmark."""
        return np.array(self._is_pose, dtype=bool)

    def __len__(self) -> int:
        return len(self.landmarks)

    def create(self, kind: LandmarkKind, position: np.ndarray) -> Landmark:
        landmark = Landmark(
            id=len(self._is_pose),  # ids are never reused, also after a merge
            kind=kind,
            class_probabilities=np.full(self.num_classes, 1.0 / self.num_classes),
        )
        self.landmarks[landmark.id] = landmark
        self._is_pose.append(kind is LandmarkKind.POSE)
        self._index[kind].set(landmark.id, position)
        return landmark

    def merge(self, duplicate: int, survivor: int) -> None:
        """Forget a landmark merged into another one."""
        landmark = self.landmarks.pop(duplicate)
        self._index[landmark.kind].remove(duplicate)
        self.merged_into[duplicate] = survivor

    def withdraw(self, landmark_id: int) -> None:
        """Take a landmark that no detection holds out of the spatial index, so that it is no
        detection's candidate, and keep it (a discrete-continuous method may take it back)."""
        if landmark_id not in self.withdrawn:
            self._index[self.landmarks[landmark_id].kind].remove(landmark_id)
            self.withdrawn.add(landmark_id)

    def reinstate(self, landmark_id: int, position: np.ndarray) -> None:
        """A withdrawn landmark held again, back in the index at `position`."""
        if landmark_id in self.withdrawn:
            self.withdrawn.discard(landmark_id)
            self.move(landmark_id, position)

    def discard(self, landmark_id: int) -> None:
        """Forget a withdrawn landmark: it is no landmark of the map."""
        self.withdrawn.remove(landmark_id)
        del self.landmarks[landmark_id]

    def move(self, landmark_id: int, position: np.ndarray) -> None:
        if landmark_id not in self.withdrawn:
            self._index[self.landmarks[landmark_id].kind].set(landmark_id, position)

    def position(self, landmark_id: int) -> np.ndarray:
        return self._index[self.landmarks[landmark_id].kind].positions[landmark_id]

    def near(self, kind: LandmarkKind, center: np.ndarray, radius: float) -> list[int]:
        return self._index[kind].query(center, radius)
