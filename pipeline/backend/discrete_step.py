"""DC-SAM's discrete step: the associations of some detections, and the classes of the
landmarks they may be, set to their most probable explanation (MPE) given the continuous
estimate, by GTSAM's discrete solver (max-product elimination of a `DiscreteFactorGraph`).

Each detection's association A_i gets a unary factor exp(-cost) over its modes (the
continuous part, as GTSAM's `DiscreteBoundaryFactor` makes it from a hybrid factor). With more
than one class, each landmark j among the modes has a class variable C_j: a factor on
(A_i, C_j) is P(report_i | C_j) where A_i takes j and 1 elsewhere, and a unary factor on C_j
holds what the detections outside the step that j holds say (`class_evidence`). A new landmark
not made yet has a class no other detection shares: its report's best likelihood; the null's is
the report averaged over classes. Every factor is scaled to a maximum of 1, so that products of
many stay in range.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import gtsam
import numpy as np

from pipeline.backend.dcsam_model import mode_probabilities


@dataclass(frozen=True)
class DetectionModes:
    """One detection's association: K + 2 modes (K candidates, a new landmark, the null)."""

    costs: np.ndarray  # (K + 2,) negative log prior x likelihood, the class left out
    landmarks: tuple[int | None, ...]  # (K + 1,) each mode's landmark but the null's; None:
    # a new landmark not made yet
    report: np.ndarray  # (C,) P(reported class | true class c)

    @property
    def null(self) -> int:
        return len(self.landmarks)


@dataclass(frozen=True)
class DiscreteSolution:
    modes: list[int]  # each detection's mode
    classes: dict[int, int]  # each landmark's class (with more than one class)
    probabilities: list[np.ndarray]  # each detection's modes, at the classes found


def association_key(i: int) -> int:
    return gtsam.symbol("a", i)


def class_key(landmark_id: int) -> int:
    return gtsam.symbol("c", landmark_id)


def _scaled(potentials: np.ndarray) -> list[float]:
    """Potentials with their maximum 1 (all ones where every one is zero)."""
    top = float(np.max(potentials))
    return list(potentials / top) if top > 0 else [1.0] * len(potentials)


def unary_semantics(d: DetectionModes, classes: Mapping[int, int] | None) -> np.ndarray:
    """Each mode's report likelihood: at landmark j's class (`classes`; 1 without them), the
    best for a new landmark not made yet, the average for the null."""
    out = np.empty(len(d.costs))
    for mode, j in enumerate(d.landmarks):
        if j is None:
            out[mode] = float(np.max(d.report))
        else:
            out[mode] = 1.0 if classes is None else float(d.report[classes[j]])
    out[d.null] = float(np.mean(d.report))
    return out


def discrete_graph(
    detections: Sequence[DetectionModes], class_evidence: Mapping[int, np.ndarray] | None
) -> gtsam.DiscreteFactorGraph:
    """The factor graph of the step; `class_evidence` None: one class, no class variables."""
    graph = gtsam.DiscreteFactorGraph()
    for i, d in enumerate(detections):
        a = (association_key(i), len(d.costs))
        potentials = np.exp(-(d.costs - np.min(d.costs)))
        if class_evidence is not None:
            own = [m for m, j in enumerate(d.landmarks) if j is None] + [d.null]
            semantic = unary_semantics(d, None)
            potentials[own] *= semantic[own]
        graph.add(a, _scaled(potentials))
        if class_evidence is None:
            continue
        num_classes = len(d.report)
        for mode, j in enumerate(d.landmarks):
            if j is None:
                continue
            table = np.ones((len(d.costs), num_classes))
            table[mode] = d.report
            graph.add([a, (class_key(j), num_classes)], _scaled(table.ravel()))
    if class_evidence is not None:
        for j in sorted({j for d in detections for j in d.landmarks if j is not None}):
            evidence = np.asarray(class_evidence[j], dtype=float)
            top = np.max(evidence)
            potentials = np.exp(evidence - top) if np.isfinite(top) else np.ones(len(evidence))
            graph.add((class_key(j), len(evidence)), _scaled(potentials))
    return graph


def solve(
    detections: Sequence[DetectionModes], class_evidence: Mapping[int, np.ndarray] | None
) -> DiscreteSolution:
    """The MPE of the detections' associations (and, with `class_evidence`, of the classes of
    every landmark among their modes: what the detections outside the step say of each, as
    log P(reports | c))."""
    if not detections:
        return DiscreteSolution([], {}, [])
    mpe = discrete_graph(detections, class_evidence).optimize()
    modes = [int(mpe[association_key(i)]) for i in range(len(detections))]
    classes = {}
    if class_evidence is not None:
        landmarks = {j for d in detections for j in d.landmarks if j is not None}
        classes = {j: int(mpe[class_key(j)]) for j in sorted(landmarks)}
    with np.errstate(divide="ignore"):  # a report a class never gives rules that mode out
        probabilities = [
            mode_probabilities(d.costs - np.log(unary_semantics(d, classes or None)))
            for d in detections
        ]
    return DiscreteSolution(modes, classes, probabilities)
