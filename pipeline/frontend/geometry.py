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

from pipeline.datasets.kitti import BODY_FROM_CAMERA, StereoIntrinsics

BODY_FROM_CAMERA_ROTATION = BODY_FROM_CAMERA[:3, :3]


# --- rotations and poses ---------------------------------------------------------------------


def skew(v: np.ndarray) -> np.ndarray:
    """The cross-product matrix: `skew(a) @ b == cross(a, b)`."""
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def so3_exp(omega: np.ndarray) -> np.ndarray:
    """Rodrigues' formula: the rotation of angle |omega| about omega."""
    theta = float(np.linalg.norm(omega))
    k = skew(omega)
    if theta < 1e-8:
        return np.eye(3) + k + 0.5 * k @ k
    return np.eye(3) + np.sin(theta) / theta * k + (1.0 - np.cos(theta)) / theta**2 * k @ k


def so3_log(rotation: np.ndarray) -> np.ndarray:
    """The rotation vector of a rotation matrix (angle in [0, pi])."""
    cos_theta = np.clip((np.trace(rotation) - 1.0) / 2.0, -1.0, 1.0)
    theta = float(np.arccos(cos_theta))
    w = np.array(
        [
            rotation[2, 1] - rotation[1, 2],
            rotation[0, 2] - rotation[2, 0],
            rotation[1, 0] - rotation[0, 1],
        ]
    )
    if theta < 1e-6:
        return 0.5 * w
    if np.pi - theta < 1e-4:
        # Near pi the antisymmetric part vanishes: take the axis from the symmetric part.
        m = (rotation + np.eye(3)) / 2.0
        axis = m[int(np.argmax(np.diag(m)))]
        axis = axis / np.linalg.norm(axis)
        if axis @ w < 0:
            axis = -axis
        return theta * axis
    return theta / (2.0 * np.sin(theta)) * w


def se3_exp(xi: np.ndarray) -> np.ndarray:
    """Exp of a tangent vector `(rx, ry, rz, tx, ty, tz)` (GTSAM's Pose3.Expmap) as a 4x4."""
    omega, v = np.asarray(xi[:3], float), np.asarray(xi[3:], float)
    theta = float(np.linalg.norm(omega))
    k = skew(omega)
    if theta < 1e-8:
        left_jacobian = np.eye(3) + 0.5 * k
    else:
        left_jacobian = (
            np.eye(3)
            + (1.0 - np.cos(theta)) / theta**2 * k
            + (theta - np.sin(theta)) / theta**3 * k @ k
        )
    pose = np.eye(4)
    pose[:3, :3] = so3_exp(omega)
    pose[:3, 3] = left_jacobian @ v
    return pose


def invert_pose(pose: np.ndarray) -> np.ndarray:
    inverse = np.eye(4)
    inverse[:3, :3] = pose[:3, :3].T
    inverse[:3, 3] = -pose[:3, :3].T @ pose[:3, 3]
    return inverse


def pose_adjoint(pose: np.ndarray) -> np.ndarray:
    """The 6x6 adjoint of a pose in tangent order (rotation, translation):
    `pose @ Exp(xi) @ inverse(pose) == Exp(adjoint @ xi)`."""
    rotation, translation = pose[:3, :3], pose[:3, 3]
    adjoint = np.zeros((6, 6))
    adjoint[:3, :3] = rotation
    adjoint[3:, 3:] = rotation
    adjoint[3:, :3] = skew(translation) @ rotation
    return adjoint


def conjugate_pose(frame_from_old: np.ndarray, pose: np.ndarray, covariance: np.ndarray):
    """A relative pose and its covariance seen in another frame: `A @ T @ inverse(A)`.

    With `T_true = T @ Exp(xi)`, `A T_true A^-1 = (A T A^-1) @ Exp(Ad_A xi)`, so the covariance
    becomes `Ad_A @ covariance @ Ad_A^T`. Used to turn camera motion into body motion.
    """
    adjoint = pose_adjoint(frame_from_old)
    new_pose = frame_from_old @ pose @ invert_pose(frame_from_old)
    return new_pose, adjoint @ covariance @ adjoint.T


def quaternion_from_rotation(rotation: np.ndarray) -> tuple[float, float, float, float]:
    """Unit quaternion `[x, y, z, w]` with w >= 0 (Shepperd's method: stable for any angle)."""
    r = rotation
    trace = np.trace(r)
    if trace > 0:
        s = 2.0 * np.sqrt(1.0 + trace)
        q = [(r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s, 0.25 * s]
    elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
        s = 2.0 * np.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
        q = [0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s, (r[2, 1] - r[1, 2]) / s]
    elif r[1, 1] > r[2, 2]:
        s = 2.0 * np.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2])
        q = [(r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s, (r[0, 2] - r[2, 0]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1])
        q = [(r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s, (r[1, 0] - r[0, 1]) / s]
    quaternion = np.array(q)
    quaternion /= np.linalg.norm(quaternion)
    if quaternion[3] < 0:
        quaternion = -quaternion
    return tuple(float(v) for v in quaternion)  # type: ignore[return-value]


def rotation_from_quaternion(quaternion: np.ndarray) -> np.ndarray:
    """The rotation matrix of a quaternion `[x, y, z, w]` (normalised first)."""
    x, y, z, w = np.asarray(quaternion, float) / np.linalg.norm(quaternion)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def rotation_angle(rotation: np.ndarray) -> float:
    return float(np.arccos(np.clip((np.trace(rotation) - 1.0) / 2.0, -1.0, 1.0)))


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


def bearing_elevation_range(point: np.ndarray) -> np.ndarray:
    """The contract's point measurement of a body-frame point `(..., 3)` -> `(..., 3)`."""
    point = np.asarray(point, float)
    x, y, z = point[..., 0], point[..., 1], point[..., 2]
    return np.stack(
        [np.arctan2(y, x), np.arctan2(z, np.hypot(x, y)), np.linalg.norm(point, axis=-1)],
        axis=-1,
    )


def bearing_elevation_range_jacobian(point: np.ndarray) -> np.ndarray:
    """d(bearing, elevation, range)/d(point) of one body-frame point: a 3x3."""
    x, y, z = np.asarray(point, float)
    rho2 = x * x + y * y
    rho = np.sqrt(rho2)
    r2 = rho2 + z * z
    r = np.sqrt(r2)
    return np.array(
        [
            [-y / rho2, x / rho2, 0.0],
            [-z * x / (r2 * rho), -z * y / (r2 * rho), rho / r2],
            [x / r, y / r, z / r],
        ]
    )


def point_from_bearing_elevation_range(measurement: np.ndarray) -> np.ndarray:
    bearing, elevation, rng = measurement
    return rng * np.array(
        [
            np.cos(elevation) * np.cos(bearing),
            np.cos(elevation) * np.sin(bearing),
            np.sin(elevation),
        ]
    )


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
