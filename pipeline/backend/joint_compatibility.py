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

A log may understate its odometry's noise, and then the drift since a loop's old landmarks
were seen is larger than C_H says: every revisit fails the test. That drift moves the recent
landmarks together, by one rigid correction (`drift_directions`: G G^T the part of C_H it
explains), so N above becomes a mixture over how far that part is understated,
sum_c w_c N(d_H; 0, C_H + (c - 1) G G^T), the weights w_c what the loops closed before said
(`noise.DriftScaleBelief`). Many pairs agreeing on one large correction then close a loop,
while a few lookalikes that only a large drift could line up pay for it.

Everything here is pure: differences and their covariance in, the pairs to merge out.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property, partial

import numpy as np

from pipeline.backend.association import LOG_2PI, chi2_gate
from pipeline.backend.budget import SearchBudget
from pipeline.geometry import skew


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
    # How far the covariance may be understated along a correction the pairs share (an
    # odometry that drifts more than its log says moves every recent landmark together): under
    # scale c the covariance is C + (c - 1) G G^T, G = `drift` (P d, r), and the likelihood is
    # a mixture over `scales` with these log prior weights (`noise.DriftScaleBelief`). By
    # default the covariance is taken as it is.
    drift: np.ndarray | None = None
    scales: np.ndarray = field(default_factory=lambda: np.ones(1))
    log_scale_weights: np.ndarray = field(default_factory=lambda: np.zeros(1))

    @property
    def dim(self) -> int:
        return self.differences.shape[1]

    def _rows(self, sets: np.ndarray) -> np.ndarray:
        """(k, m): the covariance rows of each set of pairs of `sets` (k, n), pair by pair."""
        return (sets[:, :, None] * self.dim + np.arange(self.dim)).reshape(len(sets), -1)

    def scaled_covariances(self, index: np.ndarray) -> np.ndarray:
        """(scales, m, m): the covariance of the rows `index` under each scale."""
        C = self.covariance[np.ix_(index, index)]
        if self.drift is None:
            return np.broadcast_to(C, (len(self.scales), *C.shape))
        G = self.drift[index]
        return C[None] + (self.scales - 1.0)[:, None, None] * (G @ G.T)[None]

    def scale_log_likelihoods(self, chosen: list[int]) -> tuple[np.ndarray, np.ndarray]:
        """(log N(d; 0, C_c), d^T C_c^-1 d) under each scale c of the stacked differences d
        of pairs `chosen`."""
        chosen = list(chosen)  # a tuple would index numpy arrays along several axes
        if not chosen:
            return np.zeros(len(self.scales)), np.zeros(len(self.scales))
        log_lik, d2 = self.scale_log_likelihoods_of([chosen])
        return log_lik[0], d2[0]

    def scale_log_likelihoods_of(self, sets: list[list[int]]) -> tuple[np.ndarray, np.ndarray]:
        """`scale_log_likelihoods` of several sets of pairs of one size at once, (sets, scales)
        each: numpy's linear algebra over a stack, one call for all (a search's children).

        One Cholesky factor L of C serves every scale: with y = L^-1 d and Z = L^-1 G, whose
        Z^T Z = V diag(lambda) V^T, and w = V^T Z^T y,
        d^T C_c^-1 d = |y|^2 - sum (c - 1) w^2 / (1 + (c - 1) lambda) and
        log det C_c = log det C + sum log(1 + (c - 1) lambda)."""
        chosen = np.array(sets, dtype=int).reshape(len(sets), -1)  # (k, n)
        index = self._rows(chosen)  # (k, m)
        L = np.linalg.cholesky(self.covariance[index[:, :, None], index[:, None, :]])
        d = self.differences[chosen].reshape(len(sets), -1)  # (k, m)
        log_det = 2.0 * np.sum(np.log(np.diagonal(L, axis1=1, axis2=2)), axis=1)  # (k,)
        log_det = np.repeat(log_det[:, None], len(self.scales), axis=1)  # (k, scales)
        if self.drift is None:
            y = np.linalg.solve(L, d[:, :, None])[:, :, 0]
            d2 = np.repeat(np.einsum("ki,ki->k", y, y)[:, None], len(self.scales), axis=1)
        else:
            solved = np.linalg.solve(L, np.concatenate([d[:, :, None], self.drift[index]], 2))
            y, Z = solved[:, :, 0], solved[:, :, 1:]
            lam, V = np.linalg.eigh(np.swapaxes(Z, 1, 2) @ Z)  # (k, r), (k, r, r)
            w = np.einsum("kji,kj->ki", V, np.einsum("kji,kj->ki", Z, y))  # V^T Z^T y
            c = self.scales - 1.0
            grow = c[None, :, None] * np.clip(lam, 0.0, None)[:, None, :]  # (k, scales, r)
            yy = np.einsum("ki,ki->k", y, y)
            d2 = yy[:, None] - np.sum(c[None, :, None] * w[:, None, :] ** 2 / (1.0 + grow), axis=2)
            log_det = log_det + np.sum(np.log1p(grow), axis=2)
        return -0.5 * (d2 + log_det + index.shape[1] * LOG_2PI), d2

    def log_likelihood(self, chosen: list[int]) -> tuple[float, float]:
        """(log of the mixture over `scales` of N(d; 0, C_c), the smallest d^T C_c^-1 d over
        the scales) of the stacked differences d of pairs `chosen`."""
        if not list(chosen):
            return 0.0, 0.0
        log_lik, d2 = self.log_likelihoods([list(chosen)])
        return float(log_lik[0]), float(d2[0])

    def log_likelihoods(self, sets: list[list[int]]) -> tuple[np.ndarray, np.ndarray]:
        """`log_likelihood` of several non-empty sets of pairs of one size, (sets,) each."""
        return self.mixed(*self.scale_log_likelihoods_of(sets))

    def mixed(self, log_lik: np.ndarray, d2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(the mixture over the scales, the smallest distance) of (sets, scales) each."""
        return np.logaddexp.reduce(self.log_scale_weights + log_lik, axis=1), np.min(d2, axis=1)

    @property
    def _growth(self) -> np.ndarray:
        """c - 1 of each scale the arithmetic tells apart: without a drift every scale's
        covariance is C, and one serves them all."""
        return self.scales - 1.0 if self.drift is not None else np.zeros(1)

    @cached_property
    def _scaled_blocks(self) -> np.ndarray:
        """(S, P, d, d): each pair's own block of C_c under each scale `_growth` tells apart."""
        blocks = _pair_blocks(self.covariance, np.arange(len(self.pairs)), self.dim)[None]
        if self.drift is None:
            return blocks
        G = self.drift.reshape(len(self.pairs), self.dim, -1)
        return blocks + self._growth[:, None, None, None] * (G @ np.swapaxes(G, 1, 2))[None]

    def empty_factor(self) -> SetFactor:
        """The `SetFactor` of no pairs, where a search starts."""
        S = len(self._growth)
        return SetFactor(
            np.zeros(0, dtype=int), np.zeros((S, 0, 0)), np.zeros((S, 0)), np.zeros(S),
            np.zeros(S),
        )  # fmt: skip

    def extensions(self, factor: SetFactor, new: list[int]) -> Extensions:
        """The set of `factor` extended by each pair of `new` in turn (a search's children),
        scored as `scale_log_likelihoods_of` scores them, but from the parent's factor: under
        scale c, with L the parent's factor, W = L^-1 and y = W d its whitened differences,
        a child's factor is [[L, 0], [B^T, L_n]], B = W C_c[set, new], L_n the Cholesky factor
        of C_c[new, new] - B^T B, and its new whitened rows are L_n^-1 (d_new - B^T y). So a
        child costs O(m^2 d) (m the parent's rows), not the O(m^3) of factoring its
        covariance again."""
        d, m, k = self.dim, len(factor.rows), len(new)
        new_pairs = np.asarray(new, dtype=int)
        new_rows = (new_pairs[:, None] * d + np.arange(d)).ravel()  # (k d,)
        S = len(factor.d2)
        if m:
            across = self.covariance[factor.rows][:, new_rows]  # (m, k d)
            if self.drift is not None:
                shared = self.drift[factor.rows] @ self.drift[new_rows].T
                across = across[None] + self._growth[:, None, None] * shared[None]
            B = factor.inverse @ across  # (S, m, k d)
            B = np.swapaxes(B.reshape(S, m, k, d), 1, 2)  # (S, k, m, d)
            schur = self._scaled_blocks[:, new_pairs] - np.swapaxes(B, -1, -2) @ B
            rest = self.differences[new_pairs] - np.einsum("skmi,sm->ski", B, factor.whitened)
        else:  # the first pair of a set: its own block and difference
            B = np.zeros((S, k, 0, d))
            schur = self._scaled_blocks[:, new_pairs]  # (S, k, d, d)
            rest = np.broadcast_to(self.differences[new_pairs], (S, k, d))
        L_new = np.linalg.cholesky(schur)
        y_new = np.empty((S, k, d))  # L_new^-1 rest, row by row (d is small)
        for i in range(d):
            row = rest[..., i]
            for j in range(i):
                row = row - L_new[..., i, j] * y_new[..., j]
            y_new[..., i] = row / L_new[..., i, i]
        d2 = factor.d2[:, None] + np.sum(y_new**2, axis=2)
        log_det = factor.log_det[:, None] + 2.0 * np.sum(
            np.log(np.diagonal(L_new, axis1=2, axis2=3)), axis=2
        )
        log_lik = -0.5 * (d2 + log_det + (m + d) * LOG_2PI)
        S = len(self.scales)  # one column a scale, as `scale_log_likelihoods_of` gives them
        return Extensions(
            factor, new_rows.reshape(k, d), B, L_new, y_new, d2, log_det,
            np.broadcast_to(log_lik.T, (k, S)) if len(log_lik) < S else log_lik.T,
            np.broadcast_to(d2.T, (k, S)) if len(d2) < S else d2.T,
        )  # fmt: skip

    def score(self, chosen: list[int]) -> float:
        chosen = list(chosen)
        return self.log_likelihood(chosen)[0] + float(np.sum(self.log_prior[chosen]))

    @cached_property
    def max_gains(self) -> np.ndarray:
        """Per pair, an upper bound on what adding it to any set can add to the score: its
        difference's covariance given all the others is the smallest it can be, so its
        density is at most N(0) of that."""
        n = len(self.covariance)
        # Pairs sharing a landmark can make the covariance nearly singular: a little jitter.
        jitter = 1e-9 * max(float(np.trace(self.covariance)) / n, 1e-12)
        precision = np.linalg.inv(self.covariance + jitter * np.eye(n))
        d = self.dim
        _, log_det = np.linalg.slogdet(_pair_blocks(precision, np.arange(len(self.pairs)), d))
        gains = 0.5 * (log_det - d * LOG_2PI) + self.log_prior
        return np.maximum(gains, 0.0)


@dataclass(frozen=True)
class SetFactor:
    """A set of pairs' stacked differences whitened under each scale a `PairSet` tells apart
    (S of them): what a search extends by one pair at a time (`PairSet.extensions`)."""

    rows: np.ndarray  # (m,): the set's covariance rows, pair by pair
    inverse: np.ndarray  # (S, m, m): L_c^-1, L_c the lower Cholesky factor of C_c's rows
    whitened: np.ndarray  # (S, m): L_c^-1 d
    d2: np.ndarray  # (S,): d^T C_c^-1 d
    log_det: np.ndarray  # (S,): log det C_c


@dataclass(frozen=True)
class Extensions:
    """A `SetFactor` extended by each of k pairs: their scores, and what each child's own
    factor is built from (`child`) when the search goes down to it."""

    parent: SetFactor
    new_rows: np.ndarray  # (k, d)
    B: np.ndarray  # (S, k, m, d): L_c^-1 C_c[set, new]
    L_new: np.ndarray  # (S, k, d, d): the Cholesky factor of the new rows given the set
    y_new: np.ndarray  # (S, k, d)
    d2_of: np.ndarray  # (S, k)
    log_det_of: np.ndarray  # (S, k)
    log_lik: np.ndarray  # (k, scales): as `PairSet.scale_log_likelihoods_of`
    d2: np.ndarray  # (k, scales)

    def child(self, j: int) -> SetFactor:
        """The factor of the parent's set and the j-th new pair: [[W, 0], [-L_n^-1 B^T W,
        L_n^-1]] its inverse, W the parent's."""
        parent, m = self.parent, len(self.parent.rows)
        S, d = self.L_new.shape[0], self.new_rows.shape[1]
        W, L_n_inverse = parent.inverse, np.linalg.inv(self.L_new[:, j])
        inverse = np.zeros((S, m + d, m + d))
        inverse[:, :m, :m] = W
        inverse[:, m:, :m] = -L_n_inverse @ np.swapaxes(self.B[:, j], 1, 2) @ W
        inverse[:, m:, m:] = L_n_inverse
        return SetFactor(
            np.concatenate([parent.rows, self.new_rows[j]]), inverse,
            np.concatenate([parent.whitened, self.y_new[:, j]], axis=1), self.d2_of[:, j],
            self.log_det_of[:, j],
        )  # fmt: skip


def drift_directions(
    sources: np.ndarray, loop: np.ndarray, covariance: np.ndarray
) -> np.ndarray | None:
    """G (P 3, 6) such that G G^T is the part of the differences' `covariance` (P 3, P 3) that
    one rigid correction of the recent map explains (`loop_drift_directions`, given the loop
    pairs' rows of it). None without loop pairs."""
    rows = np.repeat(np.asarray(loop, dtype=bool), 3)
    return loop_drift_directions(sources, loop, covariance[np.ix_(rows, rows)])


def loop_drift_directions(
    sources: np.ndarray, loop: np.ndarray, loop_covariance: np.ndarray
) -> np.ndarray | None:
    """`drift_directions` from the covariance of the loop pairs' differences alone (L 3, L 3),
    in their order: a check's other pairs need none of their cross terms formed.

    The odometry's drift since the old landmarks were seen moves every recent landmark (the
    `sources` (P, 3) of the loop pairs) by a small rotation about their centroid and a
    translation, which leaves a pair of two recent landmarks alike. A the correction's
    Jacobian (zero rows for pairs that close no loop), its covariance as the loop rows state it
    is A+ C A+^T, and G = A (A+ C A+^T)^1/2. None without loop pairs."""
    loop = np.asarray(loop, dtype=bool)
    if not loop.any():
        return None
    centre = sources[loop].mean(axis=0)
    A = np.zeros((len(sources), 3, 6))
    A[loop, :, :3] = -skew(sources[loop] - centre)
    A[loop, :, 3:] = np.eye(3)
    A = A.reshape(-1, 6)
    rows = np.repeat(loop, 3)
    pinv = np.linalg.pinv(A[rows])
    correction = pinv @ loop_covariance @ pinv.T
    values, vectors = np.linalg.eigh(0.5 * (correction + correction.T))
    return A @ (vectors * np.sqrt(np.clip(values, 0.0, None)))


def difference_covariance(
    landmark_covariance: np.ndarray, pairs: list[tuple[int, int]], slots: dict[int, int], dim: int
) -> np.ndarray:
    """Joint covariance of the differences l_a - l_b of `pairs`, from the joint covariance of
    the landmarks (`slots[j]` = landmark j's block index in it)."""
    offsets = np.arange(dim)
    a = (np.array([slots[x] for x, _ in pairs], dtype=int)[:, None] * dim + offsets).ravel()
    b = (np.array([slots[y] for _, y in pairs], dtype=int)[:, None] * dim + offsets).ravel()
    # the four blocks gathered (P dim, P dim) each, not the whole (n, n, dim, dim) rearranged
    cov = landmark_covariance
    C = cov[np.ix_(a, a)] - cov[np.ix_(a, b)] - cov[np.ix_(b, a)] + cov[np.ix_(b, b)]
    return 0.5 * (C + C.T)


def difference_blocks(
    landmark_covariance: np.ndarray, pairs: list[tuple[int, int]], slots: dict[int, int], dim: int
) -> np.ndarray:
    """(P, dim, dim): the diagonal blocks of `difference_covariance`, the same numbers, without
    the (P dim, P dim) matrix: a check gates each pair on its own block first."""
    offsets = np.arange(dim)
    a = np.array([slots[x] for x, _ in pairs], dtype=int)[:, None] * dim + offsets  # (P, dim)
    b = np.array([slots[y] for _, y in pairs], dtype=int)[:, None] * dim + offsets
    cov = landmark_covariance

    def block(rows: np.ndarray, columns: np.ndarray) -> np.ndarray:
        return cov[rows[:, :, None], columns[:, None, :]]

    C = block(a, a) - block(a, b) - block(b, a) + block(b, b)
    return 0.5 * (C + np.swapaxes(C, 1, 2))


class _Search:
    """Branch and bound over the sources: each takes one of its pairs or none."""

    def __init__(
        self,
        pair_set: PairSet,
        confidence: float,
        max_nodes: int,
        forbidden: frozenset[int] = frozenset(),
        required: int | None = None,
        budget: SearchBudget | None = None,
    ):
        self.pair_set = pair_set
        self.budget = budget
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
        gains = pair_set.max_gains
        best = [max((gains[p] for p in o), default=0.0) for o in options]
        self.remaining = np.concatenate([np.cumsum(best[::-1])[::-1], [0.0]])
        dim = pair_set.dim
        self.gates = {k: chi2_gate(k * dim, confidence) for k in range(1, len(options) + 1)}
        self.max_nodes = max_nodes
        self.nodes = 0
        self.exhausted = False
        self.best: tuple[int, ...] = ()
        self.best_score = 0.0 if required is None else -math.inf

    def run(self) -> tuple[tuple[int, ...], float]:
        self._visit(0, [], set(), 0.0, self.pair_set.empty_factor())
        return self.best, self.best_score

    def _visit(
        self, depth: int, chosen: list[int], used: set[int], score: float, factor: SetFactor
    ) -> None:
        self.nodes += 1
        if self.nodes > self.max_nodes or (self.budget is not None and not self.budget.spend()):
            self.exhausted = True
            return
        if score + self.remaining[depth] <= self.best_score:
            return
        if depth == len(self.options):
            self.best, self.best_score = tuple(chosen), score
            return
        # This source's pairs scored together, each from the factor of the set so far.
        new = [p for p in self.options[depth] if not {*self.pair_set.pairs[p]} & used]
        if new:
            children = self.pair_set.extensions(factor, new)
            log_liks, d2s = self.pair_set.mixed(children.log_lik, children.d2)
        for k, p in enumerate(new):
            trial = [*chosen, p]
            if d2s[k] > self.gates[len(trial)]:
                continue
            trial_score = float(log_liks[k]) + float(np.sum(self.pair_set.log_prior[trial]))
            self._visit(
                depth + 1, trial, used | {*self.pair_set.pairs[p]}, trial_score, children.child(k)
            )
        if not (self.required and depth == 0):
            self._visit(depth + 1, chosen, used, score, factor)


def best_pairs(
    pair_set: PairSet,
    confidence: float,
    max_nodes: int,
    forbidden: frozenset[int] = frozenset(),
    required: int | None = None,
    budget: SearchBudget | None = None,
) -> tuple[tuple[int, ...], float, bool]:
    """The jointly compatible set of pairs with the highest score (each landmark in one pair at
    most), without the `forbidden` pairs and with the `required` one; its score; and whether
    the search finished within `max_nodes` nodes (and the shared `budget`'s)."""
    search = _Search(pair_set, confidence, max_nodes, forbidden, required, budget)
    chosen, score = search.run()
    return chosen, score, not search.exhausted


def _block_terms(mean: np.ndarray, blocks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(log N(mean; 0, block), mean^T block^-1 mean) of each mean (..., d) and block
    (..., d, d); -inf and inf where a block's determinant is not positive. 3 x 3 blocks by
    their cofactors (`_block_terms_3`): a search's stacks hold thousands, and LAPACK's
    call a block costs ten times the arithmetic."""
    blocks = 0.5 * (blocks + np.swapaxes(blocks, -1, -2))
    if mean.shape[-1] != 3:
        return _block_terms_lapack(mean, blocks)
    return _block_terms_3(mean, blocks)


# A 3 x 3 block whose determinant is below this fraction of its diagonal's product (the
# determinant of its correlations) is nearly singular: its cofactors lose digits that LU keeps.
NEARLY_SINGULAR = 1e-6


def _block_terms_3(mean: np.ndarray, blocks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`_block_terms` of symmetric 3 x 3 blocks: block^-1 = adj(block) / det(block), the
    adjugate's entries the cofactors; nearly singular blocks (`NEARLY_SINGULAR`) by LAPACK."""
    a00, a01, a02 = blocks[..., 0, 0], blocks[..., 0, 1], blocks[..., 0, 2]
    a11, a12, a22 = blocks[..., 1, 1], blocks[..., 1, 2], blocks[..., 2, 2]
    c00 = a11 * a22 - a12 * a12
    c01 = a02 * a12 - a01 * a22
    c02 = a01 * a12 - a02 * a11
    det = a00 * c00 + a01 * c01 + a02 * c02
    x0, x1, x2 = mean[..., 0], mean[..., 1], mean[..., 2]
    quadratic = (
        c00 * x0 * x0
        + (a00 * a22 - a02 * a02) * x1 * x1
        + (a00 * a11 - a01 * a01) * x2 * x2
        + 2.0 * (c01 * x0 * x1 + c02 * x0 * x2 + (a01 * a02 - a00 * a12) * x1 * x2)
    )
    easy = det > NEARLY_SINGULAR * np.abs(a00 * a11 * a22)
    with np.errstate(divide="ignore", invalid="ignore"):
        d2 = np.where(easy, quadratic / det, np.inf)
        log_lik = np.where(easy, -0.5 * (d2 + np.log(det) + 3 * LOG_2PI), -np.inf)
    hard = ~easy
    if np.any(hard):
        log_lik[hard], d2[hard] = _block_terms_lapack(mean[hard], blocks[hard])
    return log_lik, d2


def _block_terms_lapack(mean: np.ndarray, blocks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`_block_terms` of symmetric blocks of any size, by LAPACK."""
    d = mean.shape[-1]
    sign, log_det = np.linalg.slogdet(blocks)
    safe = np.where(sign[..., None, None] > 0, blocks, np.eye(d))
    d2 = np.einsum("...i,...ij,...j->...", mean, np.linalg.inv(safe), mean)
    log_lik = -0.5 * (d2 + log_det + d * LOG_2PI)
    return np.where(sign > 0, log_lik, -np.inf), np.where(sign > 0, d2, np.inf)


def _pair_blocks(covariance: np.ndarray, pairs: np.ndarray, d: int) -> np.ndarray:
    """(k, d, d): the diagonal blocks of `covariance` (P d, P d) of the pairs `pairs` (k,)."""
    rows = pairs[:, None] * d + np.arange(d)
    return covariance[rows[:, :, None], rows[:, None, :]]


def _cholesky(blocks: np.ndarray) -> np.ndarray:
    """Lower Cholesky factors of symmetric blocks (..., d, d); a block that is not positive
    definite (the last pair of a set may leave its difference nearly determined) has its
    eigenvalues raised to a tiny fraction of its largest first."""
    blocks = 0.5 * (blocks + np.swapaxes(blocks, -1, -2))
    try:
        return np.linalg.cholesky(blocks)
    except np.linalg.LinAlgError:
        values, vectors = np.linalg.eigh(blocks)
        floor = 1e-12 * np.maximum(np.max(np.abs(values), axis=-1, keepdims=True), 1e-300)
        values = np.maximum(values, floor)
        return np.linalg.cholesky((vectors * values[..., None, :]) @ np.swapaxes(vectors, -1, -2))


class _Conditioned:
    """The open pairs' differences under each drift scale given the pairs chosen so far: each
    one's conditional mean (S, n, d) and covariance block (S, n, d, d). The chosen pairs' part
    of the covariance is kept as a factor W (S, n d, d k), C_c given them = C_c - W W^T, so that
    choosing a pair costs O(S n d^2 k) for k chosen, where conditioning the whole covariance
    cost O(S (n d)^2 d) and its memory O(S (n d)^2). The scaled covariances
    C_c = C + (c - 1) G G^T are never formed: only the columns of the pair chosen."""

    def __init__(self, pair_set: PairSet, alive: np.ndarray):
        d = pair_set.dim
        self.pair_set = pair_set
        self.alive = alive  # pair indices of the open pairs, in the order of the arrays
        self.rows = (alive[:, None] * d + np.arange(d)).ravel()  # their rows in the covariance
        self.growth = pair_set.scales - 1.0
        S, n = len(self.growth), len(alive)
        blocks = _pair_blocks(pair_set.covariance, alive, d)
        self.blocks = np.repeat(blocks[None], S, axis=0)
        if pair_set.drift is not None:
            G = pair_set.drift[self.rows].reshape(n, d, -1)
            self.blocks += self.growth[:, None, None, None] * (G @ np.swapaxes(G, 1, 2))[None]
        differences = pair_set.differences.astype(float)[alive]
        self.mean = np.repeat(differences[None], S, axis=0)
        self.W = np.zeros((S, n * d, 0))

    def terms(self) -> tuple[np.ndarray, np.ndarray]:
        """(log N(mean; 0, block), its squared distance) of each open pair, (S, n) each."""
        return _block_terms(self.mean, self.blocks)

    def choose(self, slot: int, dropped: np.ndarray) -> None:
        """Condition on the open pair at `slot`, then close the pairs `dropped` (a mask over
        the open pairs: those sharing a landmark with it, itself included)."""
        d, S, n = self.pair_set.dim, len(self.growth), len(self.alive)
        own = np.arange(slot * d, (slot + 1) * d)
        L = _cholesky(self.blocks[:, slot])  # (S, d, d)
        column = self.pair_set.covariance[np.ix_(self.rows, self.rows[own])]  # (n d, d)
        column = np.repeat(column[None], S, axis=0)
        if self.pair_set.drift is not None:
            G = self.pair_set.drift[self.rows]
            column += self.growth[:, None, None] * (G @ G[own].T)[None]
        column -= self.W @ np.swapaxes(self.W[:, own], 1, 2)
        new = np.swapaxes(np.linalg.solve(L, np.swapaxes(column, 1, 2)), 1, 2)  # C L^-T
        z = np.linalg.solve(L, self.mean[:, slot][..., None])[..., 0]  # (S, d)
        blocks = new.reshape(S, n, d, d)
        self.mean = self.mean - np.einsum("snij,sj->sni", blocks, z)
        self.blocks = self.blocks - blocks @ np.swapaxes(blocks, -1, -2)
        kept = ~dropped
        kept_rows = np.repeat(kept, d)
        self.W = np.concatenate([self.W, new], axis=2)[:, kept_rows]
        self.mean, self.blocks = self.mean[:, kept], self.blocks[:, kept]
        self.alive, self.rows = self.alive[kept], self.rows[kept_rows]


def grown_pairs(
    pair_set: PairSet,
    confidence: float,
    start: tuple[int, ...] = (),
    forbidden: frozenset[int] = frozenset(),
    budget: SearchBudget | None = None,
) -> tuple[tuple[int, ...], float, bool]:
    """A jointly compatible set grown greedily from the pairs `start`: each step adds the pair
    that raises the score most, while one does and the set passes the joint gate; with its
    score (`PairSet.score`'s), and whether it finished within the `budget` (a step looks at
    every open pair: it spends a node for each). Under each scale, each pair added conditions the
    differences still open (`_Conditioned`; their scores add up along the way), and those
    sharing a landmark with it drop out."""
    d = pair_set.dim
    alive = np.array(
        [p for p in range(len(pair_set.pairs)) if p not in forbidden or p in start], dtype=int
    )
    open_pairs = _Conditioned(pair_set, alive)
    landmarks = np.array(pair_set.pairs, dtype=np.int64).reshape(-1, 2)
    weights = pair_set.log_scale_weights
    log_lik = np.zeros(len(weights))  # the chosen set's, per scale
    d2_total = np.zeros(len(weights))
    chosen: list[int] = []
    prior = 0.0

    def add(slot: int, slot_log_lik: np.ndarray, slot_d2: np.ndarray) -> None:
        nonlocal log_lik, d2_total, prior
        p = int(open_pairs.alive[slot])
        chosen.append(p)
        log_lik = log_lik + slot_log_lik
        d2_total = d2_total + slot_d2
        prior += float(pair_set.log_prior[p])
        sharing = np.isin(landmarks[open_pairs.alive], landmarks[p]).any(axis=1)
        open_pairs.choose(slot, sharing)

    for p in start:
        if budget is not None and not budget.spend(len(open_pairs.alive)):
            return tuple(chosen), -math.inf, False
        ll, d2 = open_pairs.terms()
        slot = int(np.flatnonzero(open_pairs.alive == p)[0])
        add(slot, ll[:, slot], d2[:, slot])
    score = float(np.logaddexp.reduce(weights + log_lik)) + prior if chosen else 0.0
    while len(open_pairs.alive):
        if budget is not None and not budget.spend(len(open_pairs.alive)):
            return tuple(chosen), score, False
        ll, d2 = open_pairs.terms()
        trial = np.logaddexp.reduce((weights + log_lik)[:, None] + ll, axis=0)
        trial = trial + prior + pair_set.log_prior[open_pairs.alive]
        gate = chi2_gate((len(chosen) + 1) * d, confidence)
        trial = np.where(np.min(d2_total[:, None] + d2, axis=0) <= gate, trial, -np.inf)
        slot = int(np.argmax(trial))
        if not trial[slot] > score:
            break
        add(slot, ll[:, slot], d2[:, slot])
        score = float(trial[slot])
    return tuple(chosen), score, True


# Pairs whose conditioning on one another `seed_estimates` computes in one stack.
SEED_CHUNK = 32


def seed_estimates(pair_set: PairSet, confidence: float) -> np.ndarray:
    """Per pair, a quick estimate of the best score of a set grown from it: under each scale,
    its own gain plus, for every other source, the most one of its pairs adds given this pair
    alone. A loop pair fixes the correction of the map that the rest of its set must share, so
    given it the others' differences are nearly independent. Pairs outside the gate alone
    under every scale estimate -inf. Computed for `SEED_CHUNK` pairs at a time."""
    n, d = len(pair_set.pairs), pair_set.dim
    everyone = np.arange(n)
    scales = _Conditioned(pair_set, everyone)
    S = len(scales.growth)
    own_blocks = scales.blocks  # (S, n, d, d)
    D = pair_set.differences.astype(float)
    sources = np.array([a for a, _ in pair_set.pairs])
    groups = [sources == s for s in np.unique(sources)]
    gate = chi2_gate(d, confidence)
    weights = pair_set.log_scale_weights
    own, own_d2 = _block_terms(np.broadcast_to(D, (S, n, d)), own_blocks)  # (S, n)
    out = np.full(n, -np.inf)
    candidates = np.flatnonzero(np.min(own_d2, axis=0) <= gate)
    for chunk in np.array_split(candidates, max(1, -(-len(candidates) // SEED_CHUNK))):
        if not len(chunk):
            continue
        Q = len(chunk)
        # C_c[r, q] for every pair r and seed q of the chunk: (S, Q, n, d, d)
        rows = (chunk[:, None] * d + np.arange(d)).ravel()
        cross = pair_set.covariance[:, rows].reshape(n, d, Q, d).transpose(2, 0, 1, 3)
        cross = np.repeat(cross[None], S, axis=0)
        if pair_set.drift is not None:
            G = pair_set.drift.reshape(n, d, -1)
            cross = (
                cross
                + scales.growth[:, None, None, None, None]
                * np.einsum("nir,qjr->qnij", G, G[chunk])[None]
            )
        K = cross @ np.linalg.inv(own_blocks[:, chunk])[:, :, None]  # (S, Q, n, d, d)
        # pair r given q: D_r - K_r D_q, C_rr - K_r C_qr
        mean = D[None, None] - np.einsum("sqnij,qj->sqni", K, D[chunk])
        cov = own_blocks[:, None] - K @ np.swapaxes(cross, -1, -2)
        gains, d2 = _block_terms(mean, cov)  # (S, Q, n)
        gains = np.where(d2 <= gate, gains + pair_set.log_prior, -np.inf)
        gains[:, sources[chunk][:, None] == sources[None, :]] = -np.inf
        total = own[:, chunk] + pair_set.log_prior[chunk]  # (S, Q)
        for members in groups:
            total = total + np.maximum(np.max(gains[:, :, members], axis=2), 0.0)
        out[chunk] = np.logaddexp.reduce(weights[:, None] + total, axis=0)
    return out


class SeededSearch:
    """`best_pairs` for a set of pairs too large to search whole, with its signature: sets
    grown (`grown_pairs`) from nothing and from each of the `seeds` loop pairs of highest
    `seed_estimates`, each of which fixes a correction of the map that the pairs grown on it
    must share; finished unless the `budget` runs out.

    A rival (a set grown from a required pair) scores at least its pair's estimate: growth can
    miss a rival's best set, and an underrated rival leaves a pairing uncontested, so the
    estimate errs on the side of no merge."""

    def __init__(
        self, pair_set: PairSet, confidence: float, seeds: int, budget: SearchBudget | None = None
    ):
        self.seeds = seeds
        self.budget = budget
        self.estimates = seed_estimates(pair_set, confidence)

    def __call__(
        self,
        pair_set: PairSet,
        confidence: float,
        _max_nodes: int,
        forbidden: frozenset[int] = frozenset(),
        required: int | None = None,
    ) -> tuple[tuple[int, ...], float, bool]:
        if required is not None:
            chosen, score, finished = grown_pairs(
                pair_set, confidence, (required,), forbidden, self.budget
            )
            return chosen, max(score, float(self.estimates[required])), finished
        best, best_score, finished = grown_pairs(pair_set, confidence, (), forbidden, self.budget)
        loops = [p for p in range(len(pair_set.pairs)) if pair_set.loop[p] and p not in forbidden]
        for p in sorted(loops, key=lambda p: -self.estimates[p])[: self.seeds]:
            if not finished or not np.isfinite(self.estimates[p]):
                break
            chosen, score, finished = grown_pairs(
                pair_set, confidence, (p,), forbidden, self.budget
            )
            # The same set grown from another seed scores the same but for rounding (the order
            # of its pairs differs): the first stays, and with it the order its merges take.
            if score > best_score and set(chosen) != set(best):
                best, best_score = chosen, score
        return best, best_score, finished


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
    seeds: int = 0,
    budget: SearchBudget | None = None,
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
    A search too large to finish within `max_nodes` is made again, rivals' too, by growing
    sets from `seeds` loop pairs (`SeededSearch`); an unfinished search decides nothing. Every
    search spends the nodes it visits from `budget` (none: no bound beyond `max_nodes` a
    search): once it is spent, what is left undecided stays apart (the best set unfinished:
    no merge; a rival unfinished: its pair contested)."""
    if not pair_set.pairs:
        return []
    search = partial(best_pairs, budget=budget)
    best, score, finished = search(pair_set, confidence, max_nodes)
    if not finished and seeds > 0 and not (budget is not None and budget.exhausted):
        search = SeededSearch(pair_set, confidence, seeds, budget)
        best, score, finished = search(pair_set, confidence, max_nodes)
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
            _, rival, rival_finished = search(
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
