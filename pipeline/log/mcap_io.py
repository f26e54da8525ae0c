"""Reading and writing contract-v1 detection logs (MCAP, JSON messages).

The reader checks everything docs/log-format.md lists and raises `LogError` naming the topic
and the message position (0-based, within its topic) of the first problem. The writer writes to
a temporary name and renames into place, so a failed run never leaves a half-written log.
"""

from __future__ import annotations

import json
import logging
import math
import os
import tempfile
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcap.records import Channel, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from pipeline.errors import LogError
from pipeline.log import codec, schemas
from pipeline.log.messages import (
    FORMAT_VERSION,
    METADATA_NAME,
    CompressedImage,
    DetectionLog,
    Detections,
    GroundTruthLandmarks,
    GroundTruthPose,
    LogMetadata,
    Odometry,
    StereoCalibration,
)

logger = logging.getLogger(__name__)

ROW_SUM_TOLERANCE = 1e-6
FOXGLOVE_TOPICS = "/foxglove/"

_ENCODERS = {
    Odometry: (schemas.ODOMETRY, codec.encode_odometry),
    Detections: (schemas.DETECTIONS, codec.encode_detections),
    GroundTruthPose: (schemas.GT_POSE, codec.encode_ground_truth_pose),
    GroundTruthLandmarks: (schemas.GT_LANDMARKS, codec.encode_ground_truth_landmarks),
    StereoCalibration: (schemas.CALIBRATION, codec.encode_calibration),
    CompressedImage: (None, codec.encode_compressed_image),
}


def atomic_output(path: Path) -> tuple[int, Path]:
    """A temporary file beside `path`, to be renamed onto it once complete."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".part", dir=path.parent)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; the result should be like any new file
    return fd, Path(tmp)


class LogWriter:
    """Writes a log; use as a context manager. Messages go in the order they are written.

    With `foxglove` (the default), Foxglove's well-known messages are written beside the
    contract's topics (`pipeline/foxglove/log_topics.py`), so that the log shows in Foxglove."""

    def __init__(self, path: str | os.PathLike, metadata: LogMetadata, foxglove: bool = True):
        self.path = Path(path)
        self.metadata = metadata
        fd, self._tmp = atomic_output(self.path)
        self._file = os.fdopen(fd, "wb")
        self._writer = Writer(self._file, compression=CompressionType.ZSTD)
        self._writer.start(profile="", library="mmslam")
        self._channels: dict[str, int] = {}
        self._writer.add_metadata(METADATA_NAME, metadata_record(metadata))
        self._foxglove = None
        if foxglove:
            from pipeline.foxglove.channels import FoxgloveChannels
            from pipeline.foxglove.log_topics import LogMirror

            self._foxglove = LogMirror(FoxgloveChannels(self._writer), metadata)

    def _channel(self, topic: str) -> int:
        if topic not in self._channels:
            name, _ = schemas.SCHEMAS[topic]
            schema_id = self._writer.register_schema(
                name=name, encoding="jsonschema", data=schemas.schema_bytes(topic)
            )
            self._channels[topic] = self._writer.register_channel(
                topic=topic, message_encoding="json", schema_id=schema_id
            )
        return self._channels[topic]

    def write(self, msg: Any, topic: str | None = None) -> None:
        """Write one message; `topic` is needed only for images (left or right)."""
        default_topic, encode = _ENCODERS[type(msg)]
        topic = topic or default_topic
        if topic is None:
            raise ValueError("images need a topic")
        data = json.dumps(encode(msg), separators=(",", ":"), allow_nan=False).encode()
        self._writer.add_message(
            channel_id=self._channel(topic),
            log_time=msg.stamp_ns,
            publish_time=msg.stamp_ns,
            data=data,
            sequence=0,
        )
        if self._foxglove is not None:
            self._foxglove.write(msg)

    def close(self) -> None:
        if self._foxglove is not None:
            self._foxglove.finish()
        self._writer.finish()
        self._file.close()
        os.replace(self._tmp, self.path)

    def abort(self) -> None:
        self._file.close()
        self._tmp.unlink(missing_ok=True)

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def metadata_record(metadata: LogMetadata) -> dict[str, str]:
    return {
        "format_version": metadata.format_version,
        "num_classes": str(metadata.num_classes),
        "confusion_matrix": json.dumps([list(row) for row in metadata.confusion_matrix]),
        "class_names": json.dumps(list(metadata.class_names)),
        "source": metadata.source,
    }


