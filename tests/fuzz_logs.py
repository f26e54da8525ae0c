"""A generator of mutated detection logs, and the judge of what `mmslam inspect` makes of each.

From one small valid log (every topic, images included) it makes a few hundred mutations of
every kind issue 13 lists: byte flips anywhere (index and summary records too), truncations,
decompression bombs, huge integers, deep nesting, non-finite and extreme numbers, angles and
ranges out of range, ill-conditioned covariances, stamps past int64 or going back, wrong types,
missing fields, bad metadata (two records, duplicate or non-string class names), channels of
the wrong schema or encoding, broken links between messages, and harmless changes (another
chunking or compression, unknown topics, Foxglove's protobuf topics, key order) that must
change nothing.

Each case says what it expects: `REFUSED` (exit 2, one line on stderr), `SAME` (exit 0 and the
very log the original reads as), or `EITHER` (a random byte flip: one or the other). Run
`python -m tests.fuzz_logs` for the figures; tests/test_fuzz.py asserts them.
"""

from __future__ import annotations

import base64
import contextlib
import copy
import io
import json
import random
import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import lz4.frame
import numpy as np
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.records import Chunk, DataEnd, Footer, Header, Metadata
from mcap.writer import CompressionType, Writer

from pipeline.cli import main
from pipeline.errors import InputError
from pipeline.log import limits, read_log, schemas
from pipeline.log.messages import LogMetadata
from pipeline.log.metadata import metadata_record

REFUSED, SAME, EITHER = "refused", "same", "either"
MAGIC = b"\x89MCAP0\r\n"
I3 = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
I6 = [float(i == j) for i in range(6) for j in range(6)]
METADATA = LogMetadata(2, ((0.9, 0.1), (0.2, 0.8)), ("car", "van"), "tests/fuzz_logs.py")
SECOND = 1_000_000_000


@dataclass
class LogSpec:
    """A log to write: messages as [channel, JSON object or raw bytes, log time], channels by
    name as (topic, schema name, schema encoding, message encoding), metadata records, and how
    the MCAP file is laid out."""

    messages: list[list[Any]]
    channels: dict[str, tuple[str, str, str, str]]
    metadata: list[tuple[str, dict[str, str]]]
    compression: CompressionType = CompressionType.ZSTD
    chunk_size: int = 2048
    chunked: bool = True
    crcs: bool = True
    data_crc: bool = True  # mmslam's writer writes it; MCAP's default, and earlier logs, do not
    summary: bool = True
    attachment: bool = False


@dataclass
class Case:
    kind: str  # what the mutation is of: one of the kinds
    name: str
    expect: str  # REFUSED, SAME or EITHER
    data: bytes = field(repr=False)


def _channel(topic: str) -> tuple[str, str, str, str]:
    return topic, schemas.SCHEMAS[topic][0], "jsonschema", "json"


def base_spec() -> LogSpec:
    """A valid log of five poses holding every topic of the contract."""
    rng = np.random.default_rng(7)
    messages: list[list[Any]] = [
        [schemas.CALIBRATION, {
            "stamp_ns": SECOND, "width": 640, "height": 480, "fx": 500.0, "fy": 500.0,
            "cx": 320.0, "cy": 240.0, "baseline": 0.5,
            "body_from_camera": [0.0, 0.0, 1.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0,
                                 0.0, 0.0, 0.0, 1.0],
        }],
        [schemas.GT_LANDMARKS, {"stamp_ns": SECOND, "landmarks": [
            {"id": 10, "class_id": 0, "position": [4.0, 1.0, 0.5]},
            {"id": 11, "class_id": 1, "position": [6.0, -1.5, 0.2]},
        ]}],
    ]  # fmt: skip
    for pose in range(5):
        stamp = SECOND * (pose + 1)
        if pose:
            messages.append([schemas.ODOMETRY, {
                "stamp_ns": stamp, "from_index": pose - 1, "to_index": pose,
                "translation": [1.0, 0.01 * pose, 0.0], "rotation": [0.0, 0.0, 0.0, 1.0],
                "covariance": [v * 1e-4 for v in I6],
            }])  # fmt: skip
        messages.append([schemas.GT_POSE, {
            "stamp_ns": stamp, "pose_index": pose, "translation": [float(pose), 0.0, 0.0],
            "rotation": [0.0, 0.0, 0.0, 1.0],
        }])  # fmt: skip
        detections = []
        for landmark, (x, y, z) in ((10, (4.0, 1.0, 0.5)), (11, (6.0, -1.5, 0.2))):
            x -= pose
            if x <= 0.5:
                continue
            rng_ = float(np.sqrt(x * x + y * y + z * z))
            detections.append({
                "class_id": landmark - 10, "score": 0.9,
                "bearing": float(np.arctan2(y, x)) + float(rng.normal(0, 0.001)),
                "elevation": float(np.arctan2(z, np.hypot(x, y))), "range": rng_,
                "covariance": [v * 1e-4 for v in I3], "source": "apriltag",
                "bbox": [10.0, 20.0, 50.0, 70.0], "truth_landmark_id": landmark,
                "relative_pose": {"translation": [x, y, z], "rotation": [0.0, 0.0, 0.0, 1.0],
                                  "covariance": [v * 1e-3 for v in I6]},
            })  # fmt: skip
        messages.append(
            [schemas.DETECTIONS, {"stamp_ns": stamp, "pose_index": pose, "detections": detections}]
        )
    image = {"timestamp": {"sec": 1, "nsec": 0}, "frame_id": "camera_left", "format": "png",
             "data": base64.b64encode(b"\x89PNG not really").decode()}  # fmt: skip
    messages.append([schemas.LEFT_IMAGE, image])
    for message in messages:
        message.append(message[1].get("stamp_ns", SECOND))
    channels = {topic: _channel(topic) for topic in dict.fromkeys(m[0] for m in messages)}
    return LogSpec(messages, channels, [("mmslam", metadata_record(METADATA))])


