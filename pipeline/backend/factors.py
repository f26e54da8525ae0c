"""GTSAM factors for odometry and detections (native C++ factors only: they are ~40x cheaper to
linearise than Python `CustomFactor`s, which is what keeps mixtures affordable; see
`pipeline/backend/hypotheses.py` for where the mixture's component is chosen instead)."""

from __future__ import annotations

import math

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


# How far behind the measured point the point factor's virtual stereo camera sits (m): its
# projection differs from a Cartesian residual by terms of order (offset from the measured
# point) / this, 1e-3 at 100 m, while its coordinates (about this large) keep 1e-11 m of
# resolution in double precision.
ORTHOGRAPHIC_DISTANCE_M = 1e5
# (u_left, u_right, v) of the far stereo camera, to first order, from the point's offset along
# (left, up, along): u_left and v move with the offset across the line of sight, u_right with
# the across and along offsets together (focal length and baseline both the distance).
_STEREO_FROM_OFFSET = np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
# Near the zenith a bearing spans almost nothing across the line of sight, and a detection's
# covariance would pin that direction to nothing: its span is taken as at least that of a
# bearing at 1.5 rad of elevation (86 degrees; straight up, every method's solver fell back).
MIN_BEARING_SPAN = math.cos(1.5)


def body_point_covariance(elevation: float, range_m: float, covariance: np.ndarray) -> np.ndarray:
    """Covariance of a detection's body-frame point along (left, up, along) its direction
    (`direction_frame`), from its (bearing, elevation, range) covariance to first order: the
    bearing's angle spans cos(elevation) * range metres across (at least MIN_BEARING_SPAN *
    range), the elevation's range metres up, the range's itself along."""
    span = max(math.cos(elevation), MIN_BEARING_SPAN)
    G = np.diag([span * range_m, range_m, 1.0])
    C = G @ np.asarray(covariance, dtype=float) @ G.T
    return 0.5 * (C + C.T)


def point_measurement_factor(
    pose_key: int,
    landmark_key: int,
    detection: Detection,
    information_scale: float = 1.0,
    covariance: np.ndarray | None = None,
) -> gtsam.GenericStereoFactor3D:
    """The detection as a Cartesian residual in the body frame: the landmark's position seen
    from the pose, R^T (l - t), against the detected point, weighed by the detection's
    (bearing, elevation, range) covariance (or `covariance`, a rescaled one) carried to the
    point to first order; `information_scale` < 1 weakens it (GPDA's weights).

    Why Cartesian: the residual is linear in the landmark and in the pose's translation, its
    Jacobian on the landmark is R^T, full rank wherever the estimate is. Measured as angles and
    range, or through a projection, a landmark a loop closure's first step puts behind the
    sensor (a pose moved 2 m beside a tag seen at 1.8 m) gives a Jacobian that vanishes or
    turns, and Gauss-Newton steps from there diverged (indoor-tags, noise x6, seed 2: the
    error 600 -> 6e7 at the closure, iSAM2 refusing the graph eight updates later). The
    covariance is the detection's, whole, in a frame fixed by the measurement (not by the
    estimate), so an anisotropic noise (a planar sensor's elevation) keeps its axes.

    How: GTSAM's Python API wraps no pose-to-point factor, so the residual is a stereo factor
    in its orthographic limit, native and fast: a stereo camera of focal length and baseline
    `ORTHOGRAPHIC_DISTANCE_M`, that far behind the detected point and looking along it, sees
    the point's offset across the line of sight in u_left and v and the offset along it in
    u_right - u_left, in metres (to a relative 1e-3 at 100 m)."""
    if covariance is None:
        covariance = np.reshape(detection.covariance, (3, 3))
    offset = body_point_covariance(detection.elevation, detection.range, covariance)
    stereo = _STEREO_FROM_OFFSET @ offset @ _STEREO_FROM_OFFSET.T
    noise = gtsam.noiseModel.Gaussian.Covariance(0.5 * (stereo + stereo.T) / information_scale)
    d = ORTHOGRAPHIC_DISTANCE_M
    camera = gtsam.Cal3_S2Stereo(d, d, 0.0, 0.0, 0.0, d)
    frame = direction_frame(detection.bearing, detection.elevation)
    point = detection.range * frame[:, 2]
    sensor = gtsam.Pose3(gtsam.Rot3(frame), point - d * frame[:, 2])
    measured = gtsam.StereoPoint2(0.0, -d, 0.0)
    return gtsam.GenericStereoFactor3D(measured, noise, pose_key, landmark_key, camera, sensor)


def pose_measurement_factor(
    pose_key: int, landmark_key: int, relative_pose: RelativePose, information_scale: float = 1.0
) -> gtsam.BetweenFactorPose3:
    """6-DoF landmark factor from a tag's relative pose."""
    covariance = np.reshape(relative_pose.covariance, (6, 6)) / information_scale
    noise = gtsam.noiseModel.Gaussian.Covariance(covariance)
    measured = pose_from_message(relative_pose.translation, relative_pose.rotation)
    return gtsam.BetweenFactorPose3(pose_key, landmark_key, measured, noise)
