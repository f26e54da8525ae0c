"""JSON <-> message dataclasses, with every check the contract and `limits.py` ask of a message.

`decode_*` functions raise `ValueError` with a short reason; the reader adds the topic and the
message position. `encode_*` functions give the JSON dict that `decode_*` reads back.
"""

from __future__ import annotations

import base64
import binascii
import functools
import json
import math
from typing import Any

import numpy as np

from pipeline.log import limits
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
SHOWN_CHARS = 40  # of a bad value in a message: a log's 10 MB string must not make a 10 MB line


def shown(value: Any) -> str:
    """A bad value, as an error message shows it: its repr, cut short."""
    text = repr(value)
    return text if len(text) <= SHOWN_CHARS else text[: SHOWN_CHARS - 3] + "..."


class _NonFiniteError(ValueError):
    pass


def _reject_constant(name: str) -> float:
    raise _NonFiniteError(f"non-finite number {name} in JSON")


def parse_json(data: bytes | str) -> Any:
    """JSON text to Python values; raises ValueError with a one-line reason (NaN, Infinity,
    nesting deeper than Python's recursion allows, and integers of thousands of digits are
    refused here)."""
    try:
        return json.loads(data, parse_constant=_reject_constant)
    except _NonFiniteError:
        raise
    except json.JSONDecodeError as exc:
        raise ValueError(f"malformed JSON ({exc.msg})") from None
    except RecursionError:
        raise ValueError("JSON nested too deeply") from None
    except UnicodeDecodeError:
        raise ValueError("JSON is not UTF-8") from None
    except ValueError as exc:  # Python's limit on the digits of an integer
        raise ValueError(f"malformed JSON ({str(exc).split(':')[0]})") from None


def _field(obj: dict, name: str, where: str = "") -> Any:
    if name not in obj:
        raise ValueError(f"missing field '{where}{name}'")
    return obj[name]


def _integer(obj: dict, name: str, where: str = "", low: int = 0, high: int | None = None) -> int:
    value = _field(obj, name, where)
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"'{where}{name}' must be an integer, got {shown(value)}")
    if value < low or (high is not None and value > high):
        bound = f"{low}..{high}" if high is not None else f">= {low}"
        raise ValueError(f"'{where}{name}' must be {bound}, got {shown(value)}")
    return value


def _as_float(value: Any, label: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"'{label}' must hold only numbers, got {shown(value)}")
    try:
        number = float(value)
    except OverflowError:  # an integer of hundreds of digits
        raise ValueError(f"'{label}' holds a number too large for a float") from None
    if not math.isfinite(number):
        raise ValueError(f"'{label}' holds a non-finite number ({number})")
    return number


def _number(
    obj: dict,
    name: str,
    where: str = "",
    low: float = -math.inf,
    high: float = math.inf,
    positive: bool = False,
) -> float:
    """A finite number in [low, high], or in (0, high] if `positive`."""
    value = _as_float(_field(obj, name, where), where + name)
    if positive and not 0.0 < value <= high:
        raise ValueError(f"'{where}{name}' is {value:.6g}, outside (0, {high:.6g}]")
    if not low <= value <= high:
        raise ValueError(f"'{where}{name}' is {value:.6g}, outside [{low:.6g}, {high:.6g}]")
    return value


def _numbers(
    obj: dict, name: str, length: int, where: str = "", bound: float = math.inf
) -> tuple[float, ...]:
    """`length` finite numbers, each of magnitude at most `bound`."""
    value = _field(obj, name, where)
    if not isinstance(value, list) or len(value) != length:
        raise ValueError(f"'{where}{name}' must be a list of {length} numbers")
    numbers = tuple(_as_float(v, where + name) for v in value)
    largest = max(abs(v) for v in numbers)
    if largest > bound:
        raise ValueError(f"'{where}{name}' holds {largest:.6g}, beyond the bound {bound:.6g}")
    return numbers


def _vector(obj: dict, name: str, where: str, high: float, low: float = 0.0) -> tuple[float, ...]:
    """Three numbers whose Euclidean norm lies in [low, high]."""
    values = _numbers(obj, name, 3, where)
    norm = math.sqrt(sum(v * v for v in values))
    if not low <= norm <= high:
        raise ValueError(f"'{where}{name}' has length {norm:.6g}, outside [{low:.6g}, {high:.6g}]")
    return values


