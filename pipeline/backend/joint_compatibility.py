"""Which landmarks are one and the same: joint compatibility over pairs, with a uniqueness test.

A detection that fits no landmark at the predicted pose starts a landmark of its own
(`decisions.py`). When it was in fact a landmark seen before (a loop closure the odometry did
not support, or a re-observation that narrowly failed the gate) the map now holds a duplicate.
Merging them is the delayed, joint re-test of those associations: every recently observed
landmark is paired with the landmarks it could be, and the pairs are tested together, so that
several small pieces of evidence agreeing on one correction of the map can outweigh what none
of them shows alone (joint compatibility branch and bound, Neira and Tardos 2001).

Everything here is pure: differences of landmark estimates and their joint covariance in, the
pairs to merge out. A pair is merged only when it is part of the largest jointly compatible set
and no other set that disagrees with it about either landmark is as large (`margin` fewer
pairs at most): in an aliased world, a set of pairs shifted by one parked car can be jointly
compatible too, and then nothing is merged until more evidence tells the two apart.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PairSet:
    """Candidate pairs (source, target) and the joint covariance of their differences."""

    pairs: list[tuple[int, int]]  # landmark ids; the source is the one observed recently
    differences: np.ndarray  # (P, d): estimate of source minus estimate of target
    covariance: np.ndarray  # (P d, P d): joint covariance of the stacked differences
    loop: np.ndarray  # (P,) bool: the target was last seen long ago (a loop closure)
    # Whether two landmarks could be one (their difference passes the gate): a pair and a rival
    # that differ only by such landmarks are both right, and merges will join all three.
    alike: Callable[[int, int], bool] = lambda a, b: False

    @property
    def dim(self) -> int:
        return self.differences.shape[1]

    def joint_mahalanobis_sq(self, chosen: list[int]) -> float:
        """Squared Mahalanobis distance of the stacked differences of pairs `chosen`."""
        if not chosen:
            return 0.0
        d = self.dim
        index = np.concatenate([np.arange(p * d, (p + 1) * d) for p in chosen])
        C = self.covariance[np.ix_(index, index)]
        r = self.differences[chosen].ravel()
        return float(r @ np.linalg.solve(C, r))


def difference_covariance(
    landmark_covariance: np.ndarray, pairs: list[tuple[int, int]], slots: dict[int, int], dim: int
) -> np.ndarray:
    """Joint covariance of the differences l_a - l_b of `pairs`, from the joint covariance of
    the landmarks (`slots[j]` = landmark j's block index in it)."""
    n = landmark_covariance.shape[0]
    D = np.zeros((len(pairs) * dim, n))
    eye = np.eye(dim)
    for p, (a, b) in enumerate(pairs):
        D[p * dim : (p + 1) * dim, slots[a] * dim : (slots[a] + 1) * dim] += eye
        D[p * dim : (p + 1) * dim, slots[b] * dim : (slots[b] + 1) * dim] -= eye
    C = D @ landmark_covariance @ D.T
    return 0.5 * (C + C.T)


@dataclass
class _Search:
    pair_set: PairSet
    by_source: list[list[int]]  # per source (in search order), its pair indices
    threshold: dict[int, float]  # chi-square gate by number of pairs
    max_nodes: int
    required_first: bool = False  # the first source's pair is required: no "none" branch
    nodes: int = 0
    exhausted: bool = False
    best: tuple[int, ...] = ()
    best_d2: float = 0.0

    def run(self) -> tuple[int, ...]:
        self._visit(0, [], set())
        return self.best

    def _better(self, chosen: list[int], d2: float) -> bool:
        if len(chosen) != len(self.best):
            return len(chosen) > len(self.best)
        return d2 < self.best_d2

    def _visit(self, depth: int, chosen: list[int], used: set[int]) -> None:
        self.nodes += 1
        if self.nodes > self.max_nodes:
            self.exhausted = True
            return
        if depth == len(self.by_source):
            d2 = self.pair_set.joint_mahalanobis_sq(chosen)
            if self._better(chosen, d2):
                self.best, self.best_d2 = tuple(chosen), d2
            return
        # Bound: even pairing every remaining source cannot beat the best.
        if len(chosen) + len(self.by_source) - depth < len(self.best):
            return
        options = self.by_source[depth]
        for p in options:
            a, b = self.pair_set.pairs[p]
            if a in used or b in used:
                continue
            trial = [*chosen, p]
            if self.pair_set.joint_mahalanobis_sq(trial) <= self.threshold[len(trial)]:
                self._visit(depth + 1, trial, used | {a, b})
        if not (self.required_first and depth == 0):
            self._visit(depth + 1, chosen, used)


def _chi2_gates(count: int, dim: int, confidence: float) -> dict[int, float]:
    from scipy.special import chdtri

    return {k: float(chdtri(k * dim, 1.0 - confidence)) for k in range(1, count + 1)}


def jointly_compatible(
    pair_set: PairSet,
    confidence: float,
    max_nodes: int,
    forbidden: frozenset[int] = frozenset(),
    required: int | None = None,
) -> tuple[tuple[int, ...], bool]:
    """The largest jointly compatible set of pairs (ties: the smallest joint distance), each
    landmark in one pair at most, without the `forbidden` pairs and with the `required` one;
    and whether the search finished within `max_nodes` nodes."""
    sources = sorted({a for a, _ in pair_set.pairs})
    by_source = [
        [p for p, (a, _) in enumerate(pair_set.pairs) if a == s and p not in forbidden]
        for s in sources
    ]
    if required is not None:
        # The required pair first: the search starts from it, and no other pair of its source.
        source = pair_set.pairs[required][0]
        by_source = [[required]] + [
            options for s, options in zip(sources, by_source, strict=True) if s != source
        ]
    gates = _chi2_gates(len(sources), pair_set.dim, confidence)
    search = _Search(pair_set, by_source, gates, max_nodes, required is not None)
    return search.run(), not search.exhausted


def _same_but_alike(pair_set: PairSet, p: tuple[int, int], q: tuple[int, int]) -> bool:
    """Whether q pairs one of p's landmarks with a landmark alike to p's other one."""
    shared = set(p) & set(q)
    if len(shared) != 1:
        return False
    (s,) = shared
    x = p[0] if p[1] == s else p[1]
    y = q[0] if q[1] == s else q[1]
    return pair_set.alike(x, y)


def pairs_to_merge(
    pair_set: PairSet,
    confidence: float,
    margin: int,
    min_loop_pairs: int,
    max_nodes: int,
) -> list[tuple[int, int]]:
    """The pairs of the largest jointly compatible set that no rival explains as well.

    A rival of pair (a, b) is a jointly compatible set that pairs a or b with another landmark;
    (a, b) is kept only if every rival has fewer pairs than the largest set, by more than
    `margin`. Loop-closing pairs (targets last seen long ago) are kept only if at least
    `min_loop_pairs` of them are kept together. An unfinished search decides nothing."""
    if not pair_set.pairs:
        return []
    best, finished = jointly_compatible(pair_set, confidence, max_nodes)
    if not finished or not best:
        return []
    kept = []
    for p in best:
        a, b = pair_set.pairs[p]
        rivals = [q for q, (c, e) in enumerate(pair_set.pairs) if q != p and ({c, e} & {a, b})]
        contested = False
        for q in rivals:
            rival, rival_finished = jointly_compatible(
                pair_set, confidence, max_nodes, frozenset({p}), required=q
            )
            if not rival_finished or len(rival) >= len(best) - margin:
                contested = True
                break
        if not contested:
            kept.append(p)
    loops = [p for p in kept if pair_set.loop[p]]
    if len(loops) < min_loop_pairs:
        kept = [p for p in kept if not pair_set.loop[p]]
    return [pair_set.pairs[p] for p in kept]
