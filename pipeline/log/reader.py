"""Reading a whole log: the container (`mcap_stream.py`) through the contract's checks
(`validate.py`) into a `DetectionLog`. Raises `LogError` naming the topic and the message
position (0-based, within its topic) of the first problem."""

from __future__ import annotations

import os
from collections import Counter

from pipeline.errors import LogError
from pipeline.log import schemas
from pipeline.log.mcap_stream import McapFile
from pipeline.log.messages import METADATA_NAME, DetectionLog, LogMetadata
from pipeline.log.metadata import find_record, parse_metadata
from pipeline.log.validate import LogValidator


def log_metadata(mcap: McapFile) -> LogMetadata:
    """The file's one `mmslam` metadata record, checked."""
    try:
        record = find_record(mcap.metadata)
    except ValueError as exc:
        raise LogError(mcap.path, str(exc)) from None
    try:
        return parse_metadata(record)
    except ValueError as exc:
        raise LogError(mcap.path, str(exc), f"metadata '{METADATA_NAME}'") from None


def read_log(path: str | os.PathLike, load_images: bool = False) -> DetectionLog:
    """Read and validate a whole log; images are checked, and kept only if `load_images`."""
    with McapFile(path) as mcap:
        metadata = log_metadata(mcap)
        validator = LogValidator(mcap.path, metadata)
        log = DetectionLog(metadata=metadata, odometry=[], detections=[])
        image_counts: Counter[str] = Counter()
        for channel, index, log_time, data in mcap.messages():
            msg = validator.message(channel, index, log_time, data)
            topic = channel.topic
            if msg is None:
                continue
            if topic == schemas.ODOMETRY:
                log.odometry.append(msg)
            elif topic == schemas.DETECTIONS:
                log.detections.append(msg)
            elif topic == schemas.GT_POSE:
                log.ground_truth_poses.append(msg)
            elif topic == schemas.GT_LANDMARKS:
                log.ground_truth_landmarks = msg
            elif topic == schemas.CALIBRATION:
                log.calibration = msg
            else:
                image_counts[topic] += 1
                if load_images:
                    log.images.setdefault(topic, []).append(msg)
        validator.finish(mcap.channels.values())
    log.ground_truth_poses.sort(key=lambda m: m.pose_index)
    log.image_counts = dict(image_counts)
    return log
