"""JSON <-> message dataclasses, with every check the contract asks of a reader.

`decode_*` functions raise `ValueError` with a short reason; the reader adds the topic and the
message position. `encode_*` functions give the JSON dict that `decode_*` reads back.
"""

from __future__ import annotations

import base64
import math
from typing import Any

import numpy as np

from pipeline.log.messages import (
    CompressedImage,
    Detection,
    Detections,
    GroundTruthLandmark,
    GroundTruthLandmarks,
    GroundTruthPose,
    Odometry,
    RelativePose,
    StereoCalibration,
)

SOURCES = ("apriltag", "bbox")
QUATERNION_NORM_TOLERANCE = 1e-3


def _field(obj: dict, name: str, where: str = "") -> Any:
    if name not in obj:
        raise ValueError(f"missing field '{where}{name}'")
    return obj[name]


def _integer(obj: dict, name: str, where: str = "", minimum: int | None = None) -> int:
    value = _field(obj, name, where)
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"'{where}{name}' must be an integer, got {value!r}")
    if minimum is not None and value < minimum:
        raise ValueError(f"'{where}{name}' must be >= {minimum}, got {value}")
    return value


def _number(obj: dict, name: str, where: str = "") -> float:
    value = _field(obj, name, where)
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"'{where}{name}' must be a number, got {value!r}")
    if not math.isfinite(value):
        raise ValueError(f"'{where}{name}' is not finite ({value})")
    return float(value)


def _numbers(obj: dict, name: str, length: int, where: str = "") -> tuple[float, ...]:
    value = _field(obj, name, where)
    if not isinstance(value, list) or len(value) != length:
        raise ValueError(f"'{where}{name}' must be a list of {length} numbers")
    for item in value:
        if isinstance(item, bool) or not isinstance(item, int | float):
            raise ValueError(f"'{where}{name}' must hold only numbers, got {item!r}")
        if not math.isfinite(item):
            raise ValueError(f"'{where}{name}' holds a non-finite number ({item})")
    return tuple(float(v) for v in value)


def _quaternion(obj: dict, name: str, where: str = "") -> tuple[float, float, float, float]:
    q = _numbers(obj, name, 4, where)
    norm = math.sqrt(sum(v * v for v in q))
    if abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
        raise ValueError(f"'{where}{name}' is not a unit quaternion (norm {norm:.6g})")
    return q  # type: ignore[return-value]


def _covariance(obj: dict, name: str, dim: int, where: str = "") -> tuple[float, ...]:
    values = _numbers(obj, name, dim * dim, where)
    matrix = np.asarray(values).reshape(dim, dim)
    if not np.allclose(matrix, matrix.T, rtol=1e-6, atol=1e-12):
        raise ValueError(f"'{where}{name}' is not symmetric")
    try:
        np.linalg.cholesky(matrix)
    except np.linalg.LinAlgError:
        raise ValueError(f"'{where}{name}' is not positive definite") from None
    return values


def _stamp(obj: dict) -> int:
    return _integer(obj, "stamp_ns", minimum=0)


def decode_odometry(obj: dict) -> Odometry:
    return Odometry(
        stamp_ns=_stamp(obj),
        from_index=_integer(obj, "from_index", minimum=0),
        to_index=_integer(obj, "to_index", minimum=0),
        translation=_numbers(obj, "translation", 3),  # type: ignore[arg-type]
        rotation=_quaternion(obj, "rotation"),
        covariance=_covariance(obj, "covariance", 6),
    )


def encode_odometry(msg: Odometry) -> dict:
    return {
        "stamp_ns": msg.stamp_ns,
        "from_index": msg.from_index,
        "to_index": msg.to_index,
        "translation": list(msg.translation),
        "rotation": list(msg.rotation),
        "covariance": list(msg.covariance),
    }


