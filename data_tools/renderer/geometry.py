"""Pure camera and plane math for the renderer: numpy in, numpy out, no I/O.

Camera frames follow KITTI/OpenCV (x right, y down, z forward); pixel `(u, v)` is the centre of
the pixel in column `u`, row `v`, so a point at `(X, Y, Z)` lands at `u = fx X / Z + cx`.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from pipeline.geometry import invert_pose


def pixel_ray_coordinates(
    size: int, focal: float, centre: float, supersample: int = 1
) -> np.ndarray:
    """Normalised ray coordinate `(u - c) / f` of each sub-pixel centre along one image axis.

    With `supersample = k`, pixel `u` is split into `k` sub-pixels whose centres lie at
    `u - 1/2 + (j + 1/2) / k`; the result has `size * k` entries in image order.
    """
    index = np.arange(size * supersample, dtype=np.float64)
    coordinate = (index + 0.5) / supersample - 0.5
    return (coordinate - centre) / focal


def project_points(points_camera: np.ndarray, camera_matrix: np.ndarray) -> np.ndarray:
    """Pixel coordinates `(N, 2)` of camera-frame points `(N, 3)`; NaN for points at Z <= 0."""
    points = np.atleast_2d(np.asarray(points_camera, dtype=np.float64))
    z = points[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = camera_matrix[0, 0] * points[:, 0] / z + camera_matrix[0, 2]
        v = camera_matrix[1, 1] * points[:, 1] / z + camera_matrix[1, 2]
    pixels = np.stack([u, v], axis=1)
    pixels[z <= 0] = np.nan
    return pixels


def ray_plane_depth(
    ray_x: np.ndarray, ray_y: np.ndarray, plane_point: np.ndarray, plane_normal: np.ndarray
) -> np.ndarray:
    """Depth Z at which the rays `(x, y, 1)` from the camera centre meet a plane.

    Rays are given by their normalised coordinates (broadcastable arrays). A ray parallel to the
    plane gives +-inf; a plane behind the camera gives a negative depth.
    """
    n = np.asarray(plane_normal, dtype=np.float64)
    numerator = float(n @ np.asarray(plane_point, dtype=np.float64))
    denominator = n[0] * ray_x + n[1] * ray_y + n[2]
    with np.errstate(divide="ignore", invalid="ignore"):
        return numerator / denominator


invert_transform = invert_pose


def make_transform(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    transform = np.eye(4)
    transform[:3, :3] = rotation
    transform[:3, 3] = translation
    return transform


def rotation_from_yaw_pitch_roll(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """World-from-body rotation of a z-up body: yaw about z, then pitch about y, roll about x."""
    return Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix()


def clip_polygon_near(vertices: np.ndarray, near: float) -> np.ndarray:
    """Clip a convex camera-frame polygon `(N, 3)` to the half-space `z >= near`.

    Sutherland-Hodgman against one plane; returns the clipped vertices (possibly none).
    """
    kept: list[np.ndarray] = []
    count = len(vertices)
    for i in range(count):
        current, following = vertices[i], vertices[(i + 1) % count]
        current_in, following_in = current[2] >= near, following[2] >= near
        if current_in:
            kept.append(current)
        if current_in != following_in:
            fraction = (near - current[2]) / (following[2] - current[2])
            kept.append(current + fraction * (following - current))
    return np.array(kept).reshape(-1, 3)
