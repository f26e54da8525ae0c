"""Rigid-body math and the contract's point measurement: pure numpy, shared by every stage.

Conventions (GTSAM's, and ../shared/CONTRACT.md's): a pose maps its own frame to its parent's;
tangent vectors are ordered (rotation, translation) and perturb on the right, `T Exp(xi)`;
quaternions are [x, y, z, w]. A body-frame point is measured as (bearing, elevation, range).
Every function takes one item or a stack of them along leading axes.
"""

from __future__ import annotations

import numpy as np

# Below this angle the closed forms lose precision; their Taylor series take over.
_SMALL_ANGLE = 1e-4


def skew(v: np.ndarray) -> np.ndarray:
    """The matrix [v]x with [v]x w = v x w."""
    v = np.asarray(v, dtype=float)
    out = np.zeros((*v.shape[:-1], 3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def _exp_coefficients(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """sin(t)/t, (1 - cos t)/t^2 and (t - sin t)/t^3, safe at t = 0."""
    small = theta < _SMALL_ANGLE
    t = np.where(small, 1.0, theta)
    t2 = theta * theta
    a = np.where(small, 1.0 - t2 / 6.0, np.sin(t) / t)
    b = np.where(small, 0.5 - t2 / 24.0, (1.0 - np.cos(t)) / (t * t))
    c = np.where(small, 1.0 / 6.0 - t2 / 120.0, (t - np.sin(t)) / (t * t * t))
    return a, b, c


def so3_exp(omega: np.ndarray) -> np.ndarray:
    """Rotation vectors to rotation matrices (Rodrigues)."""
    omega = np.asarray(omega, dtype=float)
    a, b, _ = _exp_coefficients(np.linalg.norm(omega, axis=-1))
    w = skew(omega)
    return np.eye(3) + a[..., None, None] * w + b[..., None, None] * (w @ w)


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation matrices to rotation vectors, through the quaternion (stable near 0 and pi):
    the angle is 2 atan2(|v|, w) about v."""
    q = quaternion_from_rotation(R)
    v, w = q[..., :3], q[..., 3]
    n = np.linalg.norm(v, axis=-1)
    small = n < _SMALL_ANGLE * w  # w >= 0: small angles only
    w_small = np.where(small, w, 1.0)
    ratio = np.where(small, n, 0.0) / w_small
    # angle / |v|, with its series 2/w (1 - (|v|/w)^2 / 3) where |v| vanishes
    scale = np.where(
        small,
        2.0 / w_small * (1.0 - ratio * ratio / 3.0),
        2.0 * np.arctan2(n, w) / np.where(small, 1.0, n),
    )
    return v * scale[..., None]


def rotation_angle(R: np.ndarray) -> np.ndarray:
    """The angle of a rotation, in [0, pi]."""
    return np.linalg.norm(so3_log(R), axis=-1)


def se3_exp(xi: np.ndarray) -> np.ndarray:
    """Tangent vectors (rx, ry, rz, tx, ty, tz) to 4x4 poses, as GTSAM's Pose3.Expmap."""
    xi = np.asarray(xi, dtype=float)
    omega, v = xi[..., :3], xi[..., 3:]
    a, b, c = _exp_coefficients(np.linalg.norm(omega, axis=-1))
    w = skew(omega)
    w2 = w @ w
    left_jacobian = np.eye(3) + b[..., None, None] * w + c[..., None, None] * w2
    out = np.zeros((*xi.shape[:-1], 4, 4))
    out[..., :3, :3] = np.eye(3) + a[..., None, None] * w + b[..., None, None] * w2
    out[..., :3, 3] = np.einsum("...ij,...j->...i", left_jacobian, v)
    out[..., 3, 3] = 1.0
    return out


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


def invert_pose(T: np.ndarray) -> np.ndarray:
    """Inverse of 4x4 rigid transforms."""
    T = np.asarray(T, dtype=float)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    out = np.zeros_like(T)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def adjoint(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Adjoint of a pose in (rotation, translation) tangent order, 6x6:
    `T Exp(xi) T^-1 = Exp(Ad_T xi)`."""
    R = np.asarray(R, dtype=float)
    out = np.zeros((*R.shape[:-2], 6, 6))
    out[..., :3, :3] = R
    out[..., 3:, 3:] = R
    out[..., 3:, :3] = skew(t) @ R
    return out


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Points given in the frames of 4x4 poses `T` to the parent frame (broadcasting: one pose
    and many points, or one point for each pose)."""
    T = np.asarray(T, dtype=float)
    points = np.asarray(points, dtype=float)
    return np.einsum("...ij,...j->...i", T[..., :3, :3], points) + T[..., :3, 3]


def rotation_from_quaternion(q: np.ndarray) -> np.ndarray:
    """[x, y, z, w] (normalised first) to rotation matrices."""
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
    """Rotation matrices to [x, y, z, w] with w >= 0 (one of the two signs: canonical output).
    Each is read off the largest of 4x^2, 4y^2, 4z^2, 4w^2 (Shepperd's method: no division by
    a small number), then normalised."""
    R = np.asarray(R, dtype=float)
    m = R.reshape(-1, 3, 3)
    m00, m11, m22 = m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]
    # Sums and differences of the off-diagonal pairs: 4xy, 4xz, 4yz and 4wx, 4wy, 4wz.
    xy, xz, yz = m[:, 0, 1] + m[:, 1, 0], m[:, 0, 2] + m[:, 2, 0], m[:, 1, 2] + m[:, 2, 1]
    wx, wy, wz = m[:, 2, 1] - m[:, 1, 2], m[:, 0, 2] - m[:, 2, 0], m[:, 1, 0] - m[:, 0, 1]
    squares = np.stack(  # 4x^2, 4y^2, 4z^2, 4w^2
        [1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22, 1 + m00 + m11 + m22],
        axis=-1,
    )
    # Row k: 4 q_k times (x, y, z, w); any row divided by its own 4 q_k is the quaternion.
    rows = np.stack(
        [
            np.stack([squares[:, 0], xy, xz, wx], axis=-1),
            np.stack([xy, squares[:, 1], yz, wy], axis=-1),
            np.stack([xz, yz, squares[:, 2], wz], axis=-1),
            np.stack([wx, wy, wz, squares[:, 3]], axis=-1),
        ],
        axis=1,
    )
    q = rows[np.arange(len(m)), np.argmax(squares, axis=-1)]
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    q = np.where(q[:, 3:4] < 0.0, -q, q)
    return q.reshape(*R.shape[:-2], 4)


def bearing_elevation_range(p: np.ndarray) -> np.ndarray:
    """Body-frame points to (bearing, elevation, range)."""
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
    """d(bearing, elevation, range) / d(body point), 3x3."""
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
