"""A detection as the back-end uses it: its kind of landmark, its measurement vector and noise,
the factor it makes, and the landmark estimate it implies."""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from pipeline.backend import factors
from pipeline.backend.landmarks import LandmarkKind
from pipeline.backend.mixture import gaussian_log_normaliser
from pipeline.geometry import point_from_bearing_elevation_range, rotation_from_quaternion
from pipeline.log.messages import Detection


@dataclass(frozen=True)
class Measurement:
    pose_index: int
    detection_index: int  # position among the detections of its pose
    detection: Detection
    kind: LandmarkKind
    covariance: np.ndarray  # Gamma: 3x3 over (b, e, r), or 6x6 in Pose3 tangent order
    information: np.ndarray  # Gamma^-1
    log_normaliser: float  # 0.5 log det(2 pi Gamma)
    vector: np.ndarray  # (bearing, elevation, range)
    relative_rotation: np.ndarray | None = None  # of a pose measurement
    relative_translation: np.ndarray | None = None

    @property
    def dim(self) -> int:
        return self.covariance.shape[0]

    @property
    def body_point(self) -> np.ndarray:
        """Where the detection puts the landmark's position, in the body frame."""
        if self.kind is LandmarkKind.POSE:
            return self.relative_translation
        return point_from_bearing_elevation_range(self.vector)

    def factor(self, pose_key: int, landmark_key: int, information_scale: float = 1.0):
        if self.kind is LandmarkKind.POSE:
            return factors.pose_measurement_factor(
                pose_key, landmark_key, self.detection.relative_pose, information_scale
            )
        return factors.point_measurement_factor(
            pose_key, landmark_key, self.detection, information_scale, self.covariance
        )

    def initial_landmark(self, pose: gtsam.Pose3):
        """The landmark value this detection implies, seen from `pose` (a new landmark)."""
        if self.kind is LandmarkKind.POSE:
            rp = self.detection.relative_pose
            return pose.compose(factors.pose_from_message(rp.translation, rp.rotation))
        return pose.transformFrom(self.body_point)


def make_measurement(
    pose_index: int,
    detection_index: int,
    detection: Detection,
    use_relative_pose: bool,
    point_scale: np.ndarray | None = None,
) -> Measurement:
    """The detection as the back-end uses it. `point_scale` (D, diagonal) rescales a point
    measurement's covariance to D Gamma D: the noise scales the back-end estimated."""
    if use_relative_pose and detection.relative_pose is not None:
        kind = LandmarkKind.POSE
        covariance = np.reshape(detection.relative_pose.covariance, (6, 6))
    else:
        kind = LandmarkKind.POINT
        covariance = np.reshape(detection.covariance, (3, 3))
        if point_scale is not None:
            covariance = point_scale @ covariance @ point_scale
    covariance = 0.5 * (covariance + covariance.T)
    relative = detection.relative_pose if kind is LandmarkKind.POSE else None
    return Measurement(
        pose_index=pose_index,
        detection_index=detection_index,
        detection=detection,
        kind=kind,
        covariance=covariance,
        information=np.linalg.inv(covariance),
        log_normaliser=gaussian_log_normaliser(covariance),
        vector=np.array([detection.bearing, detection.elevation, detection.range]),
        relative_rotation=rotation_from_quaternion(relative.rotation) if relative else None,
        relative_translation=np.asarray(relative.translation, float) if relative else None,
    )
