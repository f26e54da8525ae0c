"""Topics, schema names and the JSON Schemas written into every log's MCAP channels."""

from __future__ import annotations

import json

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

_NUM = {"type": "number"}
_INT = {"type": "integer"}


def _array(n: int) -> dict:
    return {"type": "array", "items": _NUM, "minItems": n, "maxItems": n}


_RELATIVE_POSE = {
    "type": "object",
    "required": ["translation", "rotation", "covariance"],
    "properties": {"translation": _array(3), "rotation": _array(4), "covariance": _array(36)},
}

_DETECTION = {
    "type": "object",
    "required": [
        "class_id",
        "score",
        "bearing",
        "elevation",
        "range",
        "covariance",
        "source",
    ],
    "properties": {
        "class_id": _INT,
        "score": {"type": "number", "minimum": 0, "maximum": 1},
        "bearing": _NUM,
        "elevation": _NUM,
        "range": {"type": "number", "exclusiveMinimum": 0},
        "covariance": _array(9),
        "source": {"enum": ["apriltag", "bbox"]},
        "bbox": _array(4),
        "relative_pose": _RELATIVE_POSE,
        "truth_landmark_id": _INT,
    },
}

SCHEMAS: dict[str, tuple[str, dict]] = {
    ODOMETRY: (
        "mmslam.Odometry",
        {
            "type": "object",
            "required": [
                "stamp_ns",
                "from_index",
                "to_index",
                "translation",
                "rotation",
                "covariance",
            ],
            "properties": {
                "stamp_ns": _INT,
                "from_index": _INT,
                "to_index": _INT,
                "translation": _array(3),
                "rotation": _array(4),
                "covariance": _array(36),
            },
        },
    ),
    DETECTIONS: (
        "mmslam.Detections",
        {
            "type": "object",
            "required": ["stamp_ns", "pose_index", "detections"],
            "properties": {
                "stamp_ns": _INT,
                "pose_index": _INT,
                "detections": {"type": "array", "items": _DETECTION},
            },
        },
    ),
    GT_POSE: (
        "mmslam.GroundTruthPose",
        {
            "type": "object",
            "required": ["stamp_ns", "pose_index", "translation", "rotation"],
            "properties": {
                "stamp_ns": _INT,
                "pose_index": _INT,
                "translation": _array(3),
                "rotation": _array(4),
            },
        },
    ),
    GT_LANDMARKS: (
        "mmslam.GroundTruthLandmarks",
        {
            "type": "object",
            "required": ["stamp_ns", "landmarks"],
            "properties": {
                "stamp_ns": _INT,
                "landmarks": {
                    "type": "array",
                    "items": {
                        "type": "object",
                        "required": ["id", "class_id", "position"],
                        "properties": {"id": _INT, "class_id": _INT, "position": _array(3)},
                    },
                },
            },
        },
    ),
    CALIBRATION: (
        "mmslam.StereoCalibration",
        {
            "type": "object",
            "required": [
                "stamp_ns",
                "width",
                "height",
                "fx",
                "fy",
                "cx",
                "cy",
                "baseline",
                "body_from_camera",
            ],
            "properties": {
                "stamp_ns": _INT,
                "width": _INT,
                "height": _INT,
                "fx": _NUM,
                "fy": _NUM,
                "cx": _NUM,
                "cy": _NUM,
                "baseline": _NUM,
                "body_from_camera": _array(16),
            },
        },
    ),
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
