"""Vectorised rigid-body math for the scenario generators (pure numpy, no I/O).

Poses are 4x4 homogeneous matrices, stacked along the first axis. Tangent vectors follow
GTSAM's Pose3 order `(rx, ry, rz, tx, ty, tz)`, so `pose @ se3_exp(xi)` is GTSAM's
`pose.compose(Pose3.Expmap(xi))`: a perturbation in the frame of `pose` itself.
"""

from __future__ import annotations

import numpy as np

from pipeline.geometry import (  # noqa: F401 - the shared math, re-exported for the scenarios
    bearing_elevation_range,
    invert_pose,
    point_from_bearing_elevation_range,
    quaternion_from_rotation,
    se3_exp,
    so3_exp,
)

inverse = invert_pose


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


def path_length(positions: np.ndarray) -> float:
    """Length of the polyline through (N, 3) positions."""
    return float(np.linalg.norm(np.diff(positions, axis=0), axis=-1).sum())


def inside_any(points: np.ndarray, rectangles: np.ndarray) -> np.ndarray:
    """(..., 2) points inside any of the (K, 4) rectangles [x_min, y_min, x_max, y_max]."""
    p = points[..., None, :]
    return (
        (p[..., 0] >= rectangles[:, 0])
        & (p[..., 0] <= rectangles[:, 2])
        & (p[..., 1] >= rectangles[:, 1])
        & (p[..., 1] <= rectangles[:, 3])
    ).any(axis=-1)
