"""GTSAM factors for odometry and detections (native C++ factors only: they are ~40x cheaper to
linearise than Python `CustomFactor`s, which is what keeps mixtures affordable; see
`pipeline/backend/hypotheses.py` for where the mixture's component is chosen instead)."""

from __future__ import annotations

import gtsam
import numpy as np

from pipeline.backend.geometry import rotation_from_quaternion
from pipeline.log.messages import Detection, Odometry, RelativePose


def pose_from_message(translation, rotation) -> gtsam.Pose3:
    """Contract translation [3] and quaternion [x, y, z, w] to a gtsam Pose3."""
    return gtsam.Pose3(
        gtsam.Rot3(rotation_from_quaternion(rotation)), np.asarray(translation, float)
    )


def odometry_factor(from_key: int, to_key: int, odometry: Odometry) -> gtsam.BetweenFactorPose3:
    noise = gtsam.noiseModel.Gaussian.Covariance(np.reshape(odometry.covariance, (6, 6)))
    return gtsam.BetweenFactorPose3(
        from_key, to_key, pose_from_message(odometry.translation, odometry.rotation), noise
    )


def bearing_elevation_to_direction(bearing: float, elevation: float) -> np.ndarray:
    ce = np.cos(elevation)
    return np.array([ce * np.cos(bearing), ce * np.sin(bearing), np.sin(elevation)])


def unit3_range_covariance(bearing: float, elevation: float, covariance: np.ndarray) -> np.ndarray:
    """(bearing, elevation, range) covariance to GTSAM's bearing-range error coordinates.

    GTSAM's `BearingRangeFactor3D` measures the direction as a Unit3 whose error lives in the 2-D
    tangent basis B of the measured direction: e = B^T (d_predicted - d_measured) to first order.
    The direction's derivative by (bearing, elevation) maps our angles into that basis.
    """
    sb, cb = np.sin(bearing), np.cos(bearing)
    se, ce = np.sin(elevation), np.cos(elevation)
    d_direction = np.array([[-ce * sb, -se * cb], [ce * cb, -se * sb], [0.0, ce]])
    basis = gtsam.Unit3(bearing_elevation_to_direction(bearing, elevation)).basis()
    J = np.zeros((3, 3))
    J[:2, :2] = basis.T @ d_direction
    J[2, 2] = 1.0
    out = J @ covariance @ J.T
    return 0.5 * (out + out.T)


def point_measurement_factor(
    pose_key: int, landmark_key: int, detection: Detection, information_scale: float = 1.0
) -> gtsam.BearingRangeFactor3D:
    """Bearing/elevation/range factor; `information_scale` < 1 weakens it (GPDA's weights)."""
    covariance = np.reshape(detection.covariance, (3, 3))
    mapped = unit3_range_covariance(detection.bearing, detection.elevation, covariance)
    noise = gtsam.noiseModel.Gaussian.Covariance(mapped / information_scale)
    direction = gtsam.Unit3(bearing_elevation_to_direction(detection.bearing, detection.elevation))
    return gtsam.BearingRangeFactor3D(pose_key, landmark_key, direction, detection.range, noise)


def pose_measurement_factor(
    pose_key: int, landmark_key: int, relative_pose: RelativePose, information_scale: float = 1.0
) -> gtsam.BetweenFactorPose3:
    """6-DoF landmark factor from a tag's relative pose."""
    covariance = np.reshape(relative_pose.covariance, (6, 6)) / information_scale
    noise = gtsam.noiseModel.Gaussian.Covariance(covariance)
    measured = pose_from_message(relative_pose.translation, relative_pose.rotation)
    return gtsam.BetweenFactorPose3(pose_key, landmark_key, measured, noise)
