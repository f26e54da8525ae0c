"""A detection log's content as Foxglove messages, written beside the contract's topics as the
log is written: `LogWriter(path, metadata, mirror=foxglove_mirror)` calls `LogMirror.write`
for every message.

- `/foxglove/tf` (FrameTransform): `world` to `body` per pose (odometry, dead-reckoned);
  `body` to `camera_left` once, from the calibration;
- `/foxglove/odometry`, `/foxglove/ground_truth/pose` (PoseInFrame): per pose;
- `/foxglove/odometry/path`, `/foxglove/ground_truth/path` (PosesInFrame): the whole paths, at
  the first stamp;
- `/foxglove/ground_truth/landmarks` (SceneUpdate): a sphere per true landmark, by class;
- `/foxglove/detections` (SceneUpdate): each keyframe's detections, in the body frame;
- `/foxglove/camera/left/annotations` (ImageAnnotations): the boxes of tags and objects, with
  class and score, stamped as the left image;
- `/foxglove/camera/left/calibration` (CameraCalibration): logs with a calibration.
"""

from __future__ import annotations

from typing import Any

import foxglove.messages as fg
import numpy as np
from mcap.writer import Writer

from pipeline.foxglove import messages as fm
from pipeline.foxglove.channels import FoxgloveChannels
from pipeline.geometry import point_from_bearing_elevation_range, rotation_from_quaternion
from pipeline.log.messages import (
    Detections,
    GroundTruthLandmarks,
    GroundTruthPose,
    LogMetadata,
    Odometry,
    StereoCalibration,
)

TF = "/foxglove/tf"
ODOMETRY = "/foxglove/odometry"
ODOMETRY_PATH = "/foxglove/odometry/path"
TRUTH_POSE = "/foxglove/ground_truth/pose"
TRUTH_PATH = "/foxglove/ground_truth/path"
TRUTH_LANDMARKS = "/foxglove/ground_truth/landmarks"
DETECTIONS = "/foxglove/detections"
ANNOTATIONS = "/foxglove/camera/left/annotations"
CALIBRATION = "/foxglove/camera/left/calibration"


def matrix(translation: Any, rotation: Any) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = rotation_from_quaternion(np.asarray(rotation, float))
    T[:3, 3] = translation
    return T


class LogMirror:
    """Turns the contract's messages, in the order a log is written, into Foxglove messages."""

    def __init__(self, channels: FoxgloveChannels, metadata: LogMetadata):
        self.out = channels
        self.class_names = metadata.class_names
        self.world_from_body = np.eye(4)  # the last pose odometry reached
        self.first_stamp: int | None = None
        self.odometry_path: list[fg.Pose] = []
        self.truth_path: list[fg.Pose] = []

    def _started(self, stamp_ns: int) -> None:
        """Pose 0, the origin, at the log's first stamp."""
        if self.first_stamp is None:
            self.first_stamp = stamp_ns
            self._odometry_pose(stamp_ns)

    def _odometry_pose(self, stamp_ns: int) -> None:
        self.out.write(
            TF, stamp_ns, fm.frame_transform(stamp_ns, fm.WORLD, fm.BODY, self.world_from_body)
        )
        value = fm.pose_of_matrix(self.world_from_body)
        self.out.write(ODOMETRY, stamp_ns, fm.pose_in_frame(stamp_ns, value))
        self.odometry_path.append(value)

    def write(self, msg: Any) -> None:
        stamp = msg.stamp_ns
        self._started(stamp)
        if isinstance(msg, Odometry):
            self.world_from_body = self.world_from_body @ matrix(msg.translation, msg.rotation)
            self._odometry_pose(stamp)
        elif isinstance(msg, GroundTruthPose):
            value = fm.pose(msg.translation, msg.rotation)
            self.out.write(TRUTH_POSE, stamp, fm.pose_in_frame(stamp, value))
            self.truth_path.append(value)
        elif isinstance(msg, GroundTruthLandmarks):
            rows = [
                (
                    lm.id,
                    lm.position,
                    lm.class_id,
                    f"{lm.id} {fm.class_name(self.class_names, lm.class_id)}",
                )
                for lm in msg.landmarks
            ]
            self.out.write(TRUTH_LANDMARKS, stamp, fm.landmark_update(stamp, rows, "truth"))
        elif isinstance(msg, StereoCalibration):
            self.out.write(CALIBRATION, stamp, fm.camera_calibration(msg))
            body_from_camera = np.reshape(np.asarray(msg.body_from_camera, float), (4, 4))
            if np.linalg.det(body_from_camera[:3, :3]) > 0:  # else no rotation: no frame to show
                transform = fm.frame_transform(stamp, fm.BODY, fm.CAMERA, body_from_camera)
                self.out.write(TF, stamp, transform)
        elif isinstance(msg, Detections):
            self._detections(msg)

    def _detections(self, msg: Detections) -> None:
        stamp = msg.stamp_ns
        points = [
            point_from_bearing_elevation_range(np.array([d.bearing, d.elevation, d.range]))
            for d in msg.detections
        ]
        classes = [d.class_id for d in msg.detections]
        self.out.write(DETECTIONS, stamp, fm.detection_update(stamp, points, classes))
        if any(d.bbox is not None for d in msg.detections):
            annotations = fm.image_annotations(stamp, msg.detections, self.class_names)
            self.out.write(ANNOTATIONS, stamp, annotations)

    def _name(self, class_id: int) -> str:
        return (
            self.class_names[class_id] if 0 <= class_id < len(self.class_names) else str(class_id)
        )

    def finish(self) -> None:
        """The whole paths, at the first stamp, so that they show from the start."""
        if self.first_stamp is None:
            return
        stamp = self.first_stamp
        self.out.write(ODOMETRY_PATH, stamp, fm.poses_in_frame(stamp, self.odometry_path))
        if self.truth_path:
            self.out.write(TRUTH_PATH, stamp, fm.poses_in_frame(stamp, self.truth_path))


def foxglove_mirror(writer: Writer, metadata: LogMetadata) -> LogMirror:
    """The mirror a `LogWriter` is given to write Foxglove's messages into its file."""
    return LogMirror(FoxgloveChannels(writer), metadata)
