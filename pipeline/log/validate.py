"""The contract's checks on a log, fed one message at a time in log order.

`LogValidator` decodes each message (`codec.py` checks its fields as `messages.py` declares
them) and checks what spans messages: every channel of a contract topic has the right schema
and encodings (other topics, such as the Foxglove mirror's `/foxglove/*` in protobuf, are
skipped); stamps equal the
MCAP log time and never go back within a topic, odometry's strictly forward; odometry links
pose i to i + 1; a pose's ground truth is given once; one ground-truth landmark message and
one calibration at most; and, at the end, every pose index named is reached by odometry. It
keeps counters, not messages, so the reader, the writer and `inspect` all use it on logs of
any length.
"""

from __future__ import annotations

import functools
import logging
from collections import Counter, deque
from collections.abc import Callable, Iterable
from typing import Any

from pipeline.errors import LogError
from pipeline.log import codec, limits, schemas
from pipeline.log.mcap_stream import ChannelInfo
from pipeline.log.messages import LogMetadata

logger = logging.getLogger(__name__)


class PoseSet:
    """Pose indices seen, one bit each (at most `limits.MAX_POSES`)."""

    def __init__(self) -> None:
        self._bits = bytearray()

    def add(self, index: int) -> bool:
        """Add `index`; False if it was there already."""
        byte, bit = divmod(index, 8)
        if byte >= len(self._bits):
            self._bits.extend(bytes(max(byte + 1 - len(self._bits), len(self._bits))))
        seen = bool(self._bits[byte] >> bit & 1)
        self._bits[byte] |= 1 << bit
        return not seen


