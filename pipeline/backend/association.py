"""Association weights (METHOD.md): semantic times geometric likelihood, gated, normalised.

All functions are pure. Log domain throughout, so that tiny likelihoods of far candidates do not
underflow before normalisation.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

LOG_2PI = math.log(2.0 * math.pi)


# A search asks the gate of every set size up to its number of sources: room for them all.
@lru_cache(maxsize=4096)
def chi2_gate(dof: int, confidence: float) -> float:
    """Squared Mahalanobis distance below which a candidate passes the gate."""
    from scipy.special import chdtri  # the chi-square quantile, without importing scipy.stats

    return float(chdtri(dof, 1.0 - confidence))


def innovation_covariance(H: np.ndarray, Sigma: np.ndarray, Gamma: np.ndarray) -> np.ndarray:
    """R = H Sigma H^T + Gamma: the measurement's covariance with pose and landmark marginalised."""
    R = H @ Sigma @ H.T + Gamma
    return 0.5 * (R + R.T)


def mahalanobis_squared(residual: np.ndarray, covariance: np.ndarray) -> float:
    L = np.linalg.cholesky(covariance)
    y = np.linalg.solve(L, residual)
    return float(y @ y)


def gaussian_log_density(residual: np.ndarray, covariance: np.ndarray) -> float:
    """log N(residual; 0, covariance), normaliser included."""
    L = np.linalg.cholesky(covariance)
    y = np.linalg.solve(L, residual)
    log_det = 2.0 * float(np.sum(np.log(np.diag(L))))
    return -0.5 * (float(y @ y) + log_det + residual.size * LOG_2PI)


def mahalanobis_squared_batch(residuals: np.ndarray, covariances: np.ndarray) -> np.ndarray:
    """`mahalanobis_squared` of (k, d) residuals under (k, d, d) covariances."""
    solved = np.linalg.solve(covariances, residuals[..., None])[..., 0]
    return np.einsum("ki,ki->k", residuals, solved)


def gaussian_log_density_batch(residuals: np.ndarray, covariances: np.ndarray) -> np.ndarray:
    """`gaussian_log_density` of (k, d) residuals under (k, d, d) covariances."""
    _, log_det = np.linalg.slogdet(covariances)
    dim = residuals.shape[-1]
    return -0.5 * (mahalanobis_squared_batch(residuals, covariances) + log_det + dim * LOG_2PI)


def semantic_likelihood(
    confusion: np.ndarray, reported_class: int, class_probabilities: np.ndarray
) -> float:
    """P(reported | landmark) = sum_c P(reported | c) P(landmark class = c | past)."""
    return float(confusion[:, reported_class] @ class_probabilities)


def normalise_log_weights(log_weights: np.ndarray) -> np.ndarray:
    """exp(log_weights) normalised to sum to one, computed stably."""
    log_weights = np.asarray(log_weights, dtype=float)
    shifted = np.exp(log_weights - np.max(log_weights))
    return shifted / shifted.sum()


def association_weights(log_geometric: np.ndarray, semantic: np.ndarray) -> np.ndarray:
    """Weights of the gated candidates: proportional to semantic x geometric likelihood.

    Candidates with zero semantic likelihood (a class the detector never confuses) get zero.
    """
    semantic = np.asarray(semantic, dtype=float)
    with np.errstate(divide="ignore"):
        log_w = np.asarray(log_geometric, dtype=float) + np.log(semantic)
    if not np.any(np.isfinite(log_w)):
        return np.zeros_like(log_w)
    return normalise_log_weights(log_w)


def with_null_hypothesis(weights: np.ndarray, null_weight: float) -> tuple[np.ndarray, float]:
    """Scale candidate weights to sum to 1 - null_weight; the null takes null_weight."""
    return np.asarray(weights, dtype=float) * (1.0 - null_weight), null_weight


def class_posterior_update(
    class_probabilities: np.ndarray,
    reported_likelihood: np.ndarray,
    weight: float,
    other_mass: float,
) -> np.ndarray:
    """One detection's evidence on a landmark's class (the paper's product of sums).

    Summing the detection's association out gives, for each class c of this landmark,
    `weight * P(reported | c) + other_mass`, where `other_mass` is the likelihood of the report
    under every other association (other candidates, a new landmark, the null) times its weight:
    it does not depend on c. A sure association (weight 1, other_mass 0) is a plain Bayes update.
    """
    evidence = weight * np.asarray(reported_likelihood, dtype=float) + other_mass
    posterior = np.asarray(class_probabilities, dtype=float) * evidence
    total = posterior.sum()
    if total <= 0.0 or not np.isfinite(total):
        return np.asarray(class_probabilities, dtype=float)
    return posterior / total
