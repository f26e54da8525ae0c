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
        # The same positions by item (ids are small non-negative ints), for gathers in one call
        self._table = np.full((0, 3), np.nan)

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
        if item >= len(self._table):
            grown = np.full((max(item + 1, 2 * len(self._table)), 3), np.nan)
            grown[: len(self._table)] = self._table
            self._table = grown
        self._table[item] = position

    def table(self, items: list[int]) -> np.ndarray:
        """(n, 3): the positions of `items`, each in the index (a gather of the same numbers)."""
        return self._table[np.asarray(items, dtype=int).reshape(-1)]

    def remove(self, item: int) -> None:
        cell = self._where.pop(item)
        self._cells[cell].discard(item)
        if not self._cells[cell]:
            del self._cells[cell]
        del self.positions[item]
        self._table[item] = np.nan

    def query(self, center: np.ndarray, radius: float) -> list[int]:
        """Ids within `radius` of `center`, in increasing order (deterministic)."""
        return self.query_many(np.reshape(center, (1, 3)), np.array([radius]))[0]

    def query_many(self, centers: np.ndarray, radii: np.ndarray) -> list[list[int]]:
        """`query` of (n, 3) centres with (n,) radii: the items of every cell the balls' boxes
        touch are gathered once, and each ball keeps those within its radius."""
        centers = np.asarray(centers, dtype=float)
        radii = np.asarray(radii, dtype=float)
        lo = np.floor((centers - radii[:, None]) / self.cell_size).astype(int)
        hi = np.floor((centers + radii[:, None]) / self.cell_size).astype(int)
        if np.any(np.prod(hi - lo + 1, axis=1) > len(self._cells)):
            # A radius wider than the occupied map: every item is a candidate.
            items = set(self.positions)
        else:
            cells = {
                (i, j, k)
                for low, high in zip(lo.tolist(), hi.tolist(), strict=True)
                for i in range(low[0], high[0] + 1)
                for j in range(low[1], high[1] + 1)
                for k in range(low[2], high[2] + 1)
            }
            items = set().union(*(self._cells.get(cell, ()) for cell in cells))
        if not items:
            return [[] for _ in radii]
        ids = np.array(sorted(items))
        offsets = self._table[ids][None] - centers[:, None]
        inside = np.einsum("nmi,nmi->nm", offsets, offsets) <= (radii * radii)[:, None]
        return [ids[row].tolist() for row in inside]


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

    def positions(self, kind: LandmarkKind, ids: list[int]) -> np.ndarray:
        """(n, 3): `position` of each of `ids`, all of `kind` and in its index, in one gather."""
        return self._index[kind].table(ids)

    def near(self, kind: LandmarkKind, center: np.ndarray, radius: float) -> list[int]:
        return self._index[kind].query(center, radius)

    def near_many(
        self, kinds: list[LandmarkKind], centers: np.ndarray, radii: np.ndarray
    ) -> list[list[int]]:
        """`near` of several (kind, centre, radius), each kind's searched together."""
        out: list[list[int]] = [[] for _ in kinds]
        for kind in LandmarkKind:
            rows = [i for i, k in enumerate(kinds) if k is kind]
            if rows:
                found = self._index[kind].query_many(centers[rows], radii[rows])
                for i, ids in zip(rows, found, strict=True):
                    out[i] = ids
        return out
