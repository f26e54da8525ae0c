"""Measurement models and their Jacobians, as pure numpy functions.

Conventions (GTSAM's): a pose is (R, t) mapping body to world; tangent vectors are ordered
(rotation, translation) and perturb on the right, T * Exp(xi). A point landmark is measured as
bearing, elevation and range of its position in the body frame (../shared/CONTRACT.md); a pose
landmark as its pose relative to the body, with residual Log(Z^-1 * X^-1 * L).

Functions ending in `_batch` take stacked arrays (leading dimension N) and avoid Python loops.
"""

from __future__ import annotations

import numpy as np

_SMALL_ANGLE = 1e-8


def skew(v: np.ndarray) -> np.ndarray:
    """The matrix [v]x with [v]x w = v x w; works on (3,) or (N, 3)."""
    v = np.asarray(v, dtype=float)
    out = np.zeros((*v.shape[:-1], 3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def rotation_from_quaternion(q: np.ndarray) -> np.ndarray:
    """[x, y, z, w] to a rotation matrix; (4,) or (N, 4)."""
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    out = np.empty((*q.shape[:-1], 3, 3))
    out[..., 0, 0] = 1 - 2 * (y * y + z * z)
    out[..., 0, 1] = 2 * (x * y - z * w)
    out[..., 0, 2] = 2 * (x * z + y * w)
    out[..., 1, 0] = 2 * (x * y + z * w)
    out[..., 1, 1] = 1 - 2 * (x * x + z * z)
    out[..., 1, 2] = 2 * (y * z - x * w)
    out[..., 2, 0] = 2 * (x * z - y * w)
    out[..., 2, 1] = 2 * (y * z + x * w)
    out[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return out


def quaternion_from_rotation(R: np.ndarray) -> np.ndarray:
    """A rotation matrix to [x, y, z, w] with w >= 0 (one matrix)."""
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(np.asarray(R, dtype=float)).as_quat()
    return q if q[3] >= 0 else -q


def bearing_elevation_range(p: np.ndarray) -> np.ndarray:
    """Body-frame point(s) to (bearing, elevation, range)."""
    p = np.asarray(p, dtype=float)
    horizontal = np.hypot(p[..., 0], p[..., 1])
    return np.stack(
        [
            np.arctan2(p[..., 1], p[..., 0]),
            np.arctan2(p[..., 2], horizontal),
            np.linalg.norm(p, axis=-1),
        ],
        axis=-1,
    )


def point_from_bearing_elevation_range(z: np.ndarray) -> np.ndarray:
    """(bearing, elevation, range) to the body-frame point; inverse of the above."""
    z = np.asarray(z, dtype=float)
    b, e, r = z[..., 0], z[..., 1], z[..., 2]
    return np.stack([r * np.cos(e) * np.cos(b), r * np.cos(e) * np.sin(b), r * np.sin(e)], axis=-1)


def bearing_elevation_range_jacobian(p: np.ndarray) -> np.ndarray:
    """d(bearing, elevation, range) / d(body point), 3x3 (or N x 3 x 3)."""
    p = np.asarray(p, dtype=float)
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    rho2 = x * x + y * y
    rho = np.sqrt(rho2)
    r2 = rho2 + z * z
    r = np.sqrt(r2)
    J = np.zeros((*p.shape[:-1], 3, 3))
    J[..., 0, 0], J[..., 0, 1] = -y / rho2, x / rho2
    J[..., 1, 0] = -x * z / (rho * r2)
    J[..., 1, 1] = -y * z / (rho * r2)
    J[..., 1, 2] = rho / r2
    J[..., 2, 0], J[..., 2, 1], J[..., 2, 2] = x / r, y / r, z / r
    return J


def wrap_angle(a: np.ndarray) -> np.ndarray:
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


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
    """d(R p_body + t) / d(pose tangent), 3x6: where a measured point lands, moved by the pose."""
    return R @ np.hstack([-skew(p_body), np.eye(3)])


# ---- SO(3) and SE(3) ----


def so3_exp(w: np.ndarray) -> np.ndarray:
    """Rodrigues; (3,) or (N, 3) to rotation matrices."""
    w = np.asarray(w, dtype=float)
    theta = np.linalg.norm(w, axis=-1)[..., None, None]
    K = skew(w)
    small = theta < _SMALL_ANGLE
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0, np.sin(safe) / safe)
    b = np.where(small, 0.5, (1 - np.cos(safe)) / safe**2)
    return np.eye(3) + a * K + b * (K @ K)


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation matrices to rotation vectors (stable near 0 and pi)."""
    from scipy.spatial.transform import Rotation

    R = np.asarray(R, dtype=float)
    flat = R.reshape(-1, 3, 3)
    return Rotation.from_matrix(flat).as_rotvec().reshape(*R.shape[:-2], 3)


def so3_left_jacobian_inverse(w: np.ndarray) -> np.ndarray:
    """V^-1 of SE(3)'s log: maps translation to the tangent's translation part."""
    w = np.asarray(w, dtype=float)
    theta = np.linalg.norm(w, axis=-1)[..., None, None]
    K = skew(w)
    small = theta < 1e-5
    safe = np.where(small, 1.0, theta)
    coeff = np.where(
        small,
        1.0 / 12.0,
        (1.0 - safe * np.sin(safe) / (2.0 * (1.0 - np.cos(safe)))) / safe**2,
    )
    return np.eye(3) - 0.5 * K + coeff * (K @ K)


def se3_log(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """SE(3) Log as GTSAM's Pose3::Logmap: (rotation vector, V^-1 t)."""
    w = so3_log(R)
    v = np.einsum("...ij,...j->...i", so3_left_jacobian_inverse(w), t)
    return np.concatenate([w, v], axis=-1)


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


def adjoint(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Adjoint of a pose (or (k,) poses) in (rotation, translation) tangent order, 6x6."""
    R = np.asarray(R, dtype=float)
    out = np.zeros((*R.shape[:-2], 6, 6))
    out[..., :3, :3] = R
    out[..., 3:, 3:] = R
    out[..., 3:, :3] = skew(t) @ R
    return out


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
