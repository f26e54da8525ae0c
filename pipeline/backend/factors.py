"""GTSAM factors for odometry and detections (native C++ factors only: they are ~40x cheaper to
linearise than Python `CustomFactor`s, which is what keeps mixtures affordable; see
`pipeline/backend/hypotheses.py` for where the mixture's component is chosen instead)."""

from __future__ import annotations

import gtsam
import numpy as np

from pipeline.geometry import rotation_from_quaternion
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
    """(bearing, elevation, range) covariance in the error coordinates of GTSAM's bearing-range
    factor: the 2-D tangent plane of the direction, then range.

    GTSAM expresses the direction error in the tangent basis of the *predicted* direction, and
    `Unit3`'s basis turns abruptly where two components of the direction swap magnitude. So
    only a direction noise that is the same in every tangent direction weighs errors the same
    wherever the estimate is: the tangent block is made isotropic with its larger variance (a
    little less information than the detection carries, never more), and the direction-range
    correlation is left out.
    """
    # On the unit sphere a bearing change moves the direction by cos(elevation) times as much.
    scale = np.diag([np.cos(elevation), 1.0])
    angular = np.asarray(covariance, dtype=float)[:2, :2]
    variance = float(np.linalg.eigvalsh(scale @ angular @ scale)[-1])
    return np.diag([variance, variance, float(covariance[2, 2])])


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
