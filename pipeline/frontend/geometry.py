"""Camera and pose math shared by the front-end stages: pure functions on numpy arrays.

Conventions (../shared/CONTRACT.md): the camera optical frame is x right, y down, z forward; the
body frame is x forward, y left, z up, and `BODY_FROM_CAMERA` maps one to the other. Pose
perturbations are on the right, `T_true = T @ Exp(xi)`, with `xi = (rx, ry, rz, tx, ty, tz)` as in
GTSAM's Pose3, so a covariance over `xi` is what a log's 6x6 covariances hold.

A rectified stereo pixel is `(u, v, d)`: left-image column and row and the disparity
`d = u_left - u_right`, all in pixels.
"""

from __future__ import annotations

import numpy as np

from pipeline.datasets.camera import BODY_FROM_CAMERA, StereoIntrinsics
from pipeline.geometry import (  # noqa: F401 - the shared math, re-exported for the stages
    adjoint,
    bearing_elevation_range,
    bearing_elevation_range_jacobian,
    invert_pose,
    point_from_bearing_elevation_range,
    quaternion_from_rotation,
    rotation_angle,
    rotation_from_quaternion,
    se3_exp,
    skew,
    so3_exp,
    so3_log,
)

BODY_FROM_CAMERA_ROTATION = BODY_FROM_CAMERA[:3, :3]


# --- rotations and poses ---------------------------------------------------------------------


def pose_adjoint(pose: np.ndarray) -> np.ndarray:
    """The 6x6 adjoint of a 4x4 pose in tangent order (rotation, translation):
    `pose @ Exp(xi) @ inverse(pose) == Exp(adjoint @ xi)`."""
    return adjoint(pose[:3, :3], pose[:3, 3])


def conjugate_pose(frame_from_old: np.ndarray, pose: np.ndarray, covariance: np.ndarray):
    """A relative pose and its covariance seen in another frame: `A @ T @ inverse(A)`.

    With `T_true = T @ Exp(xi)`, `A T_true A^-1 = (A T A^-1) @ Exp(Ad_A xi)`, so the covariance
    becomes `Ad_A @ covariance @ Ad_A^T`. Used to turn camera motion into body motion.
    """
    adjoint = pose_adjoint(frame_from_old)
    new_pose = frame_from_old @ pose @ invert_pose(frame_from_old)
    return new_pose, adjoint @ covariance @ adjoint.T


# --- the stereo camera -----------------------------------------------------------------------


def stereo_pixel_covariance(pixel_sigma: float) -> np.ndarray:
    """Covariance of `(u, v, d)` when the left and right columns and the row each have noise
    `pixel_sigma`: `d = u_left - u_right` shares the left column's noise."""
    return pixel_sigma**2 * np.array([[1.0, 0.0, 1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 2.0]])


def triangulate(uvd: np.ndarray, intrinsics: StereoIntrinsics) -> np.ndarray:
    """Camera-frame points of stereo pixels `(..., 3)` -> `(..., 3)`."""
    uvd = np.asarray(uvd, float)
    u, v, d = uvd[..., 0], uvd[..., 1], uvd[..., 2]
    z = intrinsics.fx * intrinsics.baseline / d
    x = (u - intrinsics.cx) * z / intrinsics.fx
    y = (v - intrinsics.cy) * z / intrinsics.fy
    return np.stack([x, y, z], axis=-1)


def triangulation_jacobian(uvd: np.ndarray, intrinsics: StereoIntrinsics) -> np.ndarray:
    """d(point)/d(u, v, d) of `triangulate`, `(..., 3)` -> `(..., 3, 3)`."""
    uvd = np.asarray(uvd, float)
    points = triangulate(uvd, intrinsics)
    d = uvd[..., 2]
    b = intrinsics.baseline
    jacobian = np.zeros((*uvd.shape[:-1], 3, 3))
    jacobian[..., 0, 0] = b / d
    jacobian[..., 1, 1] = intrinsics.fx * b / (intrinsics.fy * d)
    jacobian[..., :, 2] = -points / d[..., None]
    return jacobian


def project(points: np.ndarray, intrinsics: StereoIntrinsics) -> np.ndarray:
    """Left-image pixels of camera-frame points `(..., 3)` -> `(..., 2)`."""
    points = np.asarray(points, float)
    z = points[..., 2]
    u = intrinsics.fx * points[..., 0] / z + intrinsics.cx
    v = intrinsics.fy * points[..., 1] / z + intrinsics.cy
    return np.stack([u, v], axis=-1)


def projection_jacobian(points: np.ndarray, intrinsics: StereoIntrinsics) -> np.ndarray:
    """d(pixel)/d(point) of `project`, `(..., 3)` -> `(..., 2, 3)`."""
    points = np.asarray(points, float)
    x, y, z = points[..., 0], points[..., 1], points[..., 2]
    jacobian = np.zeros((*points.shape[:-1], 2, 3))
    jacobian[..., 0, 0] = intrinsics.fx / z
    jacobian[..., 0, 2] = -intrinsics.fx * x / z**2
    jacobian[..., 1, 1] = intrinsics.fy / z
    jacobian[..., 1, 2] = -intrinsics.fy * y / z**2
    return jacobian


def right_camera_points(points: np.ndarray, intrinsics: StereoIntrinsics) -> np.ndarray:
    """Left-camera points in the right camera's frame (a pure shift along x by the baseline)."""
    return np.asarray(points, float) - np.array([intrinsics.baseline, 0.0, 0.0])


# --- point measurements ----------------------------------------------------------------------


def stereo_point_measurement(
    uvd: np.ndarray, uvd_covariance: np.ndarray, intrinsics: StereoIntrinsics
) -> tuple[np.ndarray, np.ndarray]:
    """(bearing, elevation, range) in the body frame, and its 3x3 covariance, of one stereo
    pixel with covariance `uvd_covariance` (first-order propagation)."""
    point_camera = triangulate(uvd, intrinsics)
    point_body = BODY_FROM_CAMERA_ROTATION @ point_camera
    jacobian = (
        bearing_elevation_range_jacobian(point_body)
        @ BODY_FROM_CAMERA_ROTATION
        @ triangulation_jacobian(uvd, intrinsics)
    )
    covariance = jacobian @ uvd_covariance @ jacobian.T
    return bearing_elevation_range(point_body), 0.5 * (covariance + covariance.T)


def camera_point_measurement(
    point_camera: np.ndarray, covariance_camera: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(bearing, elevation, range) in the body frame, and its 3x3 covariance, of a point and
    its covariance in the camera frame."""
    point_body = BODY_FROM_CAMERA_ROTATION @ np.asarray(point_camera, float)
    jacobian = bearing_elevation_range_jacobian(point_body) @ BODY_FROM_CAMERA_ROTATION
    covariance = jacobian @ np.asarray(covariance_camera, float) @ jacobian.T
    return bearing_elevation_range(point_body), 0.5 * (covariance + covariance.T)


def camera_to_body_motion(
    camera_motion: np.ndarray, camera_covariance: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The motion of the body between two frames, from that of the camera (and covariance)."""
    return conjugate_pose(BODY_FROM_CAMERA, camera_motion, camera_covariance)
