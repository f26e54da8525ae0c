"""Which landmarks are one and the same: a joint likelihood test over pairs, with a uniqueness
test.

A detection that fits no landmark well enough starts a landmark of its own
(`joint_association.py`). When it was in fact a landmark seen before (a loop closure the
odometry could not support alone, or a re-observation that narrowly failed the gate) the map
now holds a duplicate. Merging them is the delayed, joint re-test of those associations: every
recently observed landmark is paired with the landmarks it could be, and the pairs are tested
together, so that several small pieces of evidence agreeing on one correction of the map can
outweigh what none of them shows alone (joint compatibility, Neira and Tardos 2001, scored by
likelihood rather than by count).

A set H of pairs scores the log-likelihood ratio of "each pair is one landmark" against "each
source is a landmark of its own":

    log N(d_H; 0, C_H) + sum over pairs of log_prior

d_H the stacked differences of the pairs' estimates, C_H their joint covariance, and a pair's
log_prior the log of the density at which a landmark of its own could have appeared there,
inverted (the sensor's field of view), plus the prior odds and the class agreement. A large
shared uncertainty (a long drift) spreads N, so that a few pairs agreeing by chance score
little, while many agreeing pairs, or pairs of tightly known landmarks, score a lot.

Everything here is pure: differences and their covariance in, the pairs to merge out.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from pipeline.backend.association import LOG_2PI


@dataclass(frozen=True)
class PairSet:
    """Candidate pairs (source, target) and the joint covariance of their differences."""

    pairs: list[tuple[int, int]]  # landmark ids; the source is the one observed recently
    differences: np.ndarray  # (P, d): estimate of source minus estimate of target
    covariance: np.ndarray  # (P d, P d): joint covariance of the stacked differences
    log_prior: np.ndarray  # (P,): log odds of "the same" before the geometry is seen
    loop: np.ndarray  # (P,) bool: the pair would close a loop (its target not seen lately)
    # Whether two landmarks could be one (their difference passes the gate): a pair and a rival
    # that differ only by such landmarks are both right, and merges will join all three.
    alike: Callable[[int, int], bool] = lambda a, b: False

    @property
    def dim(self) -> int:
        return self.differences.shape[1]

    def _index(self, chosen: list[int]) -> np.ndarray:
        d = self.dim
        return np.concatenate([np.arange(p * d, (p + 1) * d) for p in chosen])

    def log_likelihood(self, chosen: list[int]) -> tuple[float, float]:
        """(log N(d; 0, C), d^T C^-1 d) of the stacked differences of pairs `chosen`."""
        chosen = list(chosen)  # a tuple would index numpy arrays along several axes
        if not chosen:
            return 0.0, 0.0
        index = self._index(chosen)
        L = np.linalg.cholesky(self.covariance[np.ix_(index, index)])
        y = np.linalg.solve(L, self.differences[chosen].ravel())
        d2 = float(y @ y)
        log_det = 2.0 * float(np.sum(np.log(np.diag(L))))
        return -0.5 * (d2 + log_det + len(index) * LOG_2PI), d2

    def score(self, chosen: list[int]) -> float:
        chosen = list(chosen)
        return self.log_likelihood(chosen)[0] + float(np.sum(self.log_prior[chosen]))

    def max_gains(self) -> np.ndarray:
        """Per pair, an upper bound on what adding it to any set can add to the score: its
        difference's covariance given all the others is the smallest it can be, so its
        density is at most N(0) of that."""
        n = len(self.covariance)
        # Pairs sharing a landmark can make the covariance nearly singular: a little jitter.
        jitter = 1e-9 * max(float(np.trace(self.covariance)) / n, 1e-12)
        precision = np.linalg.inv(self.covariance + jitter * np.eye(n))
        d = self.dim
        gains = np.empty(len(self.pairs))
        for p in range(len(self.pairs)):
            block = precision[p * d : (p + 1) * d, p * d : (p + 1) * d]
            _, log_det = np.linalg.slogdet(block)
            gains[p] = 0.5 * (log_det - d * LOG_2PI) + self.log_prior[p]
        return np.maximum(gains, 0.0)


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


class _Search:
    """Branch and bound over the sources: each takes one of its pairs or none."""

    def __init__(
        self,
        pair_set: PairSet,
        confidence: float,
        max_nodes: int,
        forbidden: frozenset[int] = frozenset(),
        required: int | None = None,
    ):
        from scipy.special import chdtri

        self.pair_set = pair_set
        sources = sorted({a for a, _ in pair_set.pairs})
        options = [
            [p for p, (a, _) in enumerate(pair_set.pairs) if a == s and p not in forbidden]
            for s in sources
        ]
        if required is not None:  # the required pair first, and no other of its source
            source = pair_set.pairs[required][0]
            options = [[required]] + [
                o for s, o in zip(sources, options, strict=True) if s != source
            ]
        self.options = options
        self.required = required is not None
        gains = pair_set.max_gains()
        best = [max((gains[p] for p in o), default=0.0) for o in options]
        self.remaining = np.concatenate([np.cumsum(best[::-1])[::-1], [0.0]])
        dim = pair_set.dim
        self.gates = {
            k: float(chdtri(k * dim, 1.0 - confidence)) for k in range(1, len(options) + 1)
        }
        self.max_nodes = max_nodes
        self.nodes = 0
        self.exhausted = False
        self.best: tuple[int, ...] = ()
        self.best_score = 0.0 if required is None else -math.inf

    def run(self) -> tuple[tuple[int, ...], float]:
        self._visit(0, [], set(), 0.0)
        return self.best, self.best_score

    def _visit(self, depth: int, chosen: list[int], used: set[int], score: float) -> None:
        self.nodes += 1
        if self.nodes > self.max_nodes:
            self.exhausted = True
            return
        if score + self.remaining[depth] <= self.best_score:
            return
        if depth == len(self.options):
            self.best, self.best_score = tuple(chosen), score
            return
        for p in self.options[depth]:
            a, b = self.pair_set.pairs[p]
            if a in used or b in used:
                continue
            trial = [*chosen, p]
            log_lik, d2 = self.pair_set.log_likelihood(trial)
            if d2 > self.gates[len(trial)]:
                continue
            trial_score = log_lik + float(np.sum(self.pair_set.log_prior[trial]))
            self._visit(depth + 1, trial, used | {a, b}, trial_score)
        if not (self.required and depth == 0):
            self._visit(depth + 1, chosen, used, score)


def best_pairs(
    pair_set: PairSet,
    confidence: float,
    max_nodes: int,
    forbidden: frozenset[int] = frozenset(),
    required: int | None = None,
) -> tuple[tuple[int, ...], float, bool]:
    """The jointly compatible set of pairs with the highest score (each landmark in one pair at
    most), without the `forbidden` pairs and with the `required` one; its score; and whether
    the search finished within `max_nodes` nodes."""
    search = _Search(pair_set, confidence, max_nodes, forbidden, required)
    chosen, score = search.run()
    return chosen, score, not search.exhausted


def _same_but_alike(pair_set: PairSet, p: tuple[int, int], q: tuple[int, int]) -> bool:
    """Whether q pairs one of p's landmarks with a landmark alike to p's other one."""
    shared = set(p) & set(q)
    if len(shared) != 1:
        return False
    (s,) = shared
    x = p[0] if p[1] == s else p[1]
    y = q[0] if q[1] == s else q[1]
    return pair_set.alike(x, y)


def _pulling_their_weight(pair_set: PairSet, chosen: list[int], minimum: float) -> list[int]:
    """The pairs of `chosen` each of which adds at least `minimum` to the others' score: a pair
    that agrees with a sure set only by chance adds little, however sure the set."""
    chosen = list(chosen)
    while chosen:
        total = pair_set.score(chosen)
        adds = [total - pair_set.score([q for q in chosen if q != p]) for p in chosen]
        worst = int(np.argmin(adds))
        if adds[worst] >= minimum:
            break
        chosen.pop(worst)
    return chosen


def pairs_to_merge(
    pair_set: PairSet,
    confidence: float,
    loop_log_odds: float,
    local_log_odds: float,
    ambiguity_log_odds: float,
    max_nodes: int,
    local_rivals: bool = True,
) -> list[tuple[int, int]]:
    """The pairs of the best set that are sure enough and that no rival comes close to.

    Each pair kept must add `local_log_odds` to the score of the others. The best set's pairs
    that close no loop are kept if together they reach `local_log_odds`;
    those that close a loop only if they add `loop_log_odds` to what the others score (a
    loop closure must stand on its own evidence, not borrow a sure duplicate's). A pair is
    then dropped if a rival, the best set that pairs one of its landmarks with another
    landmark (one alike to the other of them does not count), comes within
    `ambiguity_log_odds` of the best set: in a row of parked cars, a duplicate of one car
    is often as close to its neighbour (without `local_rivals`, only loop pairs have rivals).
    An unfinished search decides nothing."""
    if not pair_set.pairs:
        return []
    best, score, finished = best_pairs(pair_set, confidence, max_nodes)
    if not finished or not best:
        return []
    best = _pulling_their_weight(pair_set, list(best), local_log_odds)
    score = pair_set.score(best)
    local = [p for p in best if not pair_set.loop[p]]
    local_score = pair_set.score(local)
    kept = local if local_score >= local_log_odds else []
    if len(local) < len(best) and score - local_score >= loop_log_odds:
        kept = list(best)
    uncontested = []
    for p in kept:
        if not local_rivals and not pair_set.loop[p]:
            uncontested.append(p)
            continue
        a, b = pair_set.pairs[p]
        rivals = [
            q
            for q, (c, e) in enumerate(pair_set.pairs)
            if q != p and ({c, e} & {a, b}) and not _same_but_alike(pair_set, (a, b), (c, e))
        ]
        contested = False
        for q in rivals:
            _, rival, rival_finished = best_pairs(
                pair_set, confidence, max_nodes, frozenset({p}), required=q
            )
            if not rival_finished or rival >= score - ambiguity_log_odds:
                contested = True
                break
        if not contested:
            uncontested.append(p)
    loops = [p for p in uncontested if pair_set.loop[p]]
    if (
        loops
        and pair_set.score(uncontested)
        - pair_set.score([p for p in uncontested if not pair_set.loop[p]])
        < loop_log_odds
    ):
        uncontested = [p for p in uncontested if not pair_set.loop[p]]
    return [pair_set.pairs[p] for p in uncontested]