def parse_metadata(record: dict[str, str]) -> LogMetadata:
    """The `mmslam` metadata record, checked; raises ValueError with the reason."""
    for key in ("format_version", "num_classes", "confusion_matrix", "class_names", "source"):
        if key not in record:
            raise ValueError(f"metadata '{METADATA_NAME}' lacks '{key}'")
    if record["format_version"] != FORMAT_VERSION:
        raise ValueError(
            f"format_version {record['format_version']!r} is not supported (expected "
            f"{FORMAT_VERSION!r})"
        )
    try:
        num_classes = int(record["num_classes"])
    except ValueError:
        raise ValueError(f"num_classes {record['num_classes']!r} is not an integer") from None
    if num_classes < 1:
        raise ValueError(f"num_classes must be >= 1, got {num_classes}")
    try:
        matrix = json.loads(record["confusion_matrix"])
        names = json.loads(record["class_names"])
    except json.JSONDecodeError as exc:
        raise ValueError(f"metadata is not valid JSON ({exc.msg})") from None
    if (
        not isinstance(matrix, list)
        or len(matrix) != num_classes
        or any(not isinstance(row, list) or len(row) != num_classes for row in matrix)
    ):
        raise ValueError(f"confusion_matrix must be {num_classes} x {num_classes}")
    for i, row in enumerate(matrix):
        for v in row:
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise ValueError(f"confusion_matrix row {i} holds a non-finite or non-number")
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"confusion_matrix row {i} holds {v}, outside 0..1")
        if abs(sum(row) - 1.0) > ROW_SUM_TOLERANCE:
            raise ValueError(f"confusion_matrix row {i} sums to {sum(row):.9g}, not 1")
    if not isinstance(names, list) or len(names) != num_classes:
        raise ValueError(f"class_names must be a list of {num_classes} names")
    return LogMetadata(
        num_classes=num_classes,
        confusion_matrix=tuple(tuple(float(v) for v in row) for row in matrix),
        class_names=tuple(str(n) for n in names),
        source=record["source"],
        format_version=record["format_version"],
    )


@dataclass
class TopicInfo:
    topic: str
    schema_name: str
    schema_encoding: str
    message_encoding: str
    count: int = 0
    first_ns: int | None = None
    last_ns: int | None = None


@dataclass
class RawLog:
    """What the MCAP records say, before the messages are decoded."""

    path: str
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    topics: dict[str, TopicInfo] = field(default_factory=dict)
    messages: list[tuple[str, int, int, bytes]] = field(default_factory=list)  # topic, idx, t, data


def scan_log(path: str | os.PathLike, keep_topics: frozenset[str] | None = None) -> RawLog:
    """Read every record of an MCAP file; raises LogError if it is not whole."""
    path_str = str(path)
    raw = RawLog(path=path_str)
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    last: tuple[str, int] | None = None
    try:
        with open(path, "rb") as stream:
            for record in StreamReader(stream, validate_crcs=True).records:
                if isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel):
                    channels[record.id] = record
                    if record.topic not in raw.topics:
                        schema = schemas.get(record.schema_id)
                        raw.topics[record.topic] = TopicInfo(
                            topic=record.topic,
                            schema_name=schema.name if schema else "",
                            schema_encoding=schema.encoding if schema else "",
                            message_encoding=record.message_encoding,
                        )
                elif isinstance(record, Message):
                    channel = channels.get(record.channel_id)
                    if channel is None:
                        raise LogError(
                            path_str, f"message on unknown channel id {record.channel_id}"
                        )
                    info = raw.topics[channel.topic]
                    index = info.count
                    info.count += 1
                    info.first_ns = (
                        record.log_time
                        if info.first_ns is None
                        else min(info.first_ns, record.log_time)
                    )
                    info.last_ns = (
                        record.log_time
                        if info.last_ns is None
                        else max(info.last_ns, record.log_time)
                    )
                    last = (channel.topic, index)
                    if keep_topics is None or channel.topic in keep_topics:
                        raw.messages.append((channel.topic, index, record.log_time, record.data))
                elif isinstance(record, Metadata):
                    raw.metadata[record.name] = dict(record.metadata)
    except FileNotFoundError:
        raise LogError(path_str, "no such file") from None
    except IsADirectoryError:
        raise LogError(path_str, "is a directory, not an MCAP file") from None
    except LogError:
        raise
    except Exception as exc:  # the mcap library raises several kinds on broken files
        after = f" after {last[0]} message {last[1]}" if last else ""
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise LogError(path_str, f"file is truncated or corrupt{after} ({reason})") from None
    return raw


def _check_channels(raw: RawLog) -> None:
    for topic, info in raw.topics.items():
        if topic.startswith(FOXGLOVE_TOPICS):
            continue  # the log as Foxglove shows it (pipeline/foxglove), beside the contract's
        if topic not in schemas.SCHEMAS:
            logger.info("%s: ignoring unknown topic %s", raw.path, topic)
            continue
        expected = schemas.SCHEMAS[topic][0]
        if info.schema_name != expected:
            raise LogError(
                raw.path, f"schema is {info.schema_name!r}, expected {expected!r}", topic
            )
        if info.message_encoding != "json":
            raise LogError(
                raw.path, f"message encoding is {info.message_encoding!r}, expected 'json'", topic
            )
        if info.schema_encoding != "jsonschema":
            raise LogError(
                raw.path,
                f"schema encoding is {info.schema_encoding!r}, expected 'jsonschema'",
                topic,
            )


