"""Vectorised rigid-body math for the scenario generators (pure numpy, no I/O).

Poses are 4x4 homogeneous matrices, stacked along the first axis. Tangent vectors follow
GTSAM's Pose3 order `(rx, ry, rz, tx, ty, tz)`, so `pose @ se3_exp(xi)` is GTSAM's
`pose.compose(Pose3.Expmap(xi))`: a perturbation in the frame of `pose` itself.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

# Below this angle the closed forms lose precision; their Taylor series take over.
_SMALL_ANGLE = 1e-4


def skew(v: np.ndarray) -> np.ndarray:
    """(N, 3) vectors to (N, 3, 3) cross-product matrices."""
    v = np.asarray(v, dtype=float)
    out = np.zeros((*v.shape[:-1], 3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def _exp_coefficients(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """sin(t)/t, (1-cos t)/t^2 and (t - sin t)/t^3, safe at t = 0."""
    small = theta < _SMALL_ANGLE
    t = np.where(small, 1.0, theta)
    t2 = theta * theta
    a = np.where(small, 1.0 - t2 / 6.0, np.sin(t) / t)
    b = np.where(small, 0.5 - t2 / 24.0, (1.0 - np.cos(t)) / (t * t))
    c = np.where(small, 1.0 / 6.0 - t2 / 120.0, (t - np.sin(t)) / (t * t * t))
    return a, b, c


def so3_exp(omega: np.ndarray) -> np.ndarray:
    """(N, 3) rotation vectors to (N, 3, 3) rotation matrices (Rodrigues)."""
    omega = np.asarray(omega, dtype=float)
    theta = np.linalg.norm(omega, axis=-1)
    a, b, _ = _exp_coefficients(theta)
    w = skew(omega)
    return np.eye(3) + a[..., None, None] * w + b[..., None, None] * (w @ w)


def se3_exp(xi: np.ndarray) -> np.ndarray:
    """(N, 6) tangent vectors `(rx, ry, rz, tx, ty, tz)` to (N, 4, 4) poses, as GTSAM's Expmap."""
    xi = np.asarray(xi, dtype=float)
    omega, v = xi[..., :3], xi[..., 3:]
    theta = np.linalg.norm(omega, axis=-1)
    a, b, c = _exp_coefficients(theta)
    w = skew(omega)
    w2 = w @ w
    rotation = np.eye(3) + a[..., None, None] * w + b[..., None, None] * w2
    left_jacobian = np.eye(3) + b[..., None, None] * w + c[..., None, None] * w2
    out = np.zeros((*xi.shape[:-1], 4, 4))
    out[..., :3, :3] = rotation
    out[..., :3, 3] = np.einsum("...ij,...j->...i", left_jacobian, v)
    out[..., 3, 3] = 1.0
    return out


def inverse(poses: np.ndarray) -> np.ndarray:
    """Inverse of (..., 4, 4) rigid transforms."""
    poses = np.asarray(poses, dtype=float)
    rt = np.swapaxes(poses[..., :3, :3], -1, -2)
    out = np.zeros_like(poses)
    out[..., :3, :3] = rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", rt, poses[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def relative_poses(poses: np.ndarray) -> np.ndarray:
    """The (N-1) motions `inv(T_k) @ T_{k+1}` of a pose sequence."""
    return inverse(poses[:-1]) @ poses[1:]


def pose_from_rotation_translation(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    out = np.zeros((*np.shape(translation)[:-1], 4, 4))
    out[..., :3, :3] = rotation
    out[..., :3, 3] = translation
    out[..., 3, 3] = 1.0
    return out


def orthonormalise(poses: np.ndarray) -> np.ndarray:
    """The nearest proper rotations (SVD) in (N, 4, 4) poses, e.g. read from 7-digit text."""
    u, _, vt = np.linalg.svd(poses[..., :3, :3])
    d = np.sign(np.linalg.det(u @ vt))
    u[..., :, 2] *= d[..., None]
    out = np.array(poses, dtype=float)
    out[..., :3, :3] = u @ vt
    return out


def yaw_rotation(yaw: np.ndarray) -> np.ndarray:
    """(N,) angles to (N, 3, 3) rotations about z."""
    yaw = np.asarray(yaw, dtype=float)
    c, s = np.cos(yaw), np.sin(yaw)
    out = np.zeros((*yaw.shape, 3, 3))
    out[..., 0, 0], out[..., 0, 1] = c, -s
    out[..., 1, 0], out[..., 1, 1] = s, c
    out[..., 2, 2] = 1.0
    return out


def rotation_to_quaternion(rotation: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotations to (N, 4) unit quaternions `[x, y, z, w]` with `w >= 0`."""
    rotation = np.asarray(rotation, dtype=float).reshape(-1, 3, 3)
    q = Rotation.from_matrix(rotation).as_quat()
    return np.where(q[:, 3:4] < 0.0, -q, q)  # one of the two signs, so output is canonical


def transform_points(poses: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Points given in the frames of `poses` to the parent frame (broadcasting)."""
    return np.einsum("...ij,...j->...i", poses[..., :3, :3], points) + poses[..., :3, 3]


def bearing_elevation_range(points: np.ndarray) -> np.ndarray:
    """Body-frame points (..., 3) to the contract's `(bearing, elevation, range)` (..., 3)."""
    x, y, z = points[..., 0], points[..., 1], points[..., 2]
    return np.stack(
        [np.arctan2(y, x), np.arctan2(z, np.hypot(x, y)), np.linalg.norm(points, axis=-1)],
        axis=-1,
    )


def point_from_bearing_elevation_range(measurement: np.ndarray) -> np.ndarray:
    """The inverse of `bearing_elevation_range`."""
    b, e, r = measurement[..., 0], measurement[..., 1], measurement[..., 2]
    return np.stack([r * np.cos(e) * np.cos(b), r * np.cos(e) * np.sin(b), r * np.sin(e)], axis=-1)


def path_length(positions: np.ndarray) -> float:
    """Length of the polyline through (N, 3) positions."""
    return float(np.linalg.norm(np.diff(positions, axis=0), axis=-1).sum())
