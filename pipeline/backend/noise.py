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
as two measurements of T, delta = G (z_odometry - z_rest) with G = I - C Q^-1, and if the
odometry's true covariance is c Q, E[delta^T Q^-1 delta] = (6 - tr(Q^-1 C)) + (c - 1) r with
r = tr(Q^-1 G Q G^T): so c = 1 + (nis - (6 - tr(Q^-1 C))) / r, a window's correction (over
windows, their median moves the scale up and their pooled moment down: `drift_corrections`).
A window the landmarks do not pin (C near Q) has r near 0 and says little; the plain ratio
nis / (6 - tr(Q^-1 C)) would read low wherever the estimate still leans on a stiff odometry.
A slow odometry bias drifts more over a long window than white noise of the same step sigma:
the scale found is the one at the window's length.

Pure functions and small accumulators; the pairings come from `methods/maxmixture.py`, the
windows from `slam.py`, which applies the scales.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import gtsam
import numpy as np

# A pairing tells b_k when P_kk is at most this share of Gamma_kk.
TRACKING_SHARE = 0.25
# A window tells the odometry's scale when the landmarks let this many degrees of freedom of
# its error through (a window they do not pin says little, and noisily).
MIN_REACH = 0.25


@dataclass(frozen=True)
class NoiseScales:
    """Variance scales: of the odometry's covariance, and of each measurement component."""

    odometry: float
    measurement: tuple[float, ...]

    def measurement_matrix(self) -> np.ndarray:
        """D such that D Gamma D scales component k's variance by measurement[k]."""
        return np.diag(np.sqrt(self.measurement))


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


def drift_moments(
    discrepancy: np.ndarray, modelled: np.ndarray, relative: np.ndarray
) -> tuple[float, float, float]:
    """One window's moments under the odometry as modelled (Q, composed) and the estimate's
    relative covariance C: (delta^T Q^-1 delta, 6 - tr(Q^-1 C), tr(Q^-1 G Q G^T)) with
    G = I - C Q^-1. The window's odometry and the rest of the graph are two measurements of
    the relative pose; delta = G (z_odometry - z_rest), so if the odometry's true covariance is
    c Q, E[nis] = (6 - tr(Q^-1 C)) + (c - 1) tr(Q^-1 G Q G^T): the third says how much of the
    odometry's own error the landmarks let through."""
    Q_inv = np.linalg.inv(modelled)
    nis = float(discrepancy @ Q_inv @ discrepancy)
    decided = len(discrepancy) - float(np.trace(Q_inv @ relative))
    G = np.eye(len(discrepancy)) - relative @ Q_inv
    reach = float(np.trace(Q_inv @ G @ modelled @ G.T))
    return nis, decided, reach


class OdometryDrift:
    """The odometry's variance scale, from the windows of `length` keyframes seen since the
    scale last changed (at most `kept`, at least `min_windows`)."""

    def __init__(self, length: int, kept: int, min_windows: int):
        self.length = length
        self.min_windows = min_windows
        self._steps: deque[tuple[gtsam.Pose3, np.ndarray]] = deque(maxlen=length)  # stated
        self._moments: deque[tuple[float, float, float]] = deque(maxlen=kept)
        self._scale: float | None = None  # the odometry's scale when the moments were taken

    @property
    def full(self) -> bool:
        """Whether the last `length` steps are known: a window can be seen."""
        return len(self._steps) == self.length

    def add_step(self, step: gtsam.Pose3, stated: np.ndarray) -> None:
        self._steps.append((step, stated))

    def observe(self, relative: gtsam.Pose3, joint: np.ndarray, scale: float) -> None:
        """A window: the estimate's pose of its last keyframe relative to its first, and the
        (12, 12) joint covariance of the two, with the odometry's covariance at `scale` times
        the stated one (a new scale forgets the windows taken under the old)."""
        if scale != self._scale:
            self._moments.clear()
            self._scale = scale
        composed, stated = composed_odometry(*zip(*self._steps, strict=True))
        delta = gtsam.Pose3.Logmap(composed.between(relative))
        C = relative_covariance(relative, joint)
        self._moments.append(drift_moments(delta, scale * stated, C))

    def readings(self) -> tuple[float, float] | None:
        """The scale the windows say, (median, pooled) as `drift_corrections` reads them,
        times the current scale; None while fewer than `min_windows` windows reach."""
        if self._scale is None:
            return None
        corrections = drift_corrections(np.array(self._moments).reshape(-1, 3), self.min_windows)
        if corrections is None:
            return None
        return self._scale * corrections[0], self._scale * corrections[1]


def drift_corrections(moments: np.ndarray, min_windows: int) -> tuple[float, float] | None:
    """Windows' (nis, decided, reach) rows to the odometry scale's correction, two ways:
    (median, pooled) of 1 + (nis - decided) / reach, over the windows that reach at least
    MIN_REACH degrees of freedom of the odometry's error; None while fewer than `min_windows`
    do. The median of the windows' corrections ignores a window across a loop closure that
    bent the map (or a wrong one), which outweighs all the others in the pool (kitti05-cars,
    noise x5 with its true covariance stated, seed 9: pooled 3.15, median 1.2). The pooled
    moment, 1 + sum(nis - decided) / sum(reach), is unbiased, where the median of these
    right-skewed corrections reads low, the more so the less the windows reach."""
    nis, decided, reach = moments[moments[:, 2] >= MIN_REACH].T
    if len(reach) < min_windows:
        return None
    median = max(float(np.median(1.0 + (nis - decided) / reach)), 0.0)
    pooled = max(1.0 + float(np.sum(nis - decided) / np.sum(reach)), 0.0)
    return median, pooled


def odometry_scale_move(
    current: float,
    median: float,
    pooled: float,
    deadband: float,
    bounds: tuple[float, float],
    down: bool = True,
) -> float | None:
    """The odometry's new scale from its windows' readings (`OdometryDrift.readings`), or None
    to keep `current`. Only clear steps (each reweights the whole trajectory): up to the median
    when that reaches `deadband` times the current scale, down (if `down`) to the pooled moment
    when that is at most the current over `deadband`, within `bounds`. Each way with the
    reading that errs towards keeping the scale: a window bent by a loop closure pulls the
    pooled moment up, and the median reads low."""
    low, high = bounds
    if median >= deadband * current:
        new = min(median, high)
    elif down and pooled * deadband <= current:
        new = max(pooled, low)
    else:
        return None
    return new if new != current else None


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
