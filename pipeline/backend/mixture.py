"""Max-mixture components and expectation-maximisation weights, as pure functions.

A component k of a detection's mixture is `w_k N(h_k(x) - z; 0, Gamma_k)`. Its negative log
likelihood, normaliser included, is what the max-mixture compares, so that the null hypothesis
(a very broad Gaussian) competes fairly with narrow landmark components.
"""

from __future__ import annotations

import math

import numpy as np

from pipeline.backend.association import LOG_2PI


def gaussian_log_normaliser(covariance: np.ndarray) -> float:
    """0.5 log det(2 pi Gamma): the part of -log N that does not depend on the residual."""
    sign, log_det = np.linalg.slogdet(covariance)
    if sign <= 0:
        raise ValueError("covariance is not positive definite")
    return 0.5 * (log_det + covariance.shape[0] * LOG_2PI)


def component_nll(
    log_weight: np.ndarray | float, mahalanobis_sq: np.ndarray | float, log_normaliser: float
) -> np.ndarray:
    """-log(w N(r; 0, Gamma)) = -log w + 0.5 log det(2 pi Gamma) + 0.5 |r|^2_Gamma."""
    return -np.asarray(log_weight) + log_normaliser + 0.5 * np.asarray(mahalanobis_sq)


def null_component_nll(null_weight: float, null_sigma: float, dim: int) -> float:
    """The null hypothesis: an isotropic Gaussian of sigma `null_sigma`; its residual term is
    negligible (|r| / sigma ~ 1e-5 for any residual a real measurement has), so it is a constant."""
    return -math.log(null_weight) + 0.5 * dim * (LOG_2PI + 2.0 * math.log(null_sigma))


def em_weights(log_prior: np.ndarray, log_likelihood: np.ndarray) -> np.ndarray:
    """E-step of GPDA: posterior association weights per row, padded entries at -inf."""
    log_post = np.asarray(log_prior) + np.asarray(log_likelihood)
    top = np.max(log_post, axis=1, keepdims=True)
    expo = np.exp(log_post - top)
    return expo / expo.sum(axis=1, keepdims=True)
