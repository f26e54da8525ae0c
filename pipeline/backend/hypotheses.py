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
    """Per-key estimates fetched from iSAM2 once per evaluation round."""

    def __init__(self, solver: Isam2Solver, kinds: dict[int, LandmarkKind]):
        self.solver = solver
        self.kinds = kinds
        self._poses: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._landmarks: dict[int, object] = {}

    def set_pose(self, index: int, pose) -> None:
        self._poses[index] = (pose.rotation().matrix(), pose.translation())

    def pose(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        if index not in self._poses:
            p = self.solver.pose(X(index))
            self._poses[index] = (p.rotation().matrix(), p.translation())
        return self._poses[index]

    def landmark(self, landmark_id: int):
        if landmark_id not in self._landmarks:
            if self.kinds[landmark_id] is LandmarkKind.POSE:
                p = self.solver.pose(L(landmark_id))
                self._landmarks[landmark_id] = (p.rotation().matrix(), p.translation())
            else:
                self._landmarks[landmark_id] = self.solver.point(L(landmark_id))
        return self._landmarks[landmark_id]


def component_mahalanobis(
    records: list[AssociationRecord], estimates: EstimateCache
) -> list[np.ndarray]:
    """|h(x, l_k) - z|^2 in Gamma's metric, for every component of every record, computed in
    one vectorised pass per kind of landmark."""
    out: list[np.ndarray] = [np.empty(len(r.landmark_ids)) for r in records]
    for kind in LandmarkKind:
        pairs = [
            (i, k)
            for i, r in enumerate(records)
            if r.measurement.kind is kind
            for k in range(len(r.landmark_ids))
        ]
        if not pairs:
            continue
        rec = [records[i] for i, _ in pairs]
        poses = [estimates.pose(r.measurement.pose_index) for r in rec]
        R_x = np.stack([p[0] for p in poses])
        t_x = np.stack([p[1] for p in poses])
        lms = [estimates.landmark(records[i].landmark_ids[k]) for i, k in pairs]
        if kind is LandmarkKind.POSE:
            residual = pose_residual_batch(
                R_x,
                t_x,
                np.stack([lm[0] for lm in lms]),
                np.stack([lm[1] for lm in lms]),
                np.stack([r.measurement.relative_rotation for r in rec]),
                np.stack([r.measurement.relative_translation for r in rec]),
            )
        else:
            z_pred = predict_point_batch(R_x, t_x, np.stack(lms))
            residual = point_residual(z_pred, np.stack([r.measurement.vector for r in rec]))
        information = np.stack([r.measurement.information for r in rec])
        maha = np.einsum("ni,nij,nj->n", residual, information, residual)
        for (i, k), value in zip(pairs, maha, strict=True):
            out[i][k] = value
    return out