def _decode_relative_pose(obj: Any, where: str) -> RelativePose:
    if not isinstance(obj, dict):
        raise ValueError(f"'{where}' must be an object")
    where = where + "."
    return RelativePose(
        translation=_numbers(obj, "translation", 3, where),  # type: ignore[arg-type]
        rotation=_quaternion(obj, "rotation", where),
        covariance=_covariance(obj, "covariance", 6, where),
    )


def decode_detection(obj: Any, num_classes: int, where: str = "") -> Detection:
    if not isinstance(obj, dict):
        raise ValueError(f"'{where}' must be an object")
    where = where + "."
    class_id = _integer(obj, "class_id", where)
    if not 0 <= class_id < num_classes:
        raise ValueError(f"'{where}class_id' {class_id} is outside 0..{num_classes - 1}")
    score = _number(obj, "score", where)
    if not 0.0 <= score <= 1.0:
        raise ValueError(f"'{where}score' {score} is outside 0..1")
    rng = _number(obj, "range", where)
    if rng <= 0.0:
        raise ValueError(f"'{where}range' must be positive, got {rng}")
    source = _field(obj, "source", where)
    if source not in SOURCES:
        raise ValueError(f"'{where}source' must be one of {list(SOURCES)}, got {source!r}")
    bbox = None
    if obj.get("bbox") is not None:
        bbox = _numbers(obj, "bbox", 4, where)
        if bbox[0] > bbox[2] or bbox[1] > bbox[3]:
            raise ValueError(f"'{where}bbox' must be [u_min, v_min, u_max, v_max]")
    relative_pose = None
    if obj.get("relative_pose") is not None:
        relative_pose = _decode_relative_pose(obj["relative_pose"], where + "relative_pose")
    truth = None
    if obj.get("truth_landmark_id") is not None:
        truth = _integer(obj, "truth_landmark_id", where, minimum=-1)
    return Detection(
        class_id=class_id,
        score=score,
        bearing=_number(obj, "bearing", where),
        elevation=_number(obj, "elevation", where),
        range=rng,
        covariance=_covariance(obj, "covariance", 3, where),
        source=source,
        bbox=bbox,  # type: ignore[arg-type]
        relative_pose=relative_pose,
        truth_landmark_id=truth,
    )


def encode_detection(det: Detection) -> dict:
    obj: dict[str, Any] = {
        "class_id": det.class_id,
        "score": det.score,
        "bearing": det.bearing,
        "elevation": det.elevation,
        "range": det.range,
        "covariance": list(det.covariance),
        "source": det.source,
    }
    if det.bbox is not None:
        obj["bbox"] = list(det.bbox)
    if det.relative_pose is not None:
        rp = det.relative_pose
        obj["relative_pose"] = {
            "translation": list(rp.translation),
            "rotation": list(rp.rotation),
            "covariance": list(rp.covariance),
        }
    if det.truth_landmark_id is not None:
        obj["truth_landmark_id"] = det.truth_landmark_id
    return obj


def decode_detections(obj: dict, num_classes: int) -> Detections:
    items = _field(obj, "detections")
    if not isinstance(items, list):
        raise ValueError("'detections' must be a list")
    return Detections(
        stamp_ns=_stamp(obj),
        pose_index=_integer(obj, "pose_index", minimum=0),
        detections=tuple(
            decode_detection(item, num_classes, f"detections[{k}]") for k, item in enumerate(items)
        ),
    )


def encode_detections(msg: Detections) -> dict:
    return {
        "stamp_ns": msg.stamp_ns,
        "pose_index": msg.pose_index,
        "detections": [encode_detection(d) for d in msg.detections],
    }


def decode_ground_truth_pose(obj: dict) -> GroundTruthPose:
    return GroundTruthPose(
        stamp_ns=_stamp(obj),
        pose_index=_integer(obj, "pose_index", minimum=0),
        translation=_numbers(obj, "translation", 3),  # type: ignore[arg-type]
        rotation=_quaternion(obj, "rotation"),
    )


