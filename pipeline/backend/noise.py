"""How far a log's stated noise is from the truth: covariance scales estimated online.

Measurement components from the innovations of sure associations. A detection paired with a
landmark has innovation nu = h(x, l) - z with covariance S = P + Gamma: P the pose's and the
landmark's uncertainty seen through the measurement, Gamma the detection's own. A landmark seen
again from a pose known about as well as it (tracking: P_kk small beside Gamma_kk) tells
component k's factor b_k = (sum nu_k^2 - sum P_kk) / sum Gamma_kk.

The odometry's from the estimate itself, not from associations: the innovations that would
tell an understated odometry are those of loop closures, which the gates built on that
odometry refuse, so every pairing the back-end accepts says the odometry is fine. Over a window
of W keyframes, the odometry's composed step U (covariance Q, carried through the steps to
first order) and the estimate's relative pose T between the window's ends (covariance C from
iSAM2) differ by delta = Log(U^-1 T). Taking the window's odometry and the rest of the graph
as two measurements of T, delta = G (z_odometry - z_rest) with G = C R^-1 (R the rest's
covariance, C^-1 = Q^-1 + R^-1). In the frame that whitens Q, E = I - C is the share of each
direction the rest decides, and if the odometry's true covariance is c Q, delta's covariance
is E (I - E) + c E^2: along each eigenvector of E (share e), delta's component has variance
e (1 - e) + c e^2. The windows' likelihood over c is then exact under the model, each window
also allowed to be an outlier (bent by a wrong association); its maximum is the scale they
say, and its ratio against the current scale how sure they are (`drift_scale`). A window the
landmarks do not pin (e near 0) says nothing, and says it quietly; a window across a loop
closure (e near 1 along the loop's directions) says much.
A slow odometry bias drifts more over a long window than white noise of the same step sigma:
the scale found is the one at the window's length. Such a bias can also hide from every window
before a loop closes (the landmarks decide little of the heading: Victoria Park's yaw, 2-8 %),
and a lone window across the first loop is read as an outlier; the loops the merges close say
it directly (`DriftScaleBelief.reading`), and may raise the scale too.

Pure functions and small accumulators; the pairings come from `methods/maxmixture.py`, the
windows from `slam.py`, which applies the scales.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal, Protocol

import gtsam
import numpy as np
from gtsam.symbol_shorthand import X

from pipeline.config import NoiseConfig

logger = logging.getLogger(__name__)

# A pairing tells b_k when P_kk is at most this share of Gamma_kk.
TRACKING_SHARE = 0.25
# The estimate is iSAM2's, relinearised only where it moved: along directions the landmarks
# leave to the odometry, a window's discrepancy is not exactly zero but about this variance
# (in the window's odometry covariance, whitened; seen on city-grid windows).
SETTLING_VARIANCE = 1e-3
# Directions the landmarks decide less than this share of are the odometry's alone: there a
# window's discrepancy should be near zero (SETTLING_VARIANCE) under any scale. Beyond
# UNSETTLED_LIMIT (whitened: sigmas of the window's odometry as modelled) the model does not
# explain the window (an association or the linearisation bent it: indoor-tags, noise x6,
# the true covariance stated, seeds 3 and 5, one such window each, read 5x and 12x), and it
# is set aside.
UNDECIDED_SHARE = 0.05
UNSETTLED_LIMIT = 0.5
# The scales the windows' likelihood is searched over step by this factor.
SCALE_STEP = 1.05
# A window across a wrong association reads a drift no odometry has (kitti05-cars, noise x5,
# the true covariance stated, seed 5: one window of twenty read a scale past 100 with 937
# nats, the other nineteen about 1, and the scale went to 100 for good, 160 m RMSE). Each
# window is therefore the model's with probability 1 - OUTLIER_SHARE, else drift of
# OUTLIER_SCALE times the windows' own scale: a lone such window moves no scale, many agreeing
# windows still do.
OUTLIER_SHARE = 0.05
OUTLIER_SCALE = 1e4


@dataclass(frozen=True)
class NoiseScales:
    """Variance scales: of the odometry's covariance, and of each measurement component."""

    odometry: float
    measurement: tuple[float, ...]

    def measurement_matrix(self) -> np.ndarray:
        """D such that D Gamma D scales component k's variance by measurement[k]."""
        return np.diag(np.sqrt(self.measurement))

    def odometry_covariance(self, stated: np.ndarray) -> np.ndarray:
        """A step's stated covariance at the odometry's scale."""
        return self.odometry * stated


