"""How far a log's stated noise is from the truth: covariance scales estimated online from the
innovations of sure associations.

A detection paired with a landmark has innovation nu = h(x, l) - z with covariance
S = P + Gamma: P the pose's and the landmark's uncertainty seen through the measurement (it
grows with the odometry's covariance), Gamma the detection's own. If the log understates its
odometry by a factor a in variance and misstates each measurement component k by b_k, then
E[nu nu^T] = a P + sum_k b_k Gamma_kk e_k e_k^T (+ Gamma's correlations). Whitened by S, every
pairing gives six such equations (the upper triangle of a 3x3 matrix); pairings near a pose
just seen weigh mostly on the b_k, pairings after a long drive on a. Least squares over the
latest pairings estimates the scales; the back-end multiplies new factors' covariances by them.

Pure numpy; the pairings come from `methods/maxmixture.py`, the scales go to `slam.py`.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class NoiseScales:
    """Variance scales: of the odometry's covariance, and of each measurement component."""

    odometry: float
    measurement: tuple[float, ...]

    def measurement_matrix(self) -> np.ndarray:
        """D such that D Gamma D scales component k's variance by measurement[k]."""
        return np.diag(np.sqrt(self.measurement))


def scale_equations(
    residual: np.ndarray, prior_part: np.ndarray, gamma: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The pairing's equations (A, y): y = A [a, b_1 .. b_d], whitened by S = P + Gamma, from
    the upper triangle of W nu nu^T W^T = a W P W^T + sum_k b_k Gamma_kk W e_k e_k^T W^T
    + W Gamma_off W^T (Gamma's correlations are taken as stated)."""
    d = len(residual)
    S = prior_part + gamma
    W = np.linalg.inv(np.linalg.cholesky(0.5 * (S + S.T)))
    rows, cols = np.triu_indices(d)
    w = W @ residual
    off = gamma - np.diag(np.diag(gamma))
    y = (np.outer(w, w) - W @ off @ W.T)[rows, cols]
    columns = [(W @ prior_part @ W.T)[rows, cols]]
    for k in range(d):
        column = W[:, k] * np.sqrt(gamma[k, k])
        columns.append(np.outer(column, column)[rows, cols])
    return np.column_stack(columns), y


class ScaleEstimator:
    """Least squares over the latest `window` pairings, with a weak pull towards the current
    scales (`prior_weight` pairings' worth), bounded to `bounds`."""

    def __init__(self, dim: int, window: int, min_pairings: int, bounds: tuple[float, float]):
        self.dim = dim
        self.min_pairings = min_pairings
        self.bounds = bounds
        self._equations: deque[tuple[np.ndarray, np.ndarray]] = deque(maxlen=window)

    def __len__(self) -> int:
        return len(self._equations)

    def add(self, residual: np.ndarray, prior_part: np.ndarray, gamma: np.ndarray) -> None:
        self._equations.append(scale_equations(residual, prior_part, gamma))

    def corrections(self) -> np.ndarray | None:
        """Factors [a, b_1 .. b_d] by which the current scales are off, or None while there
        are too few pairings."""
        if len(self._equations) < self.min_pairings:
            return None
        A = np.concatenate([a for a, _ in self._equations])
        y = np.concatenate([b for _, b in self._equations])
        # A weak prior at 1 keeps a scale the pairings hardly see (no drift yet: no a) put.
        prior = 1e-4 * len(self._equations)
        n = A.shape[1]
        solution = np.linalg.solve(A.T @ A + prior * np.eye(n), A.T @ y + prior * np.ones(n))
        return np.clip(solution, *self.bounds)

    def clear(self) -> None:
        """Forget the pairings: they were whitened with the scales now replaced."""
        self._equations.clear()


def updated(
    scales: NoiseScales, corrections: np.ndarray, bounds: tuple[float, float]
) -> NoiseScales:
    """The scales times their corrections, kept within `bounds`."""
    low, high = bounds
    odometry = float(np.clip(scales.odometry * corrections[0], low, high))
    measurement = tuple(
        float(np.clip(s * c, low, high))
        for s, c in zip(scales.measurement, corrections[1:], strict=True)
    )
    return NoiseScales(odometry, measurement)