def encode_ground_truth_pose(msg: GroundTruthPose) -> dict:
    return {
        "stamp_ns": msg.stamp_ns,
        "pose_index": msg.pose_index,
        "translation": list(msg.translation),
        "rotation": list(msg.rotation),
    }


def decode_ground_truth_landmarks(obj: dict, num_classes: int) -> GroundTruthLandmarks:
    items = _field(obj, "landmarks")
    if not isinstance(items, list):
        raise ValueError("'landmarks' must be a list")
    landmarks = []
    for k, item in enumerate(items):
        where = f"landmarks[{k}]."
        if not isinstance(item, dict):
            raise ValueError(f"'landmarks[{k}]' must be an object")
        class_id = _integer(item, "class_id", where)
        if not 0 <= class_id < num_classes:
            raise ValueError(f"'{where}class_id' {class_id} is outside 0..{num_classes - 1}")
        landmarks.append(
            GroundTruthLandmark(
                id=_integer(item, "id", where, minimum=0),
                class_id=class_id,
                position=_numbers(item, "position", 3, where),  # type: ignore[arg-type]
            )
        )
    return GroundTruthLandmarks(stamp_ns=_stamp(obj), landmarks=tuple(landmarks))


def encode_ground_truth_landmarks(msg: GroundTruthLandmarks) -> dict:
    return {
        "stamp_ns": msg.stamp_ns,
        "landmarks": [
            {"id": lm.id, "class_id": lm.class_id, "position": list(lm.position)}
            for lm in msg.landmarks
        ],
    }


def decode_calibration(obj: dict) -> StereoCalibration:
    calib = StereoCalibration(
        stamp_ns=_stamp(obj),
        width=_integer(obj, "width", minimum=1),
        height=_integer(obj, "height", minimum=1),
        fx=_number(obj, "fx"),
        fy=_number(obj, "fy"),
        cx=_number(obj, "cx"),
        cy=_number(obj, "cy"),
        baseline=_number(obj, "baseline"),
        body_from_camera=_numbers(obj, "body_from_camera", 16),
    )
    if calib.fx <= 0 or calib.fy <= 0 or calib.baseline <= 0:
        raise ValueError("'fx', 'fy' and 'baseline' must be positive")
    return calib


def encode_calibration(msg: StereoCalibration) -> dict:
    return {
        "stamp_ns": msg.stamp_ns,
        "width": msg.width,
        "height": msg.height,
        "fx": msg.fx,
        "fy": msg.fy,
        "cx": msg.cx,
        "cy": msg.cy,
        "baseline": msg.baseline,
        "body_from_camera": list(msg.body_from_camera),
    }


def decode_compressed_image(obj: dict) -> CompressedImage:
    stamp = _field(obj, "timestamp")
    if not isinstance(stamp, dict):
        raise ValueError("'timestamp' must be an object {sec, nsec}")
    sec = _integer(stamp, "sec", "timestamp.", minimum=0)
    nsec = _integer(stamp, "nsec", "timestamp.", minimum=0)
    data = _field(obj, "data")
    if not isinstance(data, str):
        raise ValueError("'data' must be a base64 string")
    try:
        raw = base64.b64decode(data, validate=True)
    except ValueError:
        raise ValueError("'data' is not valid base64") from None
    return CompressedImage(
        stamp_ns=sec * 1_000_000_000 + nsec,
        frame_id=str(obj.get("frame_id", "")),
        format=str(_field(obj, "format")),
        data=raw,
    )


def encode_compressed_image(msg: CompressedImage) -> dict:
    return {
        "timestamp": {"sec": msg.stamp_ns // 1_000_000_000, "nsec": msg.stamp_ns % 1_000_000_000},
        "frame_id": msg.frame_id,
        "data": base64.b64encode(msg.data).decode("ascii"),
        "format": msg.format,
    }