class LogValidator:
    """Checks a log message by message; `finish()` makes the whole-log checks."""

    def __init__(self, path: str, metadata: LogMetadata):
        self.path = path
        self.metadata = metadata
        self.odometry_count = 0
        num_classes = metadata.num_classes
        self._decoders: dict[str, Callable[[bytes], Any]] = {
            topic: functools.partial(codec.decode, cls, num_classes=num_classes)
            for topic, (_, cls) in schemas.MESSAGES.items()
        }
        for topic in schemas.IMAGE_TOPICS:
            self._decoders[topic] = codec.decode_compressed_image
        self._checked_channels: set[int] = set()
        self._last_stamp: dict[str, int] = {}
        self._gt_poses = PoseSet()
        self._seen_once: set[str] = set()
        # Per topic naming poses: messages whose pose index was the highest so far and is not
        # reached by the odometry read so far; the first still unreached at the end is the
        # first message of its topic that names a pose odometry never reaches.
        self._unreached: dict[str, deque[tuple[int, int]]] = {
            schemas.DETECTIONS: deque(),
            schemas.GT_POSE: deque(),
        }
        self._highest: dict[str, int] = {}
        self._detections_of: Counter[int] = Counter()  # detections per pose so far

    @property
    def num_poses(self) -> int:
        return self.odometry_count + 1

    def error(self, reason: str, topic: str | None = None, index: int | None = None) -> LogError:
        return LogError(self.path, reason, topic, index)

    def check_channel(self, channel: ChannelInfo) -> None:
        """A channel of a known topic must carry the contract's schema and encodings."""
        if channel.id in self._checked_channels:
            return
        self._checked_channels.add(channel.id)
        topic = channel.topic
        if topic not in schemas.SCHEMAS:
            if not topic.startswith(schemas.FOXGLOVE_PREFIX):  # those are expected: no news
                logger.info("%s: ignoring unknown topic %r", self.path, topic)
            return
        expected = schemas.SCHEMAS[topic][0]
        found = (
            ("schema", channel.schema_name, expected),
            ("schema encoding", channel.schema_encoding, "jsonschema"),
            ("message encoding", channel.message_encoding, "json"),
        )
        for what, value, wanted in found:
            if value != wanted:
                raise self.error(
                    f"{what} is {codec.shown(value)}, expected {wanted!r} (channel {channel.id})",
                    topic,
                )

    def message(self, channel: ChannelInfo, index: int, log_time: int, data: bytes) -> Any:
        """The decoded message (None for a topic the contract does not know); raises
        `LogError` naming the topic and the message's position within it."""
        self.check_channel(channel)
        topic = channel.topic
        decode = self._decoders.get(topic)
        if decode is None:
            return None
        cap = (
            limits.MAX_IMAGE_MESSAGE_BYTES
            if topic in schemas.IMAGE_TOPICS
            else limits.MAX_JSON_MESSAGE_BYTES
        )
        if len(data) > cap:
            raise self.error(f"{len(data)} bytes, more than the {cap} allowed", topic, index)
        try:
            msg = decode(data)
        except ValueError as exc:
            raise self.error(str(exc), topic, index) from None
        if msg.stamp_ns != log_time:
            raise self.error(
                f"log_time {log_time} differs from stamp_ns {msg.stamp_ns}", topic, index
            )
        previous = self._last_stamp.get(topic)
        if previous is not None and msg.stamp_ns < previous:
            raise self.error(
                f"stamp_ns {msg.stamp_ns} is before the previous message's {previous}", topic, index
            )
        self._last_stamp[topic] = msg.stamp_ns
        self._check_links(topic, index, msg, previous)
        return msg

    def _check_links(self, topic: str, index: int, msg: Any, previous_stamp: int | None) -> None:
        if topic == schemas.ODOMETRY:
            expected = self.odometry_count
            if msg.from_index != expected or msg.to_index != expected + 1:
                raise self.error(
                    f"links pose {msg.from_index} to {msg.to_index}; expected {expected} to "
                    f"{expected + 1}",
                    topic,
                    index,
                )
            if previous_stamp is not None and msg.stamp_ns == previous_stamp:
                raise self.error(
                    f"stamp_ns {msg.stamp_ns} repeats the previous pose's: poses need times of "
                    "their own",
                    topic,
                    index,
                )
            self.odometry_count += 1
            for pending in self._unreached.values():
                while pending and pending[0][0] <= self.odometry_count:
                    pending.popleft()
        elif topic in self._unreached:
            if topic == schemas.DETECTIONS:
                self._count_detections(msg, topic, index)
            if topic == schemas.GT_POSE and not self._gt_poses.add(msg.pose_index):
                raise self.error(f"pose {msg.pose_index} given twice", topic, index)
            if msg.pose_index > max(self._highest.get(topic, 0), self.odometry_count):
                self._unreached[topic].append((msg.pose_index, index))
            self._highest[topic] = max(self._highest.get(topic, 0), msg.pose_index)
        elif topic == schemas.GT_LANDMARKS:
            self._once(topic, index, "ground-truth landmark message")
            ids = [lm.id for lm in msg.landmarks]
            if len(set(ids)) != len(ids):
                raise self.error("landmark ids are not unique", topic, index)
        elif topic == schemas.CALIBRATION:
            self._once(topic, index, "calibration message")

    def _count_detections(self, msg: Any, topic: str, index: int) -> None:
        count = self._detections_of[msg.pose_index] + len(msg.detections)
        if count > limits.MAX_DETECTIONS_PER_POSE:
            raise self.error(
                f"pose {msg.pose_index} holds {count} detections, more than the "
                f"{limits.MAX_DETECTIONS_PER_POSE} a keyframe may",
                topic,
                index,
            )
        if msg.detections:
            self._detections_of[msg.pose_index] = count

    def _once(self, topic: str, index: int, what: str) -> None:
        if topic in self._seen_once:
            raise self.error(f"only one {what} is allowed", topic, index)
        self._seen_once.add(topic)

    def finish(self, channels: Iterable[ChannelInfo]) -> None:
        """The whole-log checks, once every message has been read: every channel (also those
        without messages) and every pose index named."""
        for channel in channels:
            self.check_channel(channel)
        for topic, pending in self._unreached.items():
            if pending:
                pose_index, index = pending[0]
                raise self.error(
                    f"pose_index {pose_index} is not reached by odometry (poses 0.."
                    f"{self.num_poses - 1})",
                    topic,
                    index,
                )
