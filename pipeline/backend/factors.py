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


def odometry_factor(
    from_key: int, to_key: int, odometry: Odometry, covariance: np.ndarray | None = None
) -> gtsam.BetweenFactorPose3:
    """The odometry as a between factor, with its covariance (or `covariance`, rescaled)."""
    if covariance is None:
        covariance = np.reshape(odometry.covariance, (6, 6))
    noise = gtsam.noiseModel.Gaussian.Covariance(covariance)
    return gtsam.BetweenFactorPose3(
        from_key, to_key, pose_from_message(odometry.translation, odometry.rotation), noise
    )


def direction_frame(bearing: float, elevation: float) -> np.ndarray:
    """Rotation whose columns are (left, up, along) the direction of (bearing, elevation):
    the frame of a virtual camera looking along the detection."""
    cb, sb, ce, se = np.cos(bearing), np.sin(bearing), np.cos(elevation), np.sin(elevation)
    along = np.array([ce * cb, ce * sb, se])
    left = np.array([-sb, cb, 0.0])
    up = np.array([-se * cb, -se * sb, ce])
    return np.column_stack([left, up, along])


def virtual_stereo_covariance(
    elevation: float, range_m: float, covariance: np.ndarray
) -> np.ndarray:
    """Covariance of (u_left, u_right, v) of a virtual stereo camera (focal length 1, baseline
    `range_m`, looking along the detection) for a (bearing, elevation, range) covariance.

    At the detection u_left = v = 0 and u_right = -1. To first order, u_left moves by the
    angle along `left` (cos(elevation) times the bearing's), v by the elevation's, and
    u_right = u_left + range_change / range: the same Gaussian, correlations included, in
    coordinates whose frame does not depend on the estimate."""
    J = np.array(
        [
            [np.cos(elevation), 0.0, 0.0],
            [np.cos(elevation), 0.0, 1.0 / range_m],
            [0.0, 1.0, 0.0],
        ]
    )
    C = J @ np.asarray(covariance, dtype=float) @ J.T
    return 0.5 * (C + C.T)


def point_measurement_factor(
    pose_key: int,
    landmark_key: int,
    detection: Detection,
    information_scale: float = 1.0,
    covariance: np.ndarray | None = None,
) -> gtsam.GenericStereoFactor3D:
    """Bearing/elevation/range as a virtual stereo measurement; `information_scale` < 1 weakens
    it (GPDA's weights).

    GTSAM's bearing-range factor measures the direction error in the tangent basis of the
    *predicted* direction (Unit3), which turns abruptly where two of its components swap
    magnitude: a direction noise that is not the same in every tangent direction (a planar
    sensor's elevation, far tighter than its bearing) would be weighed in the wrong axes there.
    A stereo camera looking along the measured direction has a fixed frame instead, so the
    detection's covariance (or `covariance`, a rescaled one), anisotropic and correlated, is
    kept whole."""
    if covariance is None:
        covariance = np.reshape(detection.covariance, (3, 3))
    mapped = virtual_stereo_covariance(detection.elevation, detection.range, covariance)
    noise = gtsam.noiseModel.Gaussian.Covariance(mapped / information_scale)
    camera = gtsam.Cal3_S2Stereo(1.0, 1.0, 0.0, 0.0, 0.0, detection.range)
    frame = gtsam.Pose3(
        gtsam.Rot3(direction_frame(detection.bearing, detection.elevation)), np.zeros(3)
    )
    measured = gtsam.StereoPoint2(0.0, -1.0, 0.0)
    return gtsam.GenericStereoFactor3D(measured, noise, pose_key, landmark_key, camera, frame)


def pose_measurement_factor(
    pose_key: int, landmark_key: int, relative_pose: RelativePose, information_scale: float = 1.0
) -> gtsam.BetweenFactorPose3:
    """6-DoF landmark factor from a tag's relative pose."""
    covariance = np.reshape(relative_pose.covariance, (6, 6)) / information_scale
    noise = gtsam.noiseModel.Gaussian.Covariance(covariance)
    measured = pose_from_message(relative_pose.translation, relative_pose.rotation)
    return gtsam.BetweenFactorPose3(pose_key, landmark_key, measured, noise)
