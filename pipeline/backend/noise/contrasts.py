"""The detections' noise per component, from what a keyframe's detections disagree about.

A keyframe's K detections of mapped point landmarks have residuals r_k = h(x, l_k) - z_k at
the current estimate. Stacked, r = H_x e + (the landmarks' errors seen through h) - n, e the
pose's error and n the detections' noise. What the detections share, the pose's error (and an
odometry stated wrong with it), is projected out: with N an orthonormal basis of what H_x's
columns leave (3K - 6 directions; a keyframe needs three detections, two in a plane),
y = N^T W r, W the detections' noise whitened at the scales in use. A landmark estimated from
n_k detections holds 1 / n_k of each (its residual is the detection's noise less that share),
so that

    y ~ N(0, N^T W blockdiag((1 - 1 / n_k) Gamma_k(s)) W^T N),

Gamma_k(s) each detection's stated covariance at the components' scales s (bearing,
elevation, range), linear in their pair coefficients: one `ScaleObservation` a keyframe.

Why the smoothed residuals and not the innovations at association: a real detector's error
on one object changes slowly with the viewpoint (a tree trunk's centre, a car's box), so that
two detections a keyframe apart differ much less than two from across the run, and the
innovation against a landmark just seen says the noise is a fraction of what it is (Victoria
Park: about 1/30 of the bearing's variance, where Known DA's residuals say 0.4). The landmark's
estimate, from every viewpoint it was seen from, is what a revisit is gated against.
"""

from __future__ import annotations

import numpy as np

from pipeline.backend.geometry import point_residual, predict_point_jacobians_batch
from pipeline.backend.noise.components import ScaleObservation, nonzero_pairs, pair_basis

POSE_DIRECTIONS = 6
# Whitened, the observation's covariance gets this much more on its diagonal: it has no part
# that does not scale, and a component whose every detection agrees exactly (a planar log's
# elevation) would leave it singular.
JITTER = 1e-9


def contrast_observation(
    rotation: np.ndarray,
    translation: np.ndarray,
    landmarks: np.ndarray,
    measured: np.ndarray,
    stated: np.ndarray,
    sightings: np.ndarray,
    used: np.ndarray,
    free: np.ndarray | None = None,
) -> ScaleObservation | None:
    """The observation of a keyframe at pose (rotation, translation) whose K detections
    `measured` (K, 3: bearing, elevation, range), with stated covariances (K, 3, 3), hold point
    `landmarks` (K, 3) estimated from `sightings` (K,) detections each: what they disagree
    about, the pose's error along its `free` directions (default: all six; a planar log's
    pose is pinned in height, roll and pitch) projected out. `used`: the components' scales in
    use (they whiten, nothing more). None where nothing is left."""
    K = len(measured)
    free = np.ones(POSE_DIRECTIONS, bool) if free is None else np.asarray(free, bool)
    if int(free.sum()) >= 3 * K:
        return None
    z, H_x, _ = predict_point_jacobians_batch(rotation, translation, landmarks)
    residuals = point_residual(z, measured)  # (K, 3)
    root = np.sqrt(np.asarray(used, dtype=float))
    whiten = np.linalg.inv(np.linalg.cholesky(stated * np.outer(root, root)))  # (K, 3, 3)
    y_all = np.einsum("kij,kj->ki", whiten, residuals).reshape(-1)
    H = np.einsum("kij,kjl->kil", whiten, H_x[:, :, free]).reshape(3 * K, int(free.sum()))
    U, singular, _ = np.linalg.svd(H, full_matrices=True)
    rank = int(np.sum(singular > singular[0] * 1e-9))
    N = U[:, rank:]  # what the pose's error cannot move
    pairs = nonzero_pairs(stated)
    share = 1.0 - 1.0 / np.maximum(np.asarray(sightings, dtype=float), 1.0)
    blocks = np.stack([s * pair_basis(g, pairs) for g, s in zip(stated, share, strict=True)])
    whitened = np.einsum("kij,kpjl,kml->kpim", whiten, blocks, whiten)  # (K, P, 3, 3)
    full = np.zeros((len(pairs), 3 * K, 3 * K))
    for k in range(K):
        full[:, 3 * k : 3 * k + 3, 3 * k : 3 * k + 3] = whitened[k]
    basis = np.einsum("ia,pij,jb->pab", N, full, N)
    rest = JITTER * np.eye(N.shape[1])
    return ScaleObservation.made(N.T @ y_all, rest, basis, pairs, np.asarray(used, dtype=float))
