"""The back-end's measurement models and their Jacobians, as pure numpy functions.

Conventions (GTSAM's): a pose is (R, t) mapping body to world; tangent vectors are ordered
(rotation, translation) and perturb on the right, T * Exp(xi). A point landmark is measured as
bearing, elevation and range of its position in the body frame (../shared/CONTRACT.md); a pose
landmark as its pose relative to the body, with residual Log(Z^-1 * X^-1 * L).

Functions ending in `_batch` take stacked arrays (leading dimension N) and avoid Python loops.
"""

from __future__ import annotations

import numpy as np

from pipeline.geometry import (
    adjoint,
    bearing_elevation_range,
    bearing_elevation_range_jacobian,
    point_from_bearing_elevation_range,
    se3_log,
    skew,
    wrap_angle,
)


def point_residual(z_predicted: np.ndarray, z_measured: np.ndarray) -> np.ndarray:
    """Predicted minus measured (bearing, elevation, range), bearing wrapped to [-pi, pi)."""
    r = np.asarray(z_predicted, dtype=float) - np.asarray(z_measured, dtype=float)
    r[..., 0] = wrap_angle(r[..., 0])
    return r


def predict_point_batch(R: np.ndarray, t: np.ndarray, landmark: np.ndarray) -> np.ndarray:
    """h(x, l): (bearing, elevation, range) of world points seen from poses (R, t)."""
    p_body = np.einsum("...ji,...j->...i", R, landmark - t)
    return bearing_elevation_range(p_body)


def predict_point(
    R: np.ndarray, t: np.ndarray, landmark: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """h(x, l) with its Jacobians: (z, H_pose 3x6, H_landmark 3x3)."""
    p_body = R.T @ (landmark - t)
    J = bearing_elevation_range_jacobian(p_body)
    # Right perturbation: p_body(x Exp(w, v)) = p_body + [p_body]x w - v.
    dp_dpose = np.hstack([skew(p_body), -np.eye(3)])
    return bearing_elevation_range(p_body), J @ dp_dpose, J @ R.T


def predict_point_jacobians_batch(
    R: np.ndarray, t: np.ndarray, landmarks: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`predict_point` for one pose and (k, 3) landmarks: z (k, 3), H_pose (k, 3, 6),
    H_landmark (k, 3, 3)."""
    p_body = (np.asarray(landmarks) - t) @ R  # rows: R^T (l - t)
    J = bearing_elevation_range_jacobian(p_body)
    dp_dpose = np.concatenate([skew(p_body), np.broadcast_to(-np.eye(3), J.shape)], axis=-1)
    return bearing_elevation_range(p_body), J @ dp_dpose, J @ R.T


def world_point_jacobian_pose(R: np.ndarray, p_body: np.ndarray) -> np.ndarray:
    """d(R p_body + t) / d(pose tangent), 3x6 (or (n, 3, 6) for (n, 3) points): where a
    measured point lands, moved by the pose."""
    p_body = np.asarray(p_body, dtype=float)
    identity = np.broadcast_to(np.eye(3), (*p_body.shape[:-1], 3, 3))
    return R @ np.concatenate([-skew(p_body), identity], axis=-1)


def world_point_covariance(R: np.ndarray, z: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """Covariance of the world position a point detection z = (bearing, elevation, range)
    gives from a pose of rotation R, its (b, e, r) `covariance` taken through the inverse
    measurement model to first order. Stacked: (n, 3) detections, (n, 3, 3) covariances."""
    G = R @ np.linalg.inv(bearing_elevation_range_jacobian(point_from_bearing_elevation_range(z)))
    return G @ covariance @ np.swapaxes(G, -1, -2)


def pose_residual_batch(
    R_x: np.ndarray,
    t_x: np.ndarray,
    R_l: np.ndarray,
    t_l: np.ndarray,
    R_z: np.ndarray,
    t_z: np.ndarray,
) -> np.ndarray:
    """Log(Z^-1 X^-1 L): how far the predicted relative pose is from the measured one."""
    R_rel = np.swapaxes(R_x, -1, -2) @ R_l
    t_rel = np.einsum("...ji,...j->...i", R_x, t_l - t_x)
    R_err = np.swapaxes(R_z, -1, -2) @ R_rel
    t_err = np.einsum("...ji,...j->...i", R_z, t_rel - t_z)
    return se3_log(R_err, t_err)


def pose_residual_jacobians(
    R_x: np.ndarray, t_x: np.ndarray, R_l: np.ndarray, t_l: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """First-order Jacobians of X^-1 L in the tangent of the relative pose: (H_x, H_l), for one
    pose X and one or (k,) landmarks L.

    The residual's own Log Jacobian is the identity at zero residual, which is where it is used
    (innovation covariance of an association), so it is left out.
    """
    R_rel = R_x.T @ R_l
    t_rel = (t_l - t_x) @ R_x  # rows: R_x^T (t_l - t_x)
    # (X Exp(d))^-1 L = Exp(-d) X^-1 L = (X^-1 L) Exp(-Ad(rel^-1) d)
    R_inv = np.swapaxes(R_rel, -1, -2)
    t_inv = -np.einsum("...ij,...j->...i", R_inv, t_rel)
    H_x = -adjoint(R_inv, t_inv)
    return H_x, np.broadcast_to(np.eye(6), H_x.shape).copy()