def write_spec(spec: LogSpec) -> bytes:
    """The MCAP bytes of `spec` (data-section CRCs on, as mmslam's writer writes them)."""
    out = io.BytesIO()
    writer = Writer(
        out,
        chunk_size=spec.chunk_size,
        compression=spec.compression,
        use_chunking=spec.chunked,
        enable_crcs=spec.crcs,
        enable_data_crcs=spec.crcs and spec.data_crc,
        use_summary_offsets=spec.summary,
        use_statistics=spec.summary,
        repeat_channels=spec.summary,
        repeat_schemas=spec.summary,
    )
    writer.start(profile="", library="tests/fuzz_logs.py")
    for name, record in spec.metadata:
        writer.add_metadata(name, record)
    if spec.attachment:
        writer.add_attachment(0, 0, "notes.txt", "text/plain", b"not a message")
    ids: dict[str, int] = {}
    for name, (topic, schema_name, schema_encoding, encoding) in spec.channels.items():
        schema = writer.register_schema(schema_name, schema_encoding, b"{}")
        ids[name] = writer.register_channel(topic, encoding, schema)
    for channel, payload, log_time in spec.messages:
        data = payload if isinstance(payload, bytes) else json.dumps(payload).encode()
        writer.add_message(ids.get(channel, 999), log_time, data, log_time)
    writer.finish()
    return out.getvalue()


# ---------------------------------------------------------------------------- mutations


def _with(edit: Callable[[LogSpec], None]) -> bytes:
    spec = base_spec()
    edit(spec)
    return write_spec(spec)


def _messages_of(spec: LogSpec, topic: str) -> list[list[Any]]:
    return [m for m in spec.messages if m[0] == topic]


def _set(path: tuple, value: Any, topic: str, which: int = 1, raw: bytes | None = None) -> bytes:
    """The base log with the field at `path` of the `which`-th message of `topic` set to
    `value` (or its JSON text replaced by `raw`, for what json.dumps cannot write)."""

    def edit(spec: LogSpec) -> None:
        message = _messages_of(spec, topic)[which]
        obj = message[1]
        for key in path[:-1]:
            obj = obj[key]
        obj[path[-1]] = "__RAW__" if raw is not None else value
        if raw is not None:
            message[1] = json.dumps(message[1]).replace('"__RAW__"', raw.decode()).encode()

    return _with(edit)


def _drop(path: tuple, topic: str, which: int = 1) -> bytes:
    def edit(spec: LogSpec) -> None:
        obj = _messages_of(spec, topic)[which][1]
        for key in path[:-1]:
            obj = obj[key]
        del obj[path[-1]]

    return _with(edit)