def measurement_corrections(
    residuals: np.ndarray,
    prior_parts: np.ndarray,
    gammas: np.ndarray,
    min_pairings: int,
) -> np.ndarray:
    """Per component k, the factor by which Gamma_kk is off, from the tracking pairings of
    (n, d) residuals, (n, d, d) prior parts and (n, d, d) Gammas; 1 where fewer than
    `min_pairings` see the component."""
    P = np.einsum("nkk->nk", prior_parts)
    G = np.einsum("nkk->nk", gammas)
    tracking = P <= TRACKING_SHARE * G
    out = np.ones(residuals.shape[1])
    for k in range(residuals.shape[1]):
        rows = tracking[:, k]
        if rows.sum() >= min_pairings:
            excess = np.sum(residuals[rows, k] ** 2) - np.sum(P[rows, k])
            out[k] = max(excess, 0.0) / np.sum(G[rows, k])
    return out


class ScaleEstimator:
    """The measurement components' factors from the latest `window` pairings, once
    `min_pairings` see a component, within `bounds`."""

    def __init__(self, dim: int, window: int, min_pairings: int, bounds: tuple[float, float]):
        self.dim = dim
        self.min_pairings = min_pairings
        self.bounds = bounds
        self._pairings: deque[tuple[np.ndarray, np.ndarray, np.ndarray]] = deque(maxlen=window)

    def __len__(self) -> int:
        return len(self._pairings)

    def add(self, residual: np.ndarray, prior_part: np.ndarray, gamma: np.ndarray) -> None:
        self._pairings.append((residual, prior_part, gamma))

    def corrections(self) -> np.ndarray | None:
        """Factors [b_1 .. b_d] by which the current measurement scales are off, or None
        while there are too few pairings."""
        if len(self._pairings) < self.min_pairings:
            return None
        nu, P, G = (np.stack(part) for part in zip(*self._pairings, strict=True))
        return np.clip(measurement_corrections(nu, P, G, self.min_pairings), *self.bounds)

    def clear(self) -> None:
        """Forget the pairings: they were whitened with the scales now replaced."""
        self._pairings.clear()


def composed_odometry(
    steps: Sequence[gtsam.Pose3], covariances: Sequence[np.ndarray]
) -> tuple[gtsam.Pose3, np.ndarray]:
    """The steps' product and its covariance to first order: each step's noise (right
    perturbation, GTSAM's [rotation, translation]) carried to the end through the steps after
    it, as a prediction carries the pose's."""
    total, Q = gtsam.Pose3(), np.zeros((6, 6))
    for step, covariance in zip(steps, covariances, strict=True):
        A = step.inverse().AdjointMap()
        Q = A @ Q @ A.T + covariance
        total = total.compose(step)
    return total, Q


def relative_covariance(relative: gtsam.Pose3, joint: np.ndarray) -> np.ndarray:
    """Covariance of T = x_a^-1 x_b from the (12, 12) joint of x_a and x_b: a perturbation
    x_a Exp(e_a), x_b Exp(e_b) moves T by T Exp(e_b - Ad(T^-1) e_a)."""
    J = np.hstack([-relative.inverse().AdjointMap(), np.eye(6)])
    return J @ joint @ J.T