def _quaternion(obj: dict, name: str, where: str = "") -> tuple[float, float, float, float]:
    q = _numbers(obj, name, 4, where)
    norm = math.sqrt(sum(v * v for v in q))
    if abs(norm - 1.0) > limits.QUATERNION_NORM_TOLERANCE:
        raise ValueError(f"'{where}{name}' is not a unit quaternion (norm {norm:.6g})")
    return q  # type: ignore[return-value]


# Logs repeat a covariance (a calibrated model) message after message: check each once.
@functools.lru_cache(maxsize=4096)
def covariance_problem(values: tuple[float, ...], dim: int) -> str | None:
    """Why `values` (dim x dim, row-major) is not a covariance the back-end can use, or None."""
    matrix = np.asarray(values).reshape(dim, dim)
    if not np.allclose(matrix, matrix.T, rtol=1e-6, atol=1e-12):
        return "is not symmetric"
    eigenvalues = np.linalg.eigvalsh(matrix)
    if eigenvalues[0] <= 0.0:
        return "is not positive definite"
    variances = np.diag(matrix)
    low, high = limits.MIN_VARIANCE, limits.MAX_VARIANCE
    if np.any(variances < low) or np.any(variances > high):
        worst = variances[np.argmax((variances < low) | (variances > high))]
        return f"has a variance {worst:.3g} outside [{low:g}, {high:g}]"
    condition = eigenvalues[-1] / eigenvalues[0]
    if condition > limits.MAX_CONDITION:
        return f"has condition number {condition:.3g}, above {limits.MAX_CONDITION:g}"
    return None


@functools.lru_cache(maxsize=4096)
def _shared(values: tuple[float, ...]) -> tuple[float, ...]:
    """The first of equal tuples met lately: a log of 50,000 poses with one calibrated
    covariance holds one copy of it, not 50,000."""
    return values


def _covariance(obj: dict, name: str, dim: int, where: str = "") -> tuple[float, ...]:
    values = _numbers(obj, name, dim * dim, where)
    problem = covariance_problem(values, dim)
    if problem is not None:
        raise ValueError(f"'{where}{name}' {problem}")
    return _shared(values)


def _stamp(obj: dict) -> int:
    return _integer(obj, "stamp_ns", high=limits.MAX_STAMP_NS)


def _pose_index(obj: dict, name: str) -> int:
    return _integer(obj, name, high=limits.MAX_POSES - 1)


def _string(obj: dict, name: str, where: str = "", default: str | None = None) -> str:
    value = obj.get(name, default) if default is not None else _field(obj, name, where)
    if not isinstance(value, str):
        raise ValueError(f"'{where}{name}' must be a string, got {shown(value)}")
    return value


def decode_odometry(obj: dict) -> Odometry:
    return Odometry(
        stamp_ns=_stamp(obj),
        from_index=_pose_index(obj, "from_index"),
        to_index=_pose_index(obj, "to_index"),
        translation=_vector(obj, "translation", "", limits.MAX_ODOMETRY_STEP_M),  # type: ignore[arg-type]
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
        translation=_vector(obj, "translation", where, limits.MAX_RANGE_M),  # type: ignore[arg-type]
        rotation=_quaternion(obj, "rotation", where),
        covariance=_covariance(obj, "covariance", 6, where),
    )


