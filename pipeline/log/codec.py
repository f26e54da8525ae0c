"""JSON <-> the log's messages, as `messages.py` declares them.

msgspec decodes a message's JSON straight into its dataclass, checking every field's type and
range as it goes (the annotations' `Meta`); `checked` then makes the checks that span a
field's items (the annotations' markers: lengths, unit quaternions, covariances, box corners,
rigid transforms, class ids below the log's count). `decode` raises `ValueError` with a short
reason naming the field; the reader adds the topic and the message position. `encode` gives
the JSON dict that `decode` reads back.
"""

from __future__ import annotations

import base64
import dataclasses
import functools
import json
import math
import types
import typing
from typing import Any, TypeVar

import msgspec
import numpy as np

from pipeline import settings
from pipeline.log import limits
from pipeline.log.messages import (
    CompressedImage,
    Corners,
    Covariance,
    Norm,
    OfTheLogsClasses,
    RigidTransform,
    UnitQuaternion,
)

T = TypeVar("T")
shown = settings.shown  # a bad value, cut short: a log's 10 MB string must not make a 10 MB line


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


def _rigid_transform_problem(values: tuple[float, ...]) -> str | None:
    matrix = np.asarray(values).reshape(4, 4)
    if not np.allclose(matrix[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        return "must end in the row [0, 0, 0, 1]"
    rotation = matrix[:3, :3]
    if not np.allclose(rotation.T @ rotation, np.eye(3), atol=1e-3):
        return "must hold a rotation (orthonormal 3x3 block)"
    return None


_MARKERS = (Norm, UnitQuaternion, Covariance, Corners, RigidTransform, OfTheLogsClasses)


@functools.cache
def _plan(cls: type) -> tuple[tuple[tuple[str, Any], ...], tuple[tuple[str, bool], ...]]:
    """What `checked` checks of a message class: (field, marker) pairs, and the fields holding
    messages of their own (one, or a tuple of them)."""
    hints = typing.get_type_hints(cls, include_extras=True)
    checks, nested = [], []
    for f in dataclasses.fields(cls):
        kind = hints[f.name]
        if isinstance(kind, types.UnionType) or typing.get_origin(kind) is typing.Union:
            kind = next(a for a in typing.get_args(kind) if a is not type(None))
        if typing.get_origin(kind) is typing.Annotated:
            checks += [(f.name, m) for m in kind.__metadata__ if isinstance(m, _MARKERS)]
            kind = typing.get_args(kind)[0]
        if dataclasses.is_dataclass(kind):
            nested.append((f.name, False))
        elif typing.get_origin(kind) is tuple and dataclasses.is_dataclass(
            typing.get_args(kind)[0]
        ):
            nested.append((f.name, True))
    return tuple(checks), tuple(nested)


def checked(msg: T, num_classes: int, where: str = "") -> T:
    """`msg` after the checks that span a field's items, as the message's declaration marks
    them (ValueError naming the field), built again by its own constructor, its nested messages
    too: msgspec gives each instance it decodes a dict of its own, the constructor's share
    their class's keys and take about 280 bytes less each (a 50,000-pose log read: 132 -> 76
    MB). Equal covariances are shared between messages."""
    checks, nested = _plan(type(msg))
    parts: dict[str, Any] = {}
    for name, marker in checks:
        value = getattr(msg, name)
        if value is None:
            continue
        key = where + name
        if isinstance(marker, Covariance):
            problem = covariance_problem(value, marker.dim)
            if problem is not None:
                raise ValueError(f"'{key}' {problem}")
            parts[name] = _shared(value)
        elif isinstance(marker, Norm):
            norm = math.sqrt(sum(v * v for v in value))
            if not marker.low <= norm <= marker.high:
                raise ValueError(
                    f"'{key}' has length {norm:.6g}, outside [{marker.low:.6g}, {marker.high:.6g}]"
                )
        elif isinstance(marker, UnitQuaternion):
            norm = math.sqrt(sum(v * v for v in value))
            if abs(norm - 1.0) > limits.QUATERNION_NORM_TOLERANCE:
                raise ValueError(f"'{key}' is not a unit quaternion (norm {norm:.6g})")
        elif isinstance(marker, Corners):
            if value[0] > value[2] or value[1] > value[3]:
                raise ValueError(f"'{key}' must be [u_min, v_min, u_max, v_max]")
        elif isinstance(marker, RigidTransform):
            problem = _rigid_transform_problem(value)
            if problem is not None:
                raise ValueError(f"'{key}' {problem}")
        elif value >= num_classes:  # OfTheLogsClasses
            raise ValueError(f"'{key}' {value} is outside 0..{num_classes - 1}")
    for name, many in nested:
        value = getattr(msg, name)
        if value is None:
            continue
        if many:
            parts[name] = tuple(
                checked(item, num_classes, f"{where}{name}[{k}].") for k, item in enumerate(value)
            )
        else:
            parts[name] = checked(value, num_classes, f"{where}{name}.")
    return dataclasses.replace(msg, **parts)  # type: ignore[type-var]


@functools.cache
def _decoder(cls: type) -> msgspec.json.Decoder:
    return msgspec.json.Decoder(cls)


def _reason(error: msgspec.ValidationError, cls: type, data: bytes) -> str:
    """msgspec's refusal as one line naming the field, its range and the value read."""
    obj = parse_json(data)  # raises the reason itself where the JSON is at fault
    if not isinstance(obj, dict):
        return "message is not a JSON object"
    return settings.explain(error, cls, obj, noun="field", show=shown)


def decode(cls: type[T], data: bytes, num_classes: int) -> T:
    """One message of type `cls` from its JSON, every field checked."""
    try:
        msg = _decoder(cls).decode(data)
    except msgspec.ValidationError as error:
        raise ValueError(_reason(error, cls, data)) from None
    except msgspec.DecodeError as error:
        parse_json(data)  # raises the reason: NaN, malformed, too deep
        raise ValueError(f"malformed JSON ({error})") from None
    return checked(msg, num_classes)


def _builtin(value: Any) -> Any:
    if dataclasses.is_dataclass(value):
        return encode(value)
    if isinstance(value, tuple):
        return [_builtin(v) for v in value]
    return value


def encode(msg: Any) -> dict:
    """A message as the JSON object `decode` reads back: fields in declared order, optional
    ones left out when None."""
    if isinstance(msg, CompressedImage):
        return _encode_compressed_image(msg)
    return {
        f.name: _builtin(value)
        for f in dataclasses.fields(msg)
        if (value := getattr(msg, f.name)) is not None or f.default is not None
    }


# --- foxglove.CompressedImage: Foxglove's own schema on the wire ------------------------------


@dataclasses.dataclass(frozen=True)
class _FoxgloveTime:
    sec: typing.Annotated[int, msgspec.Meta(ge=0, le=limits.MAX_STAMP_NS // 1_000_000_000)]
    nsec: typing.Annotated[int, msgspec.Meta(ge=0, le=999_999_999)]


@dataclasses.dataclass(frozen=True)
class _CompressedImageJson:
    timestamp: _FoxgloveTime
    format: str
    data: bytes  # base64 in JSON
    frame_id: str = ""


def decode_compressed_image(data: bytes) -> CompressedImage:
    try:
        wire = _decoder(_CompressedImageJson).decode(data)
    except msgspec.ValidationError as error:
        if "base64" in str(error):
            raise ValueError("'data' is not valid base64") from None
        raise ValueError(_reason(error, _CompressedImageJson, data)) from None
    except msgspec.DecodeError as error:
        parse_json(data)
        raise ValueError(f"malformed JSON ({error})") from None
    stamp_ns = wire.timestamp.sec * 1_000_000_000 + wire.timestamp.nsec
    if stamp_ns > limits.MAX_STAMP_NS:
        raise ValueError(f"'timestamp' is past {limits.MAX_STAMP_NS} ns")
    return CompressedImage(stamp_ns, wire.frame_id, wire.format, wire.data)


def _encode_compressed_image(msg: CompressedImage) -> dict:
    return {
        "timestamp": {"sec": msg.stamp_ns // 1_000_000_000, "nsec": msg.stamp_ns % 1_000_000_000},
        "frame_id": msg.frame_id,
        "data": base64.b64encode(msg.data).decode("ascii"),
        "format": msg.format,
    }