def drift_spectrum(
    discrepancy: np.ndarray, modelled: np.ndarray, relative: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """One window in the frame that whitens its odometry's covariance Q (`modelled`): the
    share e of each direction that the rest of the graph decides (the eigenvalues of
    I - W C W^T, W Q W^T = I, C the estimate's `relative` covariance) and the discrepancy's
    component along each. If the odometry's true covariance is c Q, a component's variance is
    e (1 - e) + c e^2."""
    W = np.linalg.inv(np.linalg.cholesky(modelled))
    decided = np.eye(len(discrepancy)) - W @ relative @ W.T
    shares, basis = np.linalg.eigh(0.5 * (decided + decided.T))
    return np.clip(shares, 0.0, 1.0), basis.T @ (W @ discrepancy)


def settled(shares: np.ndarray, components: np.ndarray) -> bool:
    """Whether a window (`drift_spectrum`) is the model's: its discrepancy stays within
    UNSETTLED_LIMIT along every direction the landmarks leave to the odometry."""
    return not np.any(np.abs(components[shares < UNDECIDED_SHARE]) > UNSETTLED_LIMIT)


def drift_log_likelihood(
    scales: np.ndarray, shares: np.ndarray, components: np.ndarray
) -> np.ndarray:
    """Log-likelihood, up to a constant, of each of n windows' (n, 6) shares and components
    if the odometry's covariance is each of `scales` times the one they were taken with:
    (len(scales), n)."""
    variance = shares * (1.0 - shares) + np.multiply.outer(scales, shares**2) + SETTLING_VARIANCE
    return -0.5 * np.sum(np.log(variance) + components**2 / variance, axis=2)


def robust_drift_log_likelihood(
    scales: np.ndarray, shares: np.ndarray, components: np.ndarray
) -> np.ndarray:
    """Log-likelihood of the windows together under each of `scales`, each window an outlier
    (drift at OUTLIER_SCALE) with probability OUTLIER_SHARE."""
    model = drift_log_likelihood(scales, shares, components)
    outlier = drift_log_likelihood(np.array([OUTLIER_SCALE]), shares, components)
    mixed = np.logaddexp(np.log1p(-OUTLIER_SHARE) + model, np.log(OUTLIER_SHARE) + outlier)
    return np.sum(mixed, axis=1)


def drift_scale(
    shares: np.ndarray, components: np.ndarray, bounds: tuple[float, float]
) -> tuple[float, float]:
    """The scale within `bounds` (relative to the windows' own) under which the windows are
    most likely, and its evidence: the log-likelihood ratio of that scale against theirs."""
    low, high = bounds
    scales = np.append(np.exp(np.arange(np.log(low), np.log(high), np.log(SCALE_STEP))), high)
    # the windows' own scale last: the reference, a candidate only if within the bounds
    likelihood = robust_drift_log_likelihood(np.append(scales, 1.0), shares, components)
    if low <= 1.0 <= high:
        scales = np.append(scales, 1.0)
    best = int(np.argmax(likelihood[: len(scales)]))
    return float(scales[best]), float(likelihood[best] - likelihood[-1])


class OdometryDrift:
    """The odometry's variance scale, from the windows of `length` keyframes and, if
    `long_length`, of that many, seen since the scale last changed (the latest `kept` of
    either length, read together once `min_windows` are in).

    Long windows are for an odometry that errs by a slow bias: its drift over n keyframes grows
    faster than n while n is short of the bias's correlation time, so short windows alone read
    a smaller scale than the loops that must close need (planar-park's yaw: about 14 at 50
    keyframes, 33 at 200). Where the error is white, both lengths say the same."""

    def __init__(self, length: int, kept: int, min_windows: int, long_length: int = 0):
        self.length = length
        self.long_length = long_length
        self.min_windows = min_windows
        # stated steps, enough for the longest window
        self._steps: deque[tuple[gtsam.Pose3, np.ndarray]] = deque(maxlen=max(length, long_length))
        # (shares, components) of each window, as `drift_spectrum` gives them
        self._windows: deque[tuple[np.ndarray, np.ndarray]] = deque(maxlen=kept)
        self._scale: float | None = None  # the odometry's scale when the windows were taken

    def due(self, pose_index: int, every: int) -> list[int]:
        """The window lengths to observe ending at keyframe `pose_index`, checked every `every`
        keyframes: each length whose steps are known, every `every` keyframes or, when longer,
        every its own length, so that no two windows of one length overlap."""
        lengths = [self.length] + ([self.long_length] if self.long_length else [])
        return [n for n in lengths if len(self._steps) >= n and pose_index % max(n, every) == 0]

    def add_step(self, step: gtsam.Pose3, stated: np.ndarray) -> None:
        self._steps.append((step, stated))

    def observe(
        self, relative: gtsam.Pose3, joint: np.ndarray, scale: float, length: int | None = None
    ) -> None:
        """A window of the last `length` steps (default: `self.length`): the estimate's pose
        of its last keyframe relative to its first, and the (12, 12) joint covariance of the
        two, with the odometry's covariance at `scale` times the stated one (a new scale
        forgets the windows taken under the old). A window the model does not explain
        (`settled`) is left out."""
        if scale != self._scale:
            self._windows.clear()
            self._scale = scale
        steps = list(self._steps)[-(length or self.length) :]
        composed, stated = composed_odometry(*zip(*steps, strict=True))
        delta = gtsam.Pose3.Logmap(composed.between(relative))
        window = drift_spectrum(delta, scale * stated, relative_covariance(relative, joint))
        if settled(*window):
            self._windows.append(window)

    def reading(self, bounds: tuple[float, float]) -> tuple[float, float] | None:
        """The odometry's scale within `bounds` the windows say (`drift_scale`) and its
        evidence in nats; None while fewer than `min_windows` windows are in."""
        if self._scale is None or len(self._windows) < self.min_windows:
            return None
        shares, components = (np.stack(part) for part in zip(*self._windows, strict=True))
        low, high = bounds
        factor, evidence = drift_scale(shares, components, (low / self._scale, high / self._scale))
        return self._scale * factor, evidence


class DriftScaleBelief:
    """What the loops closed so far say about the odometry's variance scale: a distribution
    over a log grid of scales, for the loop tests of `merges.py`, which must close a first loop
    before any estimate of the scale exists (`OdometryDrift` reads it off closed loops).

    It starts as a prior: the log's covariance right (scale 1) with probability 1 - `weight`,
    the rest spread evenly in log over `steps` scales up to `max_scale`. Each set of pairs
    merged across a loop multiplies it by its likelihood under each scale, so that once loops
    close where the log says, a lookalike street that only a drift of many times the stated
    one could explain is no longer weighed as one; and once they close far from it, the next
    loop is tested at that scale."""

    def __init__(self, weight: float, max_scale: float, steps: int):
        self.loops = 0  # loops observed
        if weight <= 0.0 or max_scale <= 1.0:
            self.scales, self.log_weights = np.ones(1), np.zeros(1)
        else:
            grid = np.geomspace(max_scale ** (1.0 / steps), max_scale, steps)
            self.scales = np.concatenate([[1.0], grid])
            weights = np.concatenate([[1.0 - weight], np.full(steps, weight / steps)])
            self.log_weights = np.log(weights)
        self._prior = self.log_weights.copy()
        # The loops' log-likelihoods, each loop allowed to be an outlier (`reading`).
        self._robust = np.zeros(len(self.scales))

    def _above(self, current: float) -> np.ndarray:
        return self.scales > current * (1.0 + 1e-9)

    def relative(self, current: float) -> tuple[np.ndarray, np.ndarray]:
        """(scales, log weights) relative to the odometry's `current` scale: the scales at or
        below it count as the current one (a loop test only widens the covariance)."""
        above = self._above(current)
        folded = np.logaddexp.reduce(self.log_weights[~above]) if (~above).any() else -np.inf
        scales = np.concatenate([[1.0], self.scales[above] / current])
        return scales, np.concatenate([[folded], self.log_weights[above]])

    def observe(self, current: float, log_likelihoods: np.ndarray) -> None:
        """A loop closed: its log-likelihood under each of `relative(current)`'s scales."""
        above = self._above(current)
        full = np.empty(len(self.scales))
        full[~above] = log_likelihoods[0]
        full[above] = log_likelihoods[1:]
        posterior = self.log_weights + full
        self.log_weights = posterior - np.logaddexp.reduce(posterior)
        self._robust += np.logaddexp(
            np.log1p(-OUTLIER_SHARE) + full, np.log(OUTLIER_SHARE) + np.max(full)
        )
        self.loops += 1

    def reading(self, current: float) -> tuple[float, float] | None:
        """The odometry's scale the loops closed so far make most probable, and its evidence
        against `current`: the log-odds of that scale against all those at or below `current`
        (nats; at most 0 when the most probable is one of them). None before the first loop.

        Here, unlike in the loop tests, each loop is the model's with probability
        1 - OUTLIER_SHARE, else a wrong closure that says nothing of the drift, as each drift
        window is: one loop moves the odometry's scale by at most log(1 / OUTLIER_SHARE), 3.0
        nats, so that a lone wrong closure cannot move it (kitti05-cars, noise x5, the true
        covariance stated, seed 4: one loop of 24 said 31.6 by 1,747 nats, the others about 1;
        moved by it, the odometry's scale went 1 -> 31.6, then 29 batch re-solves and 1.28 ->
        1.90 m RMSE); two that agree can."""
        if self.loops == 0:
            return None
        posterior = self._prior + self._robust
        above = self._above(current)
        at_or_below = np.logaddexp.reduce(posterior[~above]) if (~above).any() else -np.inf
        best = int(np.argmax(posterior))
        return float(self.scales[best]), float(posterior[best] - at_or_below)

    def report(self) -> dict[str, Any]:
        """For metrics.json: the loops observed, the scales and their probabilities now."""
        return {
            "loops": self.loops,
            "scales": [round(float(c), 4) for c in self.scales],
            "probabilities": [round(float(p), 4) for p in np.exp(self.log_weights)],
        }


@dataclass(frozen=True)
class OdometryScaleMove:
    """One change of the odometry's variance scale: at which keyframe, from what to what, the
    evidence for it (nats) and whose it is: the drift windows' or the closed loops'."""

    pose_index: int
    before: float
    after: float
    evidence: float
    source: Literal["windows", "loops"] = "windows"


def odometry_scale_move(
    current: float,
    reading: float,
    evidence: float,
    deadband: float,
    min_evidence: float,
    down: bool = True,
) -> float | None:
    """The odometry's new scale from the windows' `reading` (`OdometryDrift.reading`), or None
    to keep `current`. Only clear steps, each reweights the whole trajectory: with at least
    `min_evidence` nats for it, up to the reading when that is `deadband` times the current
    scale or more, down (if `down`) when it is the current over `deadband` or less."""
    if evidence < min_evidence or reading == current:
        return None
    if reading >= deadband * current or (down and reading * deadband <= current):
        return reading
    return None


def updated(
    scales: NoiseScales, corrections: np.ndarray, bounds: tuple[float, float], max_step: float
) -> NoiseScales:
    """The measurement scales times their corrections (each by at most a factor `max_step`
    either way), kept within `bounds`; the odometry's as it was."""
    low, high = bounds
    steps = np.clip(corrections, 1.0 / max_step, max_step)
    measurement = tuple(
        float(np.clip(s * c, low, high)) for s, c in zip(scales.measurement, steps, strict=True)
    )
    return NoiseScales(scales.odometry, measurement)


class EstimateReader(Protocol):
    """What the learner reads of the estimate: poses and their joint covariance."""

    def pose(self, key: int) -> gtsam.Pose3: ...

    def joint_covariance(self, keys: list[int]) -> np.ndarray: ...


class NoiseLearner:
    """The noise scales a replay uses, and, where `enabled` (`[noise] estimate`, a method that
    sees sure pairings), how they are learnt: every `update_every` keyframes the measurement's
    from the latest sure pairings (`innovations`, which the method fills), the odometry's from
    its drift windows against the estimate or from the loops the merges closed
    (`DriftScaleBelief`), by clear moves only."""

    def __init__(self, config: NoiseConfig, enabled: bool):
        n = self.config = config
        self.enabled = enabled and n.estimate
        start = n.odometry_scale
        if self.enabled:  # from odometry_start_scale, never below its floor
            start = max(n.odometry_start_scale, n.odometry_scale)
        self.scales = NoiseScales(start, tuple(n.measurement_scale))
        self.innovations = ScaleEstimator(3, n.window, n.min_pairings, (n.min_scale, n.max_scale))
        self.drift = (
            OdometryDrift(n.drift_window, n.drift_windows, n.min_drift_windows, n.long_drift_window)
            if self.enabled
            else None
        )
        self.odometry_moves: list[OdometryScaleMove] = []  # in order

    @property
    def watches_drift(self) -> bool:
        """Whether the odometry's steps are wanted (`add_step`)."""
        return self.drift is not None

    def add_step(self, step: gtsam.Pose3, stated: np.ndarray) -> None:
        """The odometry's next step and its stated covariance."""
        if self.drift is not None:
            self.drift.add_step(step, stated)

    def samples(self, pose_index: int) -> bool:
        """Whether keyframe `pose_index` gets the whole joint test even where every pairing is
        sure, so that sure pairings tell the noise too."""
        return self.config.estimate and pose_index % self.config.sample_every == 0

    def learn(
        self, pose_index: int, estimate: EstimateReader, loops: DriftScaleBelief | None
    ) -> bool:
        """Every few keyframes, the noise scales corrected: the measurement's by the latest
        sure pairings, the odometry's by its drift against `estimate` or by the `loops` closed
        so far. Whether the odometry's changed (every odometry factor is then to be
        reweighted)."""
        n = self.config
        if not self.enabled or pose_index % n.update_every:
            return False
        measurement = self.innovations.corrections()
        if measurement is not None:
            self.scales = updated(self.scales, measurement, (n.min_scale, n.max_scale), n.max_step)
            self.innovations.clear()  # they were whitened with the scales replaced
        logger.debug("pose %d: noise scales %s", pose_index, self.scales)
        moves = self._odometry_moves(pose_index, estimate, loops)
        if not moves:
            return False
        move = max(moves, key=lambda m: m.after)
        self.odometry_moves.append(move)
        logger.debug(
            "pose %d: odometry scale %.3g -> %.3g (%s, %.1f nats)",
            pose_index,
            move.before,
            move.after,
            move.source,
            move.evidence,
        )
        self.scales = NoiseScales(move.after, self.scales.measurement)
        return True

    def _odometry_moves(
        self, pose_index: int, estimate: EstimateReader, loops: DriftScaleBelief | None
    ) -> list[OdometryScaleMove]:
        """The clear moves (`odometry_scale_move`) of the odometry's scale that the drift
        windows ending now and the loops the merges closed so far say (the loops' only up: a
        loop that closes at the current scale says little of a smaller one)."""
        n, current = self.config, self.scales.odometry
        readings = []
        windows = self._drift_reading(pose_index, estimate)
        if windows is not None:
            # Down only to undo a start set above the floor (odometry_scale): once the windows
            # have raised the scale, a map bent by the loops it let close reads unevenly, and
            # coming down again made kitti05-cars (noise x3, calibrated, seed 5) 10.4 -> 16.6 m.
            down = not any(m.after > m.before for m in self.odometry_moves)
            readings.append(("windows", *windows, down))
        if n.scale_from_loops and loops is not None:
            said = loops.reading(current)
            if said is not None:
                readings.append(("loops", min(said[0], n.max_scale), said[1], False))
        moves = []
        for source, scale, evidence, down in readings:
            after = odometry_scale_move(
                current, scale, evidence, n.drift_deadband, n.drift_evidence, down=down
            )
            if after is not None:
                moves.append(OdometryScaleMove(pose_index, current, after, evidence, source))
        return moves

    def _drift_reading(
        self, pose_index: int, estimate: EstimateReader
    ) -> tuple[float, float] | None:
        """The odometry's scale its windows say and their evidence, with the windows ending
        now."""
        if self.drift is None:
            return None
        n = self.config
        last = X(pose_index)
        last_pose = estimate.pose(last)
        for length in self.drift.due(pose_index, n.update_every):
            first = X(pose_index - length)
            relative = estimate.pose(first).between(last_pose)
            joint = estimate.joint_covariance([first, last])
            self.drift.observe(relative, joint, self.scales.odometry, length)
        return self.drift.reading((n.odometry_scale, n.max_scale))