# Every field of every message, with where it lives, and whether it is an integer.
DETECTION = ("detections", 0)
FIELDS = {
    schemas.ODOMETRY: [("stamp_ns",), ("from_index",), ("to_index",), ("translation", 0),
                       ("rotation", 3), ("covariance", 0)],
    schemas.DETECTIONS: [("stamp_ns",), ("pose_index",), (*DETECTION, "class_id"),
                         (*DETECTION, "score"), (*DETECTION, "bearing"),
                         (*DETECTION, "elevation"), (*DETECTION, "range"),
                         (*DETECTION, "covariance", 4), (*DETECTION, "bbox", 2),
                         (*DETECTION, "truth_landmark_id"),
                         (*DETECTION, "relative_pose", "translation", 0),
                         (*DETECTION, "relative_pose", "covariance", 0)],
    schemas.GT_POSE: [("stamp_ns",), ("pose_index",), ("translation", 1), ("rotation", 0)],
    schemas.GT_LANDMARKS: [("stamp_ns",), ("landmarks", 0, "id"), ("landmarks", 0, "class_id"),
                           ("landmarks", 0, "position", 2)],
    schemas.CALIBRATION: [("stamp_ns",), ("width",), ("height",), ("fx",), ("cx",),
                          ("baseline",), ("body_from_camera", 0)],
    schemas.LEFT_IMAGE: [("timestamp", "sec"), ("timestamp", "nsec")],
}  # fmt: skip
WHICH = {schemas.GT_LANDMARKS: 0, schemas.CALIBRATION: 0, schemas.LEFT_IMAGE: 0}
NOT_NUMBERS = ["text", None, True, [], {}]
OPTIONAL = {"truth_landmark_id"}  # null or absent is allowed: not a mutation to refuse


def field_cases() -> Iterator[Case]:
    """Every field of every topic: values no reader may take."""
    huge = b"1" + b"0" * 400
    deep = b"[" * 100_000 + b"]" * 100_000
    for topic, paths in FIELDS.items():
        which = WHICH.get(topic, 1)
        for path in paths:
            where = f"{topic} {'.'.join(map(str, path))}"
            yield Case("huge integer", where, REFUSED, _set(path, None, topic, which, huge))
            yield Case("deep nesting", where, REFUSED, _set(path, None, topic, which, deep))
            yield Case("non-finite", where, REFUSED, _set(path, None, topic, which, b"NaN"))
            yield Case("non-finite", where, REFUSED, _set(path, None, topic, which, b"-1e999"))
            yield Case("extreme", where, REFUSED, _set(path, 1e308, topic, which))
            for value in NOT_NUMBERS:
                if value is None and path[-1] in OPTIONAL:
                    continue
                yield Case(
                    "wrong type", f"{where} = {value!r}", REFUSED, _set(path, value, topic, which)
                )
            if isinstance(path[-1], str) and path[-1] not in OPTIONAL:
                yield Case("missing field", where, REFUSED, _drop(path, topic, which))
        late = (
            (("timestamp", "sec"), 2**34) if topic == schemas.LEFT_IMAGE else (("stamp_ns",), 2**63)
        )
        yield Case("stamp past int64", topic, REFUSED, _set(*late, topic, which))
        yield Case("malformed JSON", topic, REFUSED, _raw(topic, which, b'{"stamp_ns": 1'))
        yield Case("not an object", topic, REFUSED, _raw(topic, which, b"[1, 2]"))
        yield Case("not UTF-8", topic, REFUSED, _raw(topic, which, b'{"a": "\xff"}'))


def _raw(topic: str, which: int, data: bytes) -> bytes:
    """The base log with the `which`-th message of `topic` replaced by `data`."""
    return _with(lambda spec: _messages_of(spec, topic)[which].__setitem__(1, data))


