"""The contract-v1 detection log: its messages, how they are read and checked, and written.

`limits` (the bounds), `codec` (one message <-> JSON), `metadata` (the `mmslam` record),
`mcap_stream` (the MCAP container, streamed), `validate` (the checks across messages),
`reader` (a whole log in memory), `writer` (a log on disk, all-or-nothing).
"""

from pipeline.log.messages import (
    CompressedImage,
    Detection,
    DetectionLog,
    Detections,
    GroundTruthLandmark,
    GroundTruthLandmarks,
    GroundTruthPose,
    LogMetadata,
    Odometry,
    RelativePose,
    StereoCalibration,
)
from pipeline.log.reader import read_log
from pipeline.log.writer import LogWriter

__all__ = [
    "CompressedImage",
    "Detection",
    "DetectionLog",
    "Detections",
    "GroundTruthLandmark",
    "GroundTruthLandmarks",
    "GroundTruthPose",
    "LogMetadata",
    "LogWriter",
    "Odometry",
    "RelativePose",
    "StereoCalibration",
    "read_log",
]
