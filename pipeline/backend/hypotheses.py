"""Association records: which landmarks a detection may be, with what weights, and which of
them is in the graph now; and the evaluation of their components at the current estimate.

Where the max-mixture's component is chosen: a `CustomFactor` that picks it inside every
linearisation costs ~30 us a linearisation in Python against ~0.7 us for GTSAM's native
bearing-range factor. Instead, each record keeps the factor of its winning component in iSAM2 as
a native factor. After every update, the records whose variables iSAM2 marked (relinearised, or
touched by new or removed factors) are re-evaluated at the new estimate; where another component
now has the smaller negative log-likelihood, its factor is swapped in (DC-SAM alternates discrete
and continuous steps the same way). A variable iSAM2 does not mark has not been relinearised,
so its factors' linearisation, and hence the component a max-mixture factor would use, is
unchanged: this is the max-mixture evaluated at every linearisation, with native factors.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from gtsam.symbol_shorthand import L, X

from pipeline.backend.geometry import (
    point_residual,
    pose_residual_batch,
    predict_point_batch,
)
from pipeline.backend.landmarks import LandmarkKind
from pipeline.backend.measurements import Measurement
from pipeline.backend.movement import split_keys
from pipeline.backend.solver import Isam2Solver

NULL = -1  # landmark id and component index of the null hypothesis


@dataclass
class AssociationRecord:
    """One detection's hypotheses and the state of its factors in the graph."""

    measurement: Measurement
    landmark_ids: list[int]  # the components, null hypothesis excluded
    weights: np.ndarray  # association weights of the components (fixed; mm, ml)
    null_weight: float = 0.0  # > 0 when the null hypothesis is a component (mm-nh)
    active: int = 0  # component in the graph (index into landmark_ids), or NULL
    handles: list[int] = field(default_factory=list)  # factor handles in the solver
    graph_weights: np.ndarray | None = None  # GPDA: the weight each component's factor carries
    switches: int = 0

    @property
    def keys(self) -> list[int]:
        return [X(self.measurement.pose_index)] + [L(j) for j in self.landmark_ids]

    @property
    def is_mixture(self) -> bool:
        return len(self.landmark_ids) + (self.null_weight > 0) > 1

    @property
    def landmark_id(self) -> int:
        """The final association: the landmark in the graph, or NULL."""
        if self.graph_weights is not None:
            return self.landmark_ids[int(np.argmax(self.graph_weights))]
        return NULL if self.active == NULL else self.landmark_ids[self.active]

    @property
    def weight(self) -> float:
        if self.graph_weights is not None:
            return float(np.max(self.graph_weights))
        return self.null_weight if self.active == NULL else float(self.weights[self.active])


class EstimateCache:
    """Estimates of poses and landmarks, fetched from iSAM2 in as few calls as possible."""

    def __init__(self, solver: Isam2Solver, landmark_is_pose: np.ndarray):
        self.solver = solver
        self.landmark_is_pose = landmark_is_pose
        self._rows: dict[int, np.ndarray] = {}  # key -> [R (9), t (3)]

    def set_pose(self, index: int, pose) -> None:
        """A pose not in iSAM2 yet (the prediction of a new keyframe)."""
        self._rows[X(index)] = np.concatenate(
            [pose.rotation().matrix().ravel(), pose.translation()]
        )

    def fetch(self, pose_indices, landmark_ids) -> None:
        """Bring in every estimate not cached yet, in one iSAM2 call."""
        wanted = {X(int(i)) for i in pose_indices} | {L(int(j)) for j in landmark_ids}
        missing = sorted(wanted - self._rows.keys())
        if not missing:
            return
        is_robot, index = split_keys(np.array(missing, dtype=np.uint64))
        is_pose3 = is_robot.copy()
        is_pose3[~is_robot] = self.landmark_is_pose[index[~is_robot]]
        for key, row in zip(missing, self.solver.flat_estimates(missing, is_pose3), strict=True):
            self._rows[key] = row

    def rows(self, keys) -> np.ndarray:
        return np.stack([self._rows[k] for k in keys])

    def pose(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        self.fetch([index], [])
        row = self._rows[X(index)]
        return row[:9].reshape(3, 3), row[9:]

    def landmark(self, landmark_id: int):
        """(R, t) of a pose landmark, or the position of a point."""
        self.fetch([], [landmark_id])
        row = self._rows[L(landmark_id)]
        if self.landmark_is_pose[landmark_id]:
            return row[:9].reshape(3, 3), row[9:]
        return row[9:]


def component_mahalanobis(
    records: list[AssociationRecord], estimates: EstimateCache
) -> list[np.ndarray]:
    """|h(x, l_k) - z|^2 in Gamma's metric, for every component of every record, computed in
    one vectorised pass per kind of landmark."""
    out: list[np.ndarray] = [np.empty(len(r.landmark_ids)) for r in records]
    estimates.fetch(
        {r.measurement.pose_index for r in records}, {j for r in records for j in r.landmark_ids}
    )
    for kind in LandmarkKind:
        pairs = [
            (i, k)
            for i, r in enumerate(records)
            if r.measurement.kind is kind
            for k in range(len(r.landmark_ids))
        ]
        if not pairs:
            continue
        rec = [records[i].measurement for i, _ in pairs]
        pose = estimates.rows([X(m.pose_index) for m in rec])
        landmark = estimates.rows([L(records[i].landmark_ids[k]) for i, k in pairs])
        R_x, t_x = pose[:, :9].reshape(-1, 3, 3), pose[:, 9:]
        if kind is LandmarkKind.POSE:
            residual = pose_residual_batch(
                R_x,
                t_x,
                landmark[:, :9].reshape(-1, 3, 3),
                landmark[:, 9:],
                np.stack([m.relative_rotation for m in rec]),
                np.stack([m.relative_translation for m in rec]),
            )
        else:
            z_pred = predict_point_batch(R_x, t_x, landmark[:, 9:])
            residual = point_residual(z_pred, np.stack([m.vector for m in rec]))
        information = np.stack([m.information for m in rec])
        maha = np.einsum("ni,nij,nj->n", residual, information, residual)
        for (i, k), value in zip(pairs, maha, strict=True):
            out[i][k] = value
    return out