def value_cases() -> Iterator[Case]:
    """Finite values past the contract's bounds: the back-end's crashes of issue 13."""
    det = DETECTION
    six = [1e-4 * v for v in I6]
    ill = list(six)
    ill[0] = 1e-40  # condition number 1e36
    bad = {
        "odometry step of 1e12 m": ((schemas.ODOMETRY, ("translation", 0)), 1e12),
        "range 1e308": ((schemas.DETECTIONS, (*det, "range")), 1e308),
        "range 1e-300": ((schemas.DETECTIONS, (*det, "range")), 1e-300),
        "range 0": ((schemas.DETECTIONS, (*det, "range")), 0.0),
        "negative range": ((schemas.DETECTIONS, (*det, "range")), -5.0),
        "elevation 4 rad": ((schemas.DETECTIONS, (*det, "elevation")), 4.0),
        "bearing 1e6 rad": ((schemas.DETECTIONS, (*det, "bearing")), 1e6),
        "bearing just past pi": ((schemas.DETECTIONS, (*det, "bearing")), 3.1416),
        "score 1.5": ((schemas.DETECTIONS, (*det, "score")), 1.5),
        "class id 2 of 2": ((schemas.DETECTIONS, (*det, "class_id")), 2),
        "class id -1": ((schemas.DETECTIONS, (*det, "class_id")), -1),
        "source lidar": ((schemas.DETECTIONS, (*det, "source")), "lidar"),
        "truth id -2": ((schemas.DETECTIONS, (*det, "truth_landmark_id")), -2),
        "bbox reversed": ((schemas.DETECTIONS, (*det, "bbox")), [50.0, 20.0, 10.0, 70.0]),
        "bbox past a million px": ((schemas.DETECTIONS, (*det, "bbox", 2)), 2e6),
        "ill-conditioned odometry": ((schemas.ODOMETRY, ("covariance",)), ill),
        "zero covariance": ((schemas.ODOMETRY, ("covariance",)), [0.0] * 36),
        "asymmetric covariance": ((schemas.DETECTIONS, (*det, "covariance", 1)), 5e-5),
        "variance 1e-30": ((schemas.DETECTIONS, (*det, "covariance")),
                           [1e-30, 0, 0, 0, 1e-30, 0, 0, 0, 1e-30]),
        "variance 1e20": ((schemas.DETECTIONS, (*det, "covariance")),
                          [1e20, 0, 0, 0, 1e20, 0, 0, 0, 1e20]),
        "covariance of 8": ((schemas.DETECTIONS, (*det, "covariance")), [1.0] * 8),
        "quaternion of norm 2": ((schemas.ODOMETRY, ("rotation",)), [0.0, 0.0, 0.0, 2.0]),
        "tag 1e5 m away": ((schemas.DETECTIONS, (*det, "relative_pose", "translation", 0)), 1e5),
        "ground truth 1e9 m away": ((schemas.GT_POSE, ("translation", 0)), 1e9),
        "landmark 1e9 m away": ((schemas.GT_LANDMARKS, ("landmarks", 1, "position", 0)), 1e9),
        "landmark class 5": ((schemas.GT_LANDMARKS, ("landmarks", 1, "class_id")), 5),
        "focal length 0": ((schemas.CALIBRATION, ("fx",)), 0.0),
        "baseline 1 km": ((schemas.CALIBRATION, ("baseline",)), 1000.0),
        "not a rigid mount": ((schemas.CALIBRATION, ("body_from_camera", 15)), 2.0),
        "sheared mount": ((schemas.CALIBRATION, ("body_from_camera", 1)), 0.5),
        "image nsec past a second": ((schemas.LEFT_IMAGE, ("timestamp", "nsec")), 10**9),
        "image not base64": ((schemas.LEFT_IMAGE, ("data",)), "not base64!"),
        "image format a number": ((schemas.LEFT_IMAGE, ("format",)), 3),
        "negative stamp": ((schemas.ODOMETRY, ("stamp_ns",)), -1),
        "pose index past the bound": ((schemas.DETECTIONS, ("pose_index",)), 10**7),
    }  # fmt: skip
    for name, ((topic, path), value) in bad.items():
        yield Case("out of range", name, REFUSED, _set(path, value, topic, WHICH.get(topic, 1)))


def order_cases() -> Iterator[Case]:
    """Rules across messages: links, stamps, counts."""

    def stamps(spec: LogSpec, topic: str, values: list[int]) -> None:
        for message, value in zip(_messages_of(spec, topic), values, strict=False):
            message[1]["stamp_ns"] = message[2] = value

    def twice(topic: str) -> Callable[[LogSpec], None]:
        def edit(spec: LogSpec) -> None:
            first = _messages_of(spec, topic)[0]
            spec.messages.append(copy.deepcopy(first))

        return edit

    def field_of(topic: str, which: int, key: str, value: Any) -> Callable[[LogSpec], None]:
        def edit(spec: LogSpec) -> None:
            _messages_of(spec, topic)[which][1][key] = value

        return edit

    def log_time(spec: LogSpec) -> None:
        _messages_of(spec, schemas.ODOMETRY)[0][2] += 1

    def drop_odometry(spec: LogSpec) -> None:
        spec.messages.remove(_messages_of(spec, schemas.ODOMETRY)[-1])

    def drop_metadata(spec: LogSpec) -> None:
        spec.metadata = []

    edits: dict[str, Callable[[LogSpec], None]] = {
        "detection stamps going back": lambda s: stamps(s, schemas.DETECTIONS, [5, 4, 3, 2, 1]),
        "all odometry stamps zero": lambda s: stamps(s, schemas.ODOMETRY, [0, 0, 0, 0]),
        "odometry stamps repeating": lambda s: stamps(s, schemas.ODOMETRY, [SECOND] * 4),
        "ground truth going back": lambda s: stamps(s, schemas.GT_POSE, [9, 8, 7, 6, 5]),
        "log time differs from stamp": log_time,
        "odometry skips a pose": field_of(schemas.ODOMETRY, 1, "from_index", 2),
        "odometry steps by two": field_of(schemas.ODOMETRY, 1, "to_index", 3),
        "detection at an unreached pose": drop_odometry,
        "ground truth of a pose twice": field_of(schemas.GT_POSE, 2, "pose_index", 1),
        "two ground-truth landmark messages": twice(schemas.GT_LANDMARKS),
        "two calibrations": twice(schemas.CALIBRATION),
        "landmark ids not unique": lambda s: s.messages[1][1]["landmarks"][1].update(id=10),
        "no metadata": drop_metadata,
    }
    for name, edit in edits.items():
        yield Case("order", name, REFUSED, _with(edit))