def decode_detection(obj: Any, num_classes: int, where: str = "") -> Detection:
    if not isinstance(obj, dict):
        raise ValueError(f"'{where}' must be an object")
    where = where + "."
    class_id = _integer(obj, "class_id", where)
    if class_id >= num_classes:
        raise ValueError(f"'{where}class_id' {class_id} is outside 0..{num_classes - 1}")
    source = _field(obj, "source", where)
    if source not in SOURCES:
        raise ValueError(f"'{where}source' must be one of {list(SOURCES)}, got {shown(source)}")
    bbox = None
    if obj.get("bbox") is not None:
        bbox = _numbers(obj, "bbox", 4, where, limits.MAX_PIXEL)
        if bbox[0] > bbox[2] or bbox[1] > bbox[3]:
            raise ValueError(f"'{where}bbox' must be [u_min, v_min, u_max, v_max]")
    relative_pose = None
    if obj.get("relative_pose") is not None:
        relative_pose = _decode_relative_pose(obj["relative_pose"], where + "relative_pose")
    truth = None
    if obj.get("truth_landmark_id") is not None:
        truth = _integer(obj, "truth_landmark_id", where, low=-1, high=limits.MAX_LANDMARK_ID)
    return Detection(
        class_id=class_id,
        score=_number(obj, "score", where, 0.0, 1.0),
        # The contract's definitions: bearing = atan2(y, x), elevation = atan2(z, hypot(x, y)).
        bearing=_number(obj, "bearing", where, -math.pi, math.pi),
        elevation=_number(obj, "elevation", where, -math.pi / 2, math.pi / 2),
        range=_number(obj, "range", where, limits.MIN_RANGE_M, limits.MAX_RANGE_M),
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
        pose_index=_pose_index(obj, "pose_index"),
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
        pose_index=_pose_index(obj, "pose_index"),
        translation=_numbers(obj, "translation", 3, bound=limits.MAX_COORDINATE_M),  # type: ignore[arg-type]
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
        if class_id >= num_classes:
            raise ValueError(f"'{where}class_id' {class_id} is outside 0..{num_classes - 1}")
        landmarks.append(
            GroundTruthLandmark(
                id=_integer(item, "id", where, high=limits.MAX_LANDMARK_ID),
                class_id=class_id,
                position=_numbers(item, "position", 3, where, limits.MAX_COORDINATE_M),  # type: ignore[arg-type]
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


def _rigid_transform_problem(values: tuple[float, ...]) -> str | None:
    matrix = np.asarray(values).reshape(4, 4)
    if not np.allclose(matrix[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        return "must end in the row [0, 0, 0, 1]"
    rotation = matrix[:3, :3]
    if not np.allclose(rotation.T @ rotation, np.eye(3), atol=1e-3):
        return "must hold a rotation (orthonormal 3x3 block)"
    return None


def decode_calibration(obj: dict) -> StereoCalibration:
    pixel = limits.MAX_PIXEL
    calib = StereoCalibration(
        stamp_ns=_stamp(obj),
        width=_integer(obj, "width", low=1, high=limits.MAX_IMAGE_SIDE_PX),
        height=_integer(obj, "height", low=1, high=limits.MAX_IMAGE_SIDE_PX),
        fx=_number(obj, "fx", high=pixel, positive=True),
        fy=_number(obj, "fy", high=pixel, positive=True),
        cx=_number(obj, "cx", low=-pixel, high=pixel),
        cy=_number(obj, "cy", low=-pixel, high=pixel),
        baseline=_number(obj, "baseline", high=limits.MAX_BASELINE_M, positive=True),
        body_from_camera=_numbers(obj, "body_from_camera", 16, bound=limits.MAX_COORDINATE_M),
    )
    problem = _rigid_transform_problem(calib.body_from_camera)
    if problem is not None:
        raise ValueError(f"'body_from_camera' {problem}")
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
    sec = _integer(stamp, "sec", "timestamp.", high=limits.MAX_STAMP_NS // 1_000_000_000)
    nsec = _integer(stamp, "nsec", "timestamp.", high=999_999_999)
    stamp_ns = sec * 1_000_000_000 + nsec
    if stamp_ns > limits.MAX_STAMP_NS:
        raise ValueError(f"'timestamp' is past {limits.MAX_STAMP_NS} ns")
    data = _string(obj, "data")
    try:
        raw = base64.b64decode(data, validate=True)
    except (ValueError, binascii.Error):
        raise ValueError("'data' is not valid base64") from None
    return CompressedImage(
        stamp_ns=stamp_ns,
        frame_id=_string(obj, "frame_id", default=""),
        format=_string(obj, "format"),
        data=raw,
    )


def encode_compressed_image(msg: CompressedImage) -> dict:
    return {
        "timestamp": {"sec": msg.stamp_ns // 1_000_000_000, "nsec": msg.stamp_ns % 1_000_000_000},
        "frame_id": msg.frame_id,
        "data": base64.b64encode(msg.data).decode("ascii"),
        "format": msg.format,
    }
