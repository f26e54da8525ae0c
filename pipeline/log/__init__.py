"""The contract-v1 detection log: messages, and the one module that reads and writes them."""

from pipeline.log.mcap_io import LogWriter, RawLog, decode_log, read_log, scan_log
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
    "RawLog",
    "RelativePose",
    "StereoCalibration",
    "decode_log",
    "read_log",
    "scan_log",
]