def metadata_cases() -> Iterator[Case]:
    good = metadata_record(METADATA)
    changes: dict[str, dict[str, str] | None] = {
        "format version 2": {"format_version": "2"},
        "num_classes 0": {"num_classes": "0"},
        "num_classes -1": {"num_classes": "-1"},
        "num_classes 2_0": {"num_classes": "2_0"},
        "num_classes with a space": {"num_classes": " 2"},
        "num_classes 1001": {"num_classes": "1001"},
        "num_classes of 400 digits": {"num_classes": "1" + "0" * 400},
        "num_classes not a number": {"num_classes": "two"},
        "matrix not JSON": {"confusion_matrix": "[[0.9, 0.1], [0.2"},
        "matrix nested deep": {"confusion_matrix": "[" * 100_000 + "]" * 100_000},
        "matrix with a huge integer": {"confusion_matrix": "[[1" + "0" * 400 + ", 0], [0, 1]]"},
        "matrix with NaN": {"confusion_matrix": "[[NaN, 0.1], [0.2, 0.8]]"},
        "matrix rows not summing to 1": {"confusion_matrix": "[[0.9, 0.2], [0.2, 0.8]]"},
        "matrix of the wrong shape": {"confusion_matrix": "[[1.0]]"},
        "matrix with a negative": {"confusion_matrix": "[[1.1, -0.1], [0.2, 0.8]]"},
        "matrix of strings": {"confusion_matrix": '[["1", "0"], ["0", "1"]]'},
        "duplicate class names": {"class_names": '["car", "car"]'},
        "class names not strings": {"class_names": "[1, 2]"},
        "an empty class name": {"class_names": '["car", ""]'},
        "a class name of 300 characters": {"class_names": json.dumps(["car", "v" * 300])},
        "one class name for two": {"class_names": '["car"]'},
        "class names not JSON": {"class_names": "car, van"},
        "class names nested deep": {"class_names": "[" * 100_000 + "]" * 100_000},
    }
    for key in good:
        changes[f"no {key}"] = None
    for name, change in changes.items():
        record = dict(good)
        if change is None:
            del record[name.removeprefix("no ")]
        else:
            record.update(change)
        yield Case("metadata", name, REFUSED, _with_metadata([("mmslam", record)]))
    twice = [("mmslam", good), ("mmslam", good)]
    yield Case("metadata", "two mmslam records", REFUSED, _with_metadata(twice))


def _with_metadata(records: list[tuple[str, dict[str, str]]]) -> bytes:
    return _with(lambda spec: setattr(spec, "metadata", records))


def channel_cases() -> Iterator[Case]:
    def second_channel(schema: str, encoding: str, with_message: bool) -> Callable[[LogSpec], None]:
        def edit(spec: LogSpec) -> None:
            spec.channels["other"] = (schemas.ODOMETRY, schema, "jsonschema", encoding)
            if with_message:
                _messages_of(spec, schemas.ODOMETRY)[-1][0] = "other"

        return edit

    def first_channel(index: int, value: str) -> Callable[[LogSpec], None]:
        def edit(spec: LogSpec) -> None:
            channel = list(spec.channels[schemas.DETECTIONS])
            channel[index] = value
            spec.channels[schemas.DETECTIONS] = tuple(channel)  # type: ignore[assignment]

        return edit

    def unknown_channel(spec: LogSpec) -> None:
        spec.messages[3][0] = "nowhere"

    edits = {
        "second /odometry channel foo.Bar, cdr": second_channel("foo.Bar", "cdr", True),
        "second /odometry channel foo.Bar, no message": second_channel("foo.Bar", "cdr", False),
        "second /odometry channel, cdr": second_channel("mmslam.Odometry", "cdr", True),
        "schema name foo.Bar": first_channel(1, "foo.Bar"),
        "schema encoding protobuf": first_channel(2, "protobuf"),
        "message encoding cbor": first_channel(3, "cbor"),
        "a message on an unknown channel": unknown_channel,
    }  # fmt: skip
    for name, edit in edits.items():
        yield Case("channel", name, REFUSED, _with(edit))


