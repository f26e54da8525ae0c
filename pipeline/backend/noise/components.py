"""A robust likelihood of variance scales per direction, its fit and the evidence for a move.

Each observation is a vector y modelled as y ~ N(0, V(s)), with

    V(s) = R + sum_p c_p(s) B_p,    c_p(s) = sqrt(s_i s_j) for the pair of directions p = (i, j):

a covariance D S D (D = diag(sqrt(s)), each direction's variance times its scale, the
correlations kept) is linear in these coefficients, so that R (what does not depend on the
scales) and the B_p are computed once, when the observation is made. With probability
OUTLIER_SHARE an observation is not the model's (a window bent by a wrong association, a
wrong pairing): its density is then N(0, V_out), V_out the model's with every scale
OUTLIER_SCALE times the one in use when it was made. The scales' log prior is Gaussian in
log s, centred on the log's statement (s = 1) with PRIOR_LOG_SIGMA: a direction no observation
tells stays where the log put it.

The fit maximises the log posterior over log s within bounds by coordinate scans over a log
grid, then finer around the best point: the outlier component makes the likelihood multimodal
(a scale far above the current one can explain observations the model at the current one leaves
to the outliers, with nothing between the two to climb), which a local search would miss.

The evidence that direction i is not at its current scale is a profile likelihood ratio: the
log posterior at the fit against its maximum with s_i held at the current value (the other
directions free, so that what one of them explains as well is no evidence for i), less the
gains of the `drop` observations that gain most: no one or two observations alone move a scale.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

LOG_2PI = float(np.log(2.0 * np.pi))
OUTLIER_SHARE = 0.05
OUTLIER_SCALE = 1e4
PRIOR_LOG_SIGMA = 3.0
DOWN_EVIDENCE = 2.0
# Coordinate scans step the log scale by this factor.
SCAN_STEP = 2.0


def pair_coefficients(scales: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """c_p = sqrt(s_i s_j) for each pair (i, j) of `pairs` (P, 2), of scales (n,) or of each
    row of scales (k, n)."""
    return np.sqrt(scales[..., pairs[:, 0]] * scales[..., pairs[:, 1]])


def nonzero_pairs(covariances: np.ndarray) -> np.ndarray:
    """(P, 2) pairs i <= j of directions where any of the (n, d, d) covariances is nonzero."""
    nonzero = np.any(np.asarray(covariances) != 0.0, axis=0)
    i, j = np.nonzero(np.triu(nonzero | nonzero.T))
    return np.stack([i, j], axis=1)


def pair_basis(covariances: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """(P, d, d): covariance entries of pair p = (i, j), both (i, j) and (j, i), so that
    D S D = sum_p c_p(s) basis[p] for each of the (d, d) `covariances` summed."""
    S = np.sum(np.reshape(covariances, (-1, *np.shape(covariances)[-2:])), axis=0)
    out = np.zeros((len(pairs), *S.shape))
    for p, (i, j) in enumerate(pairs):
        out[p, i, j] = S[i, j]
        out[p, j, i] = S[j, i]
    return out


def gaussian_log_densities(y: np.ndarray, V: np.ndarray) -> np.ndarray:
    """log N(y; 0, V) of (..., d) vectors under (..., d, d) covariances."""
    L = np.linalg.cholesky(V)
    z = np.linalg.solve(L, y[..., None])[..., 0]
    log_det = 2.0 * np.sum(np.log(np.diagonal(L, axis1=-2, axis2=-1)), axis=-1)
    return -0.5 * (np.sum(z * z, axis=-1) + log_det + y.shape[-1] * LOG_2PI)


@dataclass(frozen=True)
class ScaleObservation:
    """One observation: y ~ N(0, rest + sum_p c_p(s) basis[p]), pairs into the estimator's
    directions; `outlier` its log density under the outlier model."""

    y: np.ndarray  # (d,)
    rest: np.ndarray  # (d, d)
    basis: np.ndarray  # (P, d, d)
    pairs: np.ndarray  # (P, 2)
    outlier: float

    @staticmethod
    def made(
        y: np.ndarray, rest: np.ndarray, basis: np.ndarray, pairs: np.ndarray, used: np.ndarray
    ) -> ScaleObservation:
        """The observation, its outlier density taken at OUTLIER_SCALE times `used`."""
        V = rest + np.einsum("p,pab->ab", pair_coefficients(OUTLIER_SCALE * used, pairs), basis)
        outlier = float(gaussian_log_densities(y[None], V[None])[0])
        return ScaleObservation(y, rest, basis, pairs, outlier)


@dataclass(frozen=True)
class Reading:
    """What the observations say: the scales to move to (None: stay where they are), the fit,
    and each direction's evidence (nats) for leaving its current scale."""

    scales: np.ndarray | None
    fit: np.ndarray
    evidence: np.ndarray