def read_log(path: str | os.PathLike, load_images: bool = False) -> DetectionLog:
    """Read and validate a whole log. Raises LogError on the first problem."""
    raw = scan_log(path, keep_topics=frozenset(schemas.SCHEMAS))  # the contract's topics
    return decode_log(raw, load_images=load_images)


def decode_log(raw: RawLog, load_images: bool = False) -> DetectionLog:
    path = raw.path
    if METADATA_NAME not in raw.metadata:
        raise LogError(path, f"no metadata record named '{METADATA_NAME}'")
    try:
        metadata = parse_metadata(raw.metadata[METADATA_NAME])
    except ValueError as exc:
        raise LogError(path, str(exc), f"metadata '{METADATA_NAME}'") from None
    _check_channels(raw)

    log = DetectionLog(metadata=metadata, odometry=[], detections=[])
    decoders = {
        schemas.ODOMETRY: codec.decode_odometry,
        schemas.DETECTIONS: lambda o: codec.decode_detections(o, metadata.num_classes),
        schemas.GT_POSE: codec.decode_ground_truth_pose,
        schemas.GT_LANDMARKS: lambda o: codec.decode_ground_truth_landmarks(
            o, metadata.num_classes
        ),
        schemas.CALIBRATION: codec.decode_calibration,
        schemas.LEFT_IMAGE: codec.decode_compressed_image,
        schemas.RIGHT_IMAGE: codec.decode_compressed_image,
    }
    gt_indices: set[int] = set()
    image_counts: Counter[str] = Counter()
    for topic, index, log_time, data in raw.messages:
        if topic not in decoders:
            continue
        try:
            obj = json.loads(data, parse_constant=_reject_constant)
            if not isinstance(obj, dict):
                raise ValueError("message is not a JSON object")
            msg = decoders[topic](obj)
        except json.JSONDecodeError as exc:
            raise LogError(path, f"malformed JSON ({exc.msg})", topic, index) from None
        except ValueError as exc:
            raise LogError(path, str(exc), topic, index) from None
        if msg.stamp_ns != log_time:
            raise LogError(
                path, f"log_time {log_time} differs from stamp_ns {msg.stamp_ns}", topic, index
            )
        if topic == schemas.ODOMETRY:
            expected = len(log.odometry)
            if msg.from_index != expected or msg.to_index != expected + 1:
                raise LogError(
                    path,
                    f"links pose {msg.from_index} to {msg.to_index}; expected {expected} to "
                    f"{expected + 1}",
                    topic,
                    index,
                )
            log.odometry.append(msg)
        elif topic == schemas.DETECTIONS:
            log.detections.append((index, msg))  # type: ignore[arg-type]
        elif topic == schemas.GT_POSE:
            if msg.pose_index in gt_indices:
                raise LogError(path, f"pose {msg.pose_index} given twice", topic, index)
            gt_indices.add(msg.pose_index)
            log.ground_truth_poses.append((index, msg))  # type: ignore[arg-type]
        elif topic == schemas.GT_LANDMARKS:
            if log.ground_truth_landmarks is not None:
                raise LogError(
                    path, "only one ground-truth landmark message is allowed", topic, index
                )
            ids = [lm.id for lm in msg.landmarks]
            if len(set(ids)) != len(ids):
                raise LogError(path, "landmark ids are not unique", topic, index)
            log.ground_truth_landmarks = msg
        elif topic == schemas.CALIBRATION:
            if log.calibration is not None:
                raise LogError(path, "only one calibration message is allowed", topic, index)
            log.calibration = msg
        else:
            image_counts[topic] += 1
            if load_images:
                log.images.setdefault(topic, []).append(msg)

    # Pose indices can only be checked once all odometry is known.
    num_poses = len(log.odometry) + 1
    for name, attr in ((schemas.DETECTIONS, "detections"), (schemas.GT_POSE, "ground_truth_poses")):
        checked = []
        for index, msg in getattr(log, attr):
            if msg.pose_index >= num_poses:
                raise LogError(
                    path,
                    f"pose_index {msg.pose_index} is not reached by odometry (poses 0.."
                    f"{num_poses - 1})",
                    name,
                    index,
                )
            checked.append(msg)
        setattr(log, attr, checked)
    log.ground_truth_poses.sort(key=lambda m: m.pose_index)
    log.image_counts = dict(image_counts)
    return log


def _reject_constant(name: str) -> float:
    raise ValueError(f"non-finite number {name} in JSON")
