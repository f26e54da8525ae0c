"""Topics, schema names and the JSON Schemas written into every log's MCAP channels: the
contract's from the messages' declarations (`messages.py`), Foxglove's image schema as
Foxglove writes it."""

from __future__ import annotations

import json

import msgspec

from pipeline.log.messages import (
    Detections,
    GroundTruthLandmarks,
    GroundTruthPose,
    Odometry,
    StereoCalibration,
)

ODOMETRY = "/odometry"
DETECTIONS = "/detections"
GT_POSE = "/ground_truth/pose"
GT_LANDMARKS = "/ground_truth/landmarks"
CALIBRATION = "/calibration"
LEFT_IMAGE = "/camera/left/compressed"
RIGHT_IMAGE = "/camera/right/compressed"
IMAGE_TOPICS = (LEFT_IMAGE, RIGHT_IMAGE)
# Foxglove's well-known messages (protobuf) that writers add beside the contract's topics
# (pipeline/foxglove/log_topics.py): the log as Foxglove shows it; readers skip them.
FOXGLOVE_PREFIX = "/foxglove/"

# The contract's topics: schema name and the message each carries (`messages.py`).
MESSAGES: dict[str, tuple[str, type]] = {
    topic: (f"mmslam.{cls.__name__}", cls)
    for topic, cls in (
        (ODOMETRY, Odometry),
        (DETECTIONS, Detections),
        (GT_POSE, GroundTruthPose),
        (GT_LANDMARKS, GroundTruthLandmarks),
        (CALIBRATION, StereoCalibration),
    )
}
# Topic -> (schema name, JSON Schema): the contract's made from their declarations.
SCHEMAS: dict[str, tuple[str, dict]] = {
    topic: (name, msgspec.json.schema(cls)) for topic, (name, cls) in MESSAGES.items()
}

# Foxglove's own schema, so that image topics open in Foxglove and Rerun as they are.
_COMPRESSED_IMAGE = {
    "title": "foxglove.CompressedImage",
    "type": "object",
    "properties": {
        "timestamp": {
            "type": "object",
            "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}},
        },
        "frame_id": {"type": "string"},
        "data": {"type": "string", "contentEncoding": "base64"},
        "format": {"type": "string"},
    },
}
for _topic in IMAGE_TOPICS:
    SCHEMAS[_topic] = ("foxglove.CompressedImage", _COMPRESSED_IMAGE)


def schema_bytes(topic: str) -> bytes:
    """The JSON Schema of a topic, as written into the MCAP schema record."""
    return json.dumps(SCHEMAS[topic][1], sort_keys=True, separators=(",", ":")).encode()
