"""How far a log's stated noise is from the truth: covariance scales estimated online from the
innovations of sure associations.

A detection paired with a landmark has innovation nu = h(x, l) - z with covariance
S = P + Gamma: P the pose's and the landmark's uncertainty seen through the measurement (it
grows with the odometry's covariance), Gamma the detection's own. If the log understates its
odometry by a factor a in variance and misstates measurement component k by b_k, then
E[nu nu^T] = a P + sum_k b_k Gamma_kk e_k e_k^T (+ Gamma's correlations). The two are told
apart by the pairings where one of them dominates:
- a landmark seen again from a pose known about as well as it (tracking: P_kk small beside
  Gamma_kk) tells b_k = (sum nu_k^2 - sum a P_kk) / sum Gamma_kk;
- a landmark seen after a long drive (P much larger than Gamma) tells
  a = sum (nu^T S^-1 nu - tr(S^-1 b Gamma)) / sum tr(S^-1 P), the normalised innovations'
  excess over what the measurement noise explains.
Moments, not a joint least-squares fit: where P and Gamma grow together the fit cannot tell a
from b and swings between bounds, while each moment rests on the pairings that see it.

Pure numpy; the pairings come from `methods/maxmixture.py`, the scales go to `slam.py`.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

# A pairing tells b_k when P_kk is at most this share of Gamma_kk, and a when tr(P) is at
# least this many times tr(Gamma).
TRACKING_SHARE = 0.25
DRIFT_RATIO = 4.0
ROUNDS = 5


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
    odometry: float = 1.0,
) -> np.ndarray:
    """Per component k, the factor by which Gamma_kk is off, from the tracking pairings of
    (n, d) residuals, (n, d, d) prior parts (times `odometry`, their own correction) and
    (n, d, d) Gammas; 1 where fewer than `min_pairings` see the component."""
    P = np.einsum("nkk->nk", prior_parts)
    G = np.einsum("nkk->nk", gammas)
    tracking = P <= TRACKING_SHARE * G
    out = np.ones(residuals.shape[1])
    for k in range(residuals.shape[1]):
        rows = tracking[:, k]
        if rows.sum() >= min_pairings:
            excess = np.sum(residuals[rows, k] ** 2) - odometry * np.sum(P[rows, k])
            out[k] = max(excess, 0.0) / np.sum(G[rows, k])
    return out


def odometry_correction(
    residuals: np.ndarray,
    prior_parts: np.ndarray,
    gammas: np.ndarray,
    measurement: np.ndarray,
    min_pairings: int,
) -> float:
    """The factor by which the prior parts (the odometry) are off, from the drift pairings,
    with the measurement components already corrected by `measurement`; 1 without enough."""
    drift = np.einsum("nkk->n", prior_parts) >= DRIFT_RATIO * np.einsum("nkk->n", gammas)
    if drift.sum() < min_pairings:
        return 1.0
    nu, P = residuals[drift], prior_parts[drift]
    D = np.sqrt(measurement)
    G = gammas[drift] * D[None, :, None] * D[None, None, :]
    S = P + G
    nis = np.einsum("ni,ni->n", nu, np.linalg.solve(S, nu[..., None])[..., 0])
    explained = np.einsum("nii->n", np.linalg.solve(S, G))  # tr(S^-1 b Gamma)
    carried = np.einsum("nii->n", np.linalg.solve(S, P))  # tr(S^-1 P)
    return max(float(np.sum(nis - explained) / np.sum(carried)), 0.0)


class ScaleEstimator:
    """The latest `window` pairings' moments, once `min_pairings` see a scale; each update
    moves a scale by at most `max_step` (a factor), within `bounds`."""

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
        """Factors [a, b_1 .. b_d] by which the current scales are off, or None while there
        are too few pairings."""
        if len(self._pairings) < self.min_pairings:
            return None
        nu, P, G = (np.stack(part) for part in zip(*self._pairings, strict=True))
        a = 1.0
        for _ in range(ROUNDS):  # each moment needs the other; a few rounds settle them
            b = measurement_corrections(nu, P, G, self.min_pairings, a)
            a = odometry_correction(nu, P, G, b, self.min_pairings)
        return np.clip(np.array([a, *b]), *self.bounds)

    def clear(self) -> None:
        """Forget the pairings: they were whitened with the scales now replaced."""
        self._pairings.clear()


def updated(
    scales: NoiseScales, corrections: np.ndarray, bounds: tuple[float, float], max_step: float
) -> NoiseScales:
    """The scales times their corrections (each by at most a factor `max_step` either way),
    kept within `bounds`."""
    low, high = bounds
    steps = np.clip(corrections, 1.0 / max_step, max_step)
    odometry = float(np.clip(scales.odometry * steps[0], low, high))
    measurement = tuple(
        float(np.clip(s * c, low, high)) for s, c in zip(scales.measurement, steps[1:], strict=True)
    )
    return NoiseScales(odometry, measurement)
