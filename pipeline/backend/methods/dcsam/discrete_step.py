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

The exact MPE couples every detection that may take a landmark with every other that may take
the same one, through the landmark's class; across an aliased street those chains join many
landmarks, and eliminating them grows tables exponentially in their number (a city grid's
log: 10 GB, not done after 20 minutes). So each group of detections linked through landmarks
is solved exactly (associations eliminated first, then classes) only where it holds at most
`exact_class_variables` landmarks; a larger group is solved by turns, each exactly given the
other: the associations given the classes, the classes given the associations, from the
classes the outside evidence favours, until neither changes (each turn can only raise the
probability, so it ends), as DC-SAM itself alternates discrete and continuous.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import gtsam
import numpy as np

from pipeline.backend.methods.dcsam.model import mode_probabilities


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


def groups(detections: Sequence[DetectionModes]) -> list[list[int]]:
    """The detections (by index) linked through landmarks they may both take, each group in
    order, the groups by their first detection."""
    parent = list(range(len(detections)))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    first_of: dict[int, int] = {}
    for i, d in enumerate(detections):
        for j in d.landmarks:
            if j is None:
                continue
            if j in first_of:
                parent[root(i)] = root(first_of[j])
            else:
                first_of[j] = i
    members: dict[int, list[int]] = {}
    for i in range(len(detections)):
        members.setdefault(root(i), []).append(i)
    return sorted(members.values())


def landmarks_of(detections: Sequence[DetectionModes]) -> list[int]:
    return sorted({j for d in detections for j in d.landmarks if j is not None})


def exact(
    detections: Sequence[DetectionModes], class_evidence: Mapping[int, np.ndarray] | None
) -> tuple[list[int], dict[int, int]]:
    """The MPE by max-product, the associations eliminated first."""
    graph = discrete_graph(detections, class_evidence)
    ordering = gtsam.Ordering()
    for i in range(len(detections)):
        ordering.push_back(association_key(i))
    landmarks = landmarks_of(detections) if class_evidence is not None else []
    for j in landmarks:
        ordering.push_back(class_key(j))
    mpe = graph.maxProduct(ordering).argmax()
    modes = [int(mpe[association_key(i)]) for i in range(len(detections))]
    return modes, {j: int(mpe[class_key(j)]) for j in landmarks}


def by_turns(
    detections: Sequence[DetectionModes],
    class_evidence: Mapping[int, np.ndarray],
    max_turns: int = 100,
) -> tuple[list[int], dict[int, int]]:
    """Associations given classes, then classes given associations, until neither changes."""
    landmarks = landmarks_of(detections)
    classes = {j: int(np.argmax(class_evidence[j])) for j in landmarks}
    modes: list[int] = []
    with np.errstate(divide="ignore"):  # a report a class never gives rules that mode out
        logs = [np.log(d.report) for d in detections]
        for _ in range(max_turns):
            new_modes = [
                int(np.argmin(d.costs - np.log(unary_semantics(d, classes)))) for d in detections
            ]
            evidence = {j: np.array(class_evidence[j], dtype=float) for j in landmarks}
            for d, mode, log_report in zip(detections, new_modes, logs, strict=True):
                j = d.landmarks[mode] if mode < d.null else None
                if j is not None:
                    evidence[j] = evidence[j] + log_report
            new_classes = {j: int(np.argmax(e)) for j, e in evidence.items()}
            if new_modes == modes and new_classes == classes:
                break
            modes, classes = new_modes, new_classes
    return modes, classes


def solve(
    detections: Sequence[DetectionModes],
    class_evidence: Mapping[int, np.ndarray] | None,
    exact_class_variables: int = 8,
) -> DiscreteSolution:
    """The MPE of the detections' associations (and, with `class_evidence`, of the classes of
    every landmark among their modes: what the detections outside the step say of each, as
    log P(reports | c)); by turns in a group of more than `exact_class_variables` landmarks."""
    if not detections:
        return DiscreteSolution([], {}, [])
    if class_evidence is None:
        modes, classes = exact(detections, None)
    else:
        modes = [0] * len(detections)
        classes = {}
        small: list[int] = []
        for group in groups(detections):
            members = [detections[i] for i in group]
            if len(landmarks_of(members)) <= exact_class_variables:
                small += group
                continue
            group_modes, group_classes = by_turns(members, class_evidence)
            for i, mode in zip(group, group_modes, strict=True):
                modes[i] = mode
            classes.update(group_classes)
        if small:  # every small group at once: they share no variable
            small_modes, small_classes = exact([detections[i] for i in small], class_evidence)
            for i, mode in zip(small, small_modes, strict=True):
                modes[i] = mode
            classes.update(small_classes)
    with np.errstate(divide="ignore"):  # a report a class never gives rules that mode out
        probabilities = [
            mode_probabilities(d.costs - np.log(unary_semantics(d, classes or None)))
            for d in detections
        ]
    return DiscreteSolution(modes, classes, probabilities)