def harmless_cases() -> Iterator[Case]:
    """Changes that must leave the log as it reads."""

    def unknown_topic(spec: LogSpec) -> None:
        spec.channels["extra"] = ("/lidar/points", "foo.Bar", "protobuf", "cdr")
        spec.messages.insert(4, ["extra", b"\x00\x01 anything", SECOND])

    def foxglove_topics(spec: LogSpec) -> None:  # as mmslam's writer adds them beside the log's
        spec.channels["fox"] = ("/foxglove/tf", "foxglove.FrameTransform", "protobuf", "protobuf")
        spec.channels["path"] = (
            "/foxglove/odometry/path", "foxglove.PosesInFrame", "protobuf", "protobuf"
        )  # fmt: skip
        spec.messages.insert(4, ["fox", b"\x0a\x06\x08\x01\x10\x00", SECOND])
        spec.messages.append(["path", b"\x0a\x06\x08\x01", SECOND])  # last, at the first stamp

    def shuffled_keys(spec: LogSpec) -> None:
        for message in spec.messages:
            message[1] = dict(reversed(list(message[1].items())))

    def spaced_json(spec: LogSpec) -> None:
        for message in spec.messages:
            message[1] = json.dumps(message[1], indent=3).encode()

    def extra_fields(spec: LogSpec) -> None:
        for message in spec.messages:
            message[1]["comment"] = {"anything": [1, "two", None]}

    def float_forms(spec: LogSpec) -> None:
        for message in _messages_of(spec, schemas.ODOMETRY):
            text = json.dumps(message[1]).replace('"rotation": [0.0, 0.0, 0.0, 1.0]',
                                                  '"rotation": [0, 0e0, -0.0, 1E0]')  # fmt: skip
            message[1] = text.encode()

    def layout(**options: Any) -> Callable[[LogSpec], None]:
        return lambda spec: [setattr(spec, k, v) for k, v in options.items()]  # type: ignore[func-returns-value]

    other_metadata = lambda s: s.metadata.insert(0, ("camera", {"model": "zed"}))  # noqa: E731
    edits = {
        "a topic the contract does not know": unknown_topic,
        "Foxglove's topics in protobuf": foxglove_topics,
        "JSON keys in another order": shuffled_keys,
        "JSON with whitespace": spaced_json,
        "fields the contract does not know": extra_fields,
        "numbers written otherwise": float_forms,
        "another metadata record": other_metadata,
        "an attachment": layout(attachment=True),
        "lz4 chunks": layout(compression=CompressionType.LZ4),
        "uncompressed chunks": layout(compression=CompressionType.NONE),
        "one chunk": layout(chunk_size=10**6),
        "a chunk a message": layout(chunk_size=1),
        "no chunks": layout(chunked=False),
        "no CRCs": layout(crcs=False),
        "no summary": layout(summary=False),
        "lz4, no chunks, no summary, no CRCs": layout(
            compression=CompressionType.LZ4, chunked=False, summary=False, crcs=False
        ),
    }
    for name, edit in edits.items():
        yield Case("harmless", name, SAME, _with(edit))
    for i in range(9):  # and the same log under random chunk sizes
        size = random.Random(i).randint(64, 4096)
        yield Case("harmless", f"chunks of {size} bytes", SAME, _with(layout(chunk_size=size)))


def _record(record: Any) -> bytes:
    builder = RecordBuilder()
    record.write(builder)
    return builder.end()


def _file_of_chunks(chunks: list[Chunk]) -> bytes:
    """A whole MCAP file of our making: a header, the mmslam metadata, then `chunks`."""
    records = [Header("", "bomb"), Metadata("mmslam", metadata_record(METADATA)), *chunks]
    records += [DataEnd(0), Footer(0, 0, 0)]
    return MAGIC + b"".join(_record(r) for r in records) + MAGIC


def _chunk(compression: str, data: bytes, size: int, crc: int = 0) -> Chunk:
    return Chunk(compression, data, SECOND, SECOND, crc, size)