class _Group:
    """The observations of one dimension, stacked, over the estimator's pair list."""

    def __init__(self) -> None:
        self.y: list[np.ndarray] = []
        self.rest: list[np.ndarray] = []
        self.basis: list[np.ndarray] = []
        self.outlier: list[float] = []
        self._stacked: tuple[np.ndarray, ...] | None = None

    def stacked(self) -> tuple[np.ndarray, ...]:
        if self._stacked is None:
            self._stacked = (
                np.stack(self.y),
                np.stack(self.rest),
                np.stack(self.basis),
                np.array(self.outlier),
            )
        return self._stacked


class ScaleLikelihood:
    """The latest `kept` observations over directions `names`, and what they say."""

    def __init__(self, names: tuple[str, ...], kept: int):
        self.names = names
        self._observations: deque[ScaleObservation] = deque(maxlen=kept)
        self._pairs = np.zeros((0, 2), dtype=int)  # union of the observations' pairs
        self._groups: dict[int, _Group] | None = None
        self._last_fit: np.ndarray | None = None  # log scales, the last `reading`'s fit

    def __len__(self) -> int:
        return len(self._observations)

    def add(self, observation: ScaleObservation) -> None:
        self._observations.append(observation)
        new = {tuple(p) for p in observation.pairs} - {tuple(p) for p in self._pairs}
        if new:
            self._pairs = np.array(sorted({tuple(p) for p in self._pairs} | new), dtype=int)
        self._groups = None

    @property
    def observations(self) -> tuple[ScaleObservation, ...]:
        return tuple(self._observations)

    def replace(self, observations: list[ScaleObservation]) -> None:
        """The observations read anew: these, the latest `kept` of them, in place of all."""
        self._observations.clear()
        self._pairs = np.zeros((0, 2), dtype=int)
        for observation in observations:
            self.add(observation)

    def _grouped(self) -> dict[int, _Group]:
        if self._groups is None:
            index = {tuple(p): k for k, p in enumerate(self._pairs)}
            groups: dict[int, _Group] = {}
            for o in self._observations:
                g = groups.setdefault(len(o.y), _Group())
                basis = np.zeros((len(self._pairs), len(o.y), len(o.y)))
                for p, b in zip(o.pairs, o.basis, strict=True):
                    basis[index[tuple(p)]] += b
                g.y.append(o.y)
                g.rest.append(o.rest)
                g.basis.append(basis)
                g.outlier.append(o.outlier)
            self._groups = groups
        return self._groups

    def per_observation(self, thetas: np.ndarray) -> np.ndarray:
        """Each observation's log density (mixture) at each row of log scales `thetas`
        (k, n): (k, observations); a single row (n,) gives (observations,)."""
        thetas = np.asarray(thetas, dtype=float)
        c = pair_coefficients(np.exp(np.atleast_2d(thetas)), self._pairs)
        out = np.concatenate([_log_densities(g.stacked(), c) for g in self._grouped().values()], 1)
        return out[0] if thetas.ndim == 1 else out

    def log_posterior(self, thetas: np.ndarray) -> np.ndarray:
        """The log posterior (up to a constant) at each row of log scales `thetas` (k, n)."""
        prior = -0.5 * np.sum((thetas / PRIOR_LOG_SIGMA) ** 2, axis=1)
        return prior + np.sum(self.per_observation(thetas), axis=1)

    def fit(self, start: np.ndarray, free: np.ndarray, bounds: tuple[float, float]) -> np.ndarray:
        """The log scales maximising the posterior over the directions `free` (the others held
        at `start`), within `bounds` (scales): coordinate scans over a log grid of SCAN_STEP,
        each direction's in one batch, then around the best point at finer steps (to 1/8 of
        the grid's; plenty beside a deadband of 1.5 or more)."""
        low, high = np.log(bounds[0]), np.log(bounds[1])
        theta = np.clip(np.array(start, dtype=float), low, high)
        best = float(self.log_posterior(theta[None])[0])
        step = np.log(SCAN_STEP)
        grid = np.linspace(low, high, int(np.ceil((high - low) / step)) + 1)
        for offsets in (None, *(step * f * np.arange(-3, 4) for f in (1 / 2, 1 / 8))):
            for i in np.flatnonzero(free):
                values = grid if offsets is None else np.clip(theta[i] + offsets, low, high)
                trials = np.repeat(theta[None], len(values), axis=0)
                trials[:, i] = values
                scores = self.log_posterior(trials)
                k = int(np.argmax(scores))
                if scores[k] > best:
                    best, theta = float(scores[k]), trials[k]
        return theta

    def reading(
        self,
        current: np.ndarray,
        bounds: tuple[float, float],
        min_evidence: float,
        deadband: float,
        drop: int,
        tested: np.ndarray | None = None,
    ) -> Reading:
        """Where the observations put the scales, and which of the `tested` directions
        (default: all; the others are nuisances, always fitted) moves from `current`: of those
        whose fit lies `deadband` times away or more with at least `min_evidence` nats up, or
        DOWN_EVIDENCE times that down (profile likelihood ratio, less the `drop` observations
        that gain most), the one with the most evidence beyond what it needs. The scales are then
        fitted again with the other tested directions held."""
        n = len(self.names)
        tested = np.ones(n, bool) if tested is None else np.asarray(tested, bool)
        now = np.log(np.asarray(current, dtype=float))
        if not self._worth_fitting(now, bounds, min_evidence, deadband):
            return Reading(None, np.exp(now), np.zeros(n))
        everything = np.ones(n, bool)
        best = self._last_fit = self.fit(now, everything, bounds)
        evidence = np.zeros(n)
        top = self.per_observation(best)
        for i in np.flatnonzero(tested & (np.abs(best - now) >= np.log(deadband))):
            free = everything.copy()
            free[i] = False
            start = best.copy()
            start[i] = now[i]
            held = self.fit(start, free, bounds)
            gains = np.sort(top - self.per_observation(held))[::-1]
            prior = 0.5 * (best[i] ** 2 - now[i] ** 2) / PRIOR_LOG_SIGMA**2
            evidence[i] = float(np.sum(gains[drop:]) - prior)
        # Down takes DOWN_EVIDENCE times the evidence: a noise learnt too small turns true
        # revisits away (and the outlier component, taking the tails of a heavier-tailed
        # truth, leans the fit down), while one learnt too large only widens the gates.
        needed = np.where(best < now, DOWN_EVIDENCE * min_evidence, min_evidence)
        if not (evidence >= needed).any():
            return Reading(None, np.exp(best), evidence)
        # One direction a reading, the clearest: moved together, one direction's large move
        # made room for another's false one (indoor tags noise 8 seed 1: the yaw 1373 -> 343
        # and the forward 1 -> 1259, truth 3.9, on 3.4 nats); the next reading asks again.
        moving = np.arange(n) == np.argmax(evidence - needed)
        after = self.fit(now, moving | ~tested, bounds)
        if np.all(np.abs(after - now)[moving] < np.log(deadband)):
            # alone, the direction stays near its scale (the joint fit's move was the others')
            return Reading(None, np.exp(best), evidence)
        return Reading(np.exp(after), np.exp(best), evidence)

    def _worth_fitting(
        self, now: np.ndarray, bounds: tuple[float, float], min_evidence: float, deadband: float
    ) -> bool:
        """Whether any direction alone, the others where they are, or the last fit, is
        `min_evidence` more probable than `now`, `deadband` times or more away on the scan's
        grid: if none is, the fit is skipped (a cheap test: where the observations say what
        they said, nothing is fitted)."""
        low, high = np.log(bounds[0]), np.log(bounds[1])
        grid = np.linspace(low, high, int(np.ceil((high - low) / np.log(SCAN_STEP))) + 1)
        trials = []
        for i in range(len(now)):
            far = grid[np.abs(grid - now[i]) >= np.log(deadband)]
            rows = np.repeat(now[None], len(far), axis=0)
            rows[:, i] = far
            trials.append(rows)
        if self._last_fit is not None and len(self._last_fit) == len(now):
            trials.append(self._last_fit[None])
        scores = self.log_posterior(np.concatenate([now[None], *trials]))
        return bool(np.max(scores[1:]) - scores[0] >= min_evidence)


def _log_densities(stacked: tuple[np.ndarray, ...], c: np.ndarray) -> np.ndarray:
    """Each observation's mixture log density under each row of pair coefficients c (k, P):
    (k, observations)."""
    y, rest, basis, outlier = stacked
    V = rest[None] + np.einsum("kp,npab->knab", c, basis)
    model = gaussian_log_densities(np.broadcast_to(y, (*V.shape[:2], y.shape[1])), V)
    return np.logaddexp(np.log1p(-OUTLIER_SHARE) + model, np.log(OUTLIER_SHARE) + outlier[None])
