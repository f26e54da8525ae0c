"""Writing a contract-v1 log: MCAP with JSON messages, all-or-nothing.

Every message goes through the reader's own checks (`validate.py`) before it is written, so a
log this writer completes is one the reader accepts; a message that fails them is an
`InputError` and nothing is written. The file appears only once complete (`AtomicFile`), with
MCAP's CRCs over its chunks, its data section and its summary. A caller may hand it a mirror
that writes more beside the contract's topics, from the messages that passed the checks:
Foxglove's well-known messages under `/foxglove/` (`foxglove_mirror` of
`pipeline/foxglove/log_topics.py`), so that the log shows in Foxglove; readers skip them. The
mirror is handed in, not imported: this layer knows nothing of the ones above it.
"""

from __future__ import annotations

import json
import os
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any, BinaryIO, Protocol

from mcap.writer import CompressionType, Writer

from pipeline.errors import InputError, LogError
from pipeline.log import codec, schemas
from pipeline.log.mcap_stream import ChannelInfo
from pipeline.log.messages import (
    METADATA_NAME,
    CompressedImage,
    LogMetadata,
)
from pipeline.log.metadata import metadata_record, parse_metadata
from pipeline.log.validate import LogValidator
from pipeline.outputs import AtomicFile

# The topic of each message type (images go to the one the caller names).
_TOPICS: dict[type, str | None] = {cls: topic for topic, (_, cls) in schemas.MESSAGES.items()}
_TOPICS[CompressedImage] = None


def mcap_writer(file: BinaryIO) -> Writer:
    """An MCAP writer as every mmslam file is written: zstd chunks, and CRCs over the chunks,
    the data section (`DataEnd`, which mcap's writer leaves at 0 unless asked) and the summary,
    so that a flipped bit anywhere is refused on reading."""
    return Writer(file, compression=CompressionType.ZSTD, enable_crcs=True, enable_data_crcs=True)


class Mirror(Protocol):
    """Sees every message a log writer has checked and written, in order, and writes its own
    beside them into the same MCAP file."""

    def write(self, msg: Any) -> None: ...

    def finish(self) -> None: ...


# Makes a mirror for the MCAP file a writer opens, given the log's metadata.
MirrorFactory = Callable[[Writer, LogMetadata], Mirror]


class LogWriter:
    """Writes a log; use as a context manager. Messages go in the order they are written.

    With `mirror` (`pipeline.foxglove.log_topics.foxglove_mirror`, say), what it makes of the
    messages is written beside the contract's topics."""

    def __init__(
        self,
        path: str | os.PathLike,
        metadata: LogMetadata,
        mirror: MirrorFactory | None = None,
    ):
        self.path = Path(path)
        self.metadata = metadata
        record = metadata_record(metadata)
        try:
            parse_metadata(record)
        except ValueError as exc:
            raise self._refusal(f"metadata '{METADATA_NAME}': {exc}") from None
        self._validator = LogValidator(str(self.path), metadata)
        self._out = AtomicFile(self.path)
        self._writer = mcap_writer(self._out.file)
        self._writer.start(profile="", library="mmslam")
        self._channels: dict[str, ChannelInfo] = {}
        self._counts: Counter[str] = Counter()
        self._writer.add_metadata(METADATA_NAME, record)
        self._mirror = None if mirror is None else mirror(self._writer, metadata)

    def _refusal(self, detail: str) -> InputError:
        return InputError(f"not writing {self.path}: {detail}")

    def _channel(self, topic: str) -> ChannelInfo:
        if topic not in self._channels:
            name, _ = schemas.SCHEMAS[topic]
            schema_id = self._writer.register_schema(
                name=name, encoding="jsonschema", data=schemas.schema_bytes(topic)
            )
            channel_id = self._writer.register_channel(
                topic=topic, message_encoding="json", schema_id=schema_id
            )
            self._channels[topic] = ChannelInfo(channel_id, topic, name, "jsonschema", "json")
        return self._channels[topic]

    def write(self, msg: Any, topic: str | None = None) -> None:
        """Write one message; `topic` is needed only for images (left or right)."""
        topic = topic or _TOPICS[type(msg)]
        if topic is None:
            raise ValueError("images need a topic")
        index = self._counts[topic]
        self._counts[topic] += 1
        try:
            data = json.dumps(codec.encode(msg), separators=(",", ":"), allow_nan=False).encode()
        except ValueError:
            raise self._refusal(f"{topic} message {index}: holds a non-finite number") from None
        channel = self._channel(topic)
        try:
            self._validator.message(channel, index, msg.stamp_ns, data)
        except LogError as exc:
            raise self._refusal(exc.detail) from None
        self._writer.add_message(
            channel_id=channel.id,
            log_time=msg.stamp_ns,
            publish_time=msg.stamp_ns,
            data=data,
            sequence=0,
        )
        if self._mirror is not None:
            self._mirror.write(msg)

    def close(self) -> None:
        try:
            self._validator.finish(self._channels.values())
        except LogError as exc:
            self.abort()
            raise self._refusal(exc.detail) from None
        try:
            if self._mirror is not None:
                self._mirror.finish()
            self._writer.finish()
        except BaseException:
            self.abort()
            raise
        self._out.commit()

    def abort(self) -> None:
        self._out.discard()

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()