def _zstd_of_zeros(size: int, head: bytes = b"") -> bytes:
    """`head`, then zeros up to `size` bytes, compressed a MiB at a time."""
    compressor = zstandard.ZstdCompressor().compressobj()
    block = bytes(2**20)
    parts = [compressor.compress(head + block[len(head) :])]
    parts += [compressor.compress(block) for _ in range(size // len(block) - 1)]
    return b"".join(parts) + compressor.flush()


def _records_of(data: bytes) -> list[tuple[int, int, int]]:
    """(offset, opcode, length with its head) of each top-level record of an MCAP file."""
    records, offset = [], len(MAGIC)
    while offset < len(data) - len(MAGIC):
        length = 9 + struct.unpack_from("<Q", data, offset + 1)[0]
        records.append((offset, data[offset], length))
        offset += length
    return records


def _data_end(data: bytes) -> int:
    return next(offset for offset, opcode, _ in _records_of(data) if opcode == 0x0F)


def bomb_cases() -> Iterator[Case]:
    """Chunks that inflate far beyond their size: refused before they are inflated."""
    gib, mib = 2**30, 2**20
    zeros, small = _zstd_of_zeros(gib), _zstd_of_zeros(mib)
    one_record = _zstd_of_zeros(9 * mib, struct.pack("<BQ", 0x80, 9 * mib - 9))  # unknown kind
    lz4_zeros = lz4.frame.compress(bytes(64 * mib))
    bombs = {
        "1 GiB of zstd, claimed": [_chunk("zstd", zeros, gib)],
        "1 GiB of zstd claiming 1 KiB": [_chunk("zstd", zeros, 1024)],
        "1 MiB of zstd claiming 0 B": [_chunk("zstd", small, 0)],
        "64 MiB of lz4, claimed": [_chunk("lz4", lz4_zeros, 64 * mib)],
        "64 MiB of lz4 claiming 9 B": [_chunk("lz4", lz4_zeros, 9)],
        "a chunk claiming 2**63 bytes": [_chunk("zstd", small, 2**63)],
        "a chunk of unknown compression": [_chunk("brotli", small, mib)],
        "20 chunks of 9 MiB, each under the chunk cap": [_chunk("zstd", one_record, 9 * mib)] * 20,
    }
    for name, chunks in bombs.items():
        yield Case("decompression bomb", name, REFUSED, _file_of_chunks(chunks))
    for crcs in (True, False):  # spliced into a valid log, before its data end
        valid = _with(lambda s, c=crcs: setattr(s, "crcs", c))
        end, bomb = _data_end(valid), _record(_chunk("zstd", zeros, gib))
        spliced = bytearray(valid[:end] + bomb + valid[end:])
        for at in (len(spliced) - 8 - 20, len(spliced) - 8 - 12):  # the footer's offsets
            struct.pack_into(
                "<Q", spliced, at, struct.unpack_from("<Q", spliced, at)[0] + len(bomb)
            )
        yield Case(
            "decompression bomb", f"spliced into a log (CRCs {crcs})", REFUSED, bytes(spliced)
        )


def container_cases(count_flips: int = 160, count_cuts: int = 30) -> Iterator[Case]:
    """Byte flips anywhere (a third of them in the summary and footer: index records, CRCs),
    each refused, and truncations at random lengths."""
    valid = write_spec(base_spec())
    rng = random.Random(13)
    summary_start = struct.unpack_from("<Q", valid, len(valid) - 8 - 20)[0]
    for i in range(count_flips):
        low = summary_start if i % 3 == 0 else 0
        offset = rng.randrange(low, len(valid))
        flipped = bytearray(valid)
        flipped[offset] ^= 1 << rng.randrange(8)
        where = "summary or footer" if offset >= summary_start else "data section"
        # CRCs over the chunks, the data section and the summary: nothing passes
        yield Case("byte flip", f"bit at {offset} ({where})", REFUSED, bytes(flipped))
    for length in sorted(
        {0, 1, 8, 9, len(valid) - 1, *(rng.randrange(len(valid)) for _ in range(count_cuts))}
    ):
        yield Case("truncation", f"first {length} of {len(valid)} bytes", REFUSED, valid[:length])
    # A log as MCAP's default writer (and mmslam's before) writes it: no data-section CRC, so
    # only the chunks' and the summary's CRCs guard it. Flips in its index and summary records.
    legacy = _with(lambda s: setattr(s, "data_crc", False))
    spans = [(o, o + n) for o, op, n in _records_of(legacy) if op in (0x07, 0x08, 0x0B, 0x0D, 0x0E)]
    spans.append((len(legacy) - 8 - 29, len(legacy)))  # the footer and the closing magic
    for _ in range(count_flips // 4):
        start, end = rng.choice(spans)
        offset = rng.randrange(start, end)
        flipped = bytearray(legacy)
        flipped[offset] ^= 1 << rng.randrange(8)
        yield Case(
            "byte flip", f"bit at {offset} (index or summary, no data CRC)", EITHER, bytes(flipped)
        )
    yield Case("container", "bytes after the closing magic", REFUSED, valid + b"\x00")
    header_end = 8 + 9 + struct.unpack_from("<Q", valid, 9)[0]
    yield Case("container", "no header first", REFUSED, valid[:8] + valid[header_end:])
    yield Case("container", "not MCAP at all", REFUSED, b"hello world, this is not a log" * 10)


def edge_cases() -> Iterator[Case]:
    """Values at the documented bounds, which the reader accepts: the back-end must cope, or
    fail in one line (exit 1), never with a traceback."""
    det = DETECTION
    tight = [v / limits.MAX_CONDITION for v in I6]
    loose = limits.MAX_VARIANCE / limits.MAX_CONDITION  # the other variances
    for i in (3, 4, 5):
        tight[i * 7] = 1.0  # condition number at the bound
    values = {
        "the longest odometry step": (
            (schemas.ODOMETRY, ("translation",)), [limits.MAX_ODOMETRY_STEP_M, 0.0, 0.0]
        ),
        "range 10 km": ((schemas.DETECTIONS, (*det, "range")), 1e4),
        "range 1 mm": ((schemas.DETECTIONS, (*det, "range")), 1e-3),
        "elevation pi/2": ((schemas.DETECTIONS, (*det, "elevation")), np.pi / 2),
        "bearing -pi": ((schemas.DETECTIONS, (*det, "bearing")), -np.pi),
        "the smallest variance": ((schemas.DETECTIONS, (*det, "covariance")),
                                  [limits.MIN_VARIANCE, 0, 0, 0, 1e-6, 0, 0, 0, 1e-6]),
        "the largest variance": ((schemas.DETECTIONS, (*det, "covariance")),
                                 [limits.MAX_VARIANCE, 0, 0, 0, loose, 0, 0, 0, loose]),
        "the worst odometry condition number": ((schemas.ODOMETRY, ("covariance",)), tight),
        "ground truth 1e8 m away": ((schemas.GT_POSE, ("translation", 0)), 1e8),
    }  # fmt: skip
    for name, ((topic, path), value) in values.items():
        yield Case("at a bound", name, SAME, _set(path, value, topic, WHICH.get(topic, 1)))

    def late(spec: LogSpec) -> None:  # the last stamps int64 holds
        for message in spec.messages:
            shift = 2**63 - 1 - 10 * SECOND
            if "stamp_ns" in message[1]:
                message[1]["stamp_ns"] += shift
            else:  # an image
                stamp = SECOND + shift
                message[1]["timestamp"] = {"sec": stamp // SECOND, "nsec": stamp % SECOND}
            message[2] += shift

    yield Case("at a bound", "stamps up to 2**63 - 1", SAME, _with(late))


def all_cases() -> Iterator[Case]:
    yield from field_cases()
    yield from value_cases()
    yield from order_cases()
    yield from metadata_cases()
    yield from channel_cases()
    yield from harmless_cases()
    yield from bomb_cases()
    yield from container_cases()


# ------------------------------------------------------------------------------- judging


@dataclass(frozen=True)
class Outcome:
    status: int | None  # None: main() raised
    stderr: str
    same: bool  # status 0 and the log reads as the original does

    @property
    def refused_cleanly(self) -> bool:
        lines = self.stderr.splitlines()
        return self.status == 2 and len(lines) == 1 and "Traceback" not in self.stderr

    @property
    def traceback(self) -> bool:
        return self.status is None or "Traceback" in self.stderr or self.status not in (0, 2)

    def meets(self, expect: str) -> bool:
        if expect == REFUSED:
            return self.refused_cleanly
        if expect == SAME:
            return self.same
        return self.refused_cleanly or self.same


def judge(case: Case, folder: Path, original: Any) -> Outcome:
    """`mmslam inspect` on the case's log, in this process; then whether it reads the same."""
    path = folder / "case.mcap"
    path.write_bytes(case.data)
    out, err = io.StringIO(), io.StringIO()
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            status: int | None = main(["inspect", str(path), "--json"])
    except Exception as exc:  # a traceback, as the user would see it
        return Outcome(None, f"Traceback: {type(exc).__name__}: {exc}", False)
    same = False
    if status == 0:
        try:
            same = read_log(path, load_images=True) == original
        except InputError:
            same = False
    return Outcome(status, err.getvalue(), same)


def run(folder: Path) -> list[tuple[Case, Outcome]]:
    base = folder / "base.mcap"
    base.write_bytes(write_spec(base_spec()))
    original = read_log(base, load_images=True)
    return [(case, judge(case, folder, original)) for case in all_cases()]


def figures(results: list[tuple[Case, Outcome]]) -> str:
    refused = sum(o.refused_cleanly for _, o in results)
    accepted = sum(o.status == 0 for _, o in results)
    tracebacks = sum(o.traceback for _, o in results)
    kinds = sorted({c.kind for c, _ in results})
    missed = [f"{c.kind}: {c.name}" for c, o in results if not o.meets(c.expect)]
    lines = [
        f"{len(results)} cases of {len(kinds)} kinds: {refused} refused cleanly, {accepted} "
        f"accepted ({sum(o.same for _, o in results)} reading the same as the original), "
        f"{tracebacks} tracebacks, {len(missed)} not as expected",
        "by kind: " + ", ".join(f"{k} {sum(c.kind == k for c, _ in results)}" for k in kinds),
    ]
    return "\n".join(lines + missed)


if __name__ == "__main__":
    import tempfile

    with tempfile.TemporaryDirectory() as folder:
        print(figures(run(Path(folder))))
