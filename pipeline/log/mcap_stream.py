"""A log's MCAP container, read in two streaming passes over one open file.

The first pass reads every record but decompresses nothing: it checks the structure (magic,
header first, data end, footer, nothing after the closing magic), the data-section CRC and
the summary CRC, and collects the metadata records. The second pass decompresses one chunk at
a time, checks its CRC, and yields the messages in file order. Nothing is held but one record
or one chunk, and decompression is capped (`limits.py`), so memory stays bounded whatever the
file's size or what it claims. Every problem is a `LogError` naming the file.
"""

from __future__ import annotations

import io
import logging
import os
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass

import lz4.frame
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Metadata, Schema

from pipeline.errors import LogError, first_line
from pipeline.log import limits

logger = logging.getLogger(__name__)

MAGIC = b"\x89MCAP0\r\n"
_HEAD = struct.Struct("<BQ")  # a record's opcode and length
_MESSAGE = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_CHUNK = struct.Struct("<QQQI")  # start time, end time, uncompressed size, uncompressed CRC
_FOOTER = struct.Struct("<QQI")  # summary start, summary offset start, summary CRC


class CorruptError(Exception):
    """The container is broken; the reader turns it into a `LogError`."""


@dataclass(frozen=True)
class ChannelInfo:
    id: int
    topic: str
    schema_name: str
    schema_encoding: str
    message_encoding: str


@dataclass
class TopicInfo:
    """A topic's channel (its first) and what its messages' log times span."""

    topic: str
    schema_name: str
    schema_encoding: str
    message_encoding: str
    count: int = 0
    first_ns: int | None = None
    last_ns: int | None = None


def _parse(record_type, body: bytes):
    """A record of the mcap library's kind from its body."""
    return record_type.read(ReadDataStream(io.BytesIO(body)))


def _records(data: bytes | memoryview) -> Iterator[tuple[int, memoryview]]:
    """The (opcode, body) records packed in a chunk's uncompressed data."""
    view = memoryview(data)
    offset = 0
    while offset < len(view):
        if offset + _HEAD.size > len(view):
            raise CorruptError("a record inside a chunk is cut short")
        opcode, length = _HEAD.unpack_from(view, offset)
        offset += _HEAD.size
        if length > len(view) - offset:
            raise CorruptError("a record inside a chunk runs past the chunk")
        yield opcode, view[offset : offset + length]
        offset += length


class McapFile:
    """One MCAP file, open for reading; use as a context manager.

    `metadata` holds the data section's metadata records, `channels` the channels met so far
    and `topics` the counts of the messages read so far (all of them once `messages()` ends).
    """

    def __init__(self, path: str | os.PathLike):
        self.path = str(path)
        self.channels: dict[int, ChannelInfo] = {}
        self.topics: dict[str, TopicInfo] = {}
        self.metadata: list[tuple[str, dict[str, str]]] = []
        self._schemas: dict[int, Schema] = {}
        self._channel_records: dict[int, Channel] = {}
        self._inflated = 0
        self._last: tuple[str, int] | None = None
        try:
            self._file = open(path, "rb")  # noqa: SIM115 (closed by close())
        except FileNotFoundError:
            raise LogError(self.path, "no such file") from None
        except IsADirectoryError:
            raise LogError(self.path, "is a directory, not an MCAP file") from None
        except OSError as exc:
            raise LogError(self.path, f"cannot be read ({exc.strerror})") from None
        try:
            self._size = os.fstat(self._file.fileno()).st_size
            self._check_structure()
        except BaseException:
            self._file.close()
            raise

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> McapFile:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()

    # ------------------------------------------------------------------------ the records
    def _top_level(self) -> Iterator[tuple[int, int, bytes, bytes]]:
        """(offset, opcode, head, body) of every record from the start to the footer, which
        must be followed by the closing magic and nothing else."""
        f = self._file
        f.seek(0)
        if f.read(len(MAGIC)) != MAGIC:
            raise CorruptError("not an MCAP file (no MCAP magic at its start)")
        offset = len(MAGIC)
        while True:
            head = f.read(_HEAD.size)
            if len(head) < _HEAD.size:
                raise CorruptError("the file ends before its footer")
            opcode, length = _HEAD.unpack(head)
            if length > limits.MAX_RECORD_BYTES:
                raise CorruptError(
                    f"a record claims {length} bytes (at most {limits.MAX_RECORD_BYTES})"
                )
            if length > self._size - offset - _HEAD.size:
                raise CorruptError("the file ends inside a record")
            body = f.read(length)
            yield offset, opcode, head, body
            offset += _HEAD.size + length
            if opcode == Opcode.FOOTER:
                break
        if f.read(len(MAGIC) + 1) != MAGIC:
            raise CorruptError("the footer is not followed by the closing MCAP magic alone")

    def _check_structure(self) -> None:
        """Pass one: structure, data-section CRC, summary CRC, metadata."""
        try:
            self._check_records()
        except CorruptError as exc:
            raise LogError(self.path, f"file is truncated or corrupt ({exc})") from None
        except Exception as exc:  # the mcap library's parsers raise several kinds on garbage
            reason = first_line(str(exc)) or type(exc).__name__
            raise LogError(self.path, f"file is truncated or corrupt ({reason})") from None

    def _check_records(self) -> None:
        crc = zlib.crc32(MAGIC)
        data_end = None  # offset just past the data-end record
        summary_crc = 0
        for number, (offset, opcode, head, body) in enumerate(self._top_level()):
            if number == 0 and opcode != Opcode.HEADER:
                raise CorruptError("the first record is not a header")
            if data_end is None:
                if opcode == Opcode.DATA_END:
                    if len(body) < 4:
                        raise CorruptError("the data-end record is cut short")
                    (expected,) = struct.unpack_from("<I", body)
                    if expected not in (0, crc):
                        raise CorruptError("data section CRC mismatch")
                    data_end = offset + len(head) + len(body)
                    continue
                if opcode == Opcode.FOOTER:
                    raise CorruptError("no data-end record before the footer")
                crc = zlib.crc32(body, zlib.crc32(head, crc))
                if opcode == Opcode.METADATA:
                    record = _parse(Metadata, body)
                    self.metadata.append((record.name, dict(record.metadata)))
            elif opcode == Opcode.FOOTER:
                if len(body) < _FOOTER.size:
                    raise CorruptError("the footer is cut short")
                start, _, expected = _FOOTER.unpack_from(body)
                if start not in (0, data_end):
                    raise CorruptError(f"the footer puts the summary at {start}, not at {data_end}")
                if start == 0 and offset != data_end:
                    raise CorruptError("records between the data end and a footer without summary")
                summary_crc = zlib.crc32(body[:16], zlib.crc32(head, summary_crc))
                if expected not in (0, summary_crc):
                    raise CorruptError("summary CRC mismatch")
            else:
                summary_crc = zlib.crc32(body, zlib.crc32(head, summary_crc))

    # ----------------------------------------------------------------------- the messages
    def messages(self) -> Iterator[tuple[ChannelInfo, int, int, bytes]]:
        """Pass two: (channel, position in its topic, log time, data) of every message, in
        file order."""
        try:
            for _, opcode, _, body in self._top_level():
                if opcode == Opcode.DATA_END:
                    return
                if opcode == Opcode.CHUNK:
                    for inner, record in _records(self._inflate(body)):
                        yield from self._record(inner, record)
                else:
                    yield from self._record(opcode, body)
        except CorruptError as exc:
            raise LogError(
                self.path, f"file is truncated or corrupt{self._after()} ({exc})"
            ) from None
        except LogError:
            raise
        except Exception as exc:
            reason = first_line(str(exc)) or type(exc).__name__
            raise LogError(
                self.path, f"file is truncated or corrupt{self._after()} ({reason})"
            ) from None

    def _after(self) -> str:
        return f" after {self._last[0]} message {self._last[1]}" if self._last else ""

    def _record(self, opcode: int, body: bytes | memoryview) -> Iterator[tuple]:
        if opcode == Opcode.MESSAGE:
            if len(body) < _MESSAGE.size:
                raise CorruptError("a message record is cut short")
            channel_id, _, log_time, _ = _MESSAGE.unpack_from(body)
            channel = self.channels.get(channel_id)
            if channel is None:
                raise LogError(self.path, f"message on unknown channel id {channel_id}")
            info = self.topics[channel.topic]
            index = info.count
            info.count += 1
            info.first_ns = log_time if info.first_ns is None else min(info.first_ns, log_time)
            info.last_ns = log_time if info.last_ns is None else max(info.last_ns, log_time)
            self._last = (channel.topic, index)
            yield channel, index, log_time, bytes(body[_MESSAGE.size :])
        elif opcode == Opcode.SCHEMA:
            self._add_schema(_parse(Schema, bytes(body)))
        elif opcode == Opcode.CHANNEL:
            self._add_channel(_parse(Channel, bytes(body)))

    def _add_schema(self, schema: Schema) -> None:
        known = self._schemas.setdefault(schema.id, schema)
        if known != schema:
            raise CorruptError(f"schema id {schema.id} is defined twice, differently")

    def _add_channel(self, channel: Channel) -> None:
        known = self._channel_records.setdefault(channel.id, channel)
        if known != channel:
            raise CorruptError(f"channel id {channel.id} is defined twice, differently")
        if channel.id in self.channels:
            return
        schema = self._schemas.get(channel.schema_id)
        if schema is None and channel.schema_id != 0:
            raise CorruptError(
                f"channel id {channel.id} names unknown schema id {channel.schema_id}"
            )
        info = ChannelInfo(
            id=channel.id,
            topic=channel.topic,
            schema_name=schema.name if schema else "",
            schema_encoding=schema.encoding if schema else "",
            message_encoding=channel.message_encoding,
        )
        self.channels[channel.id] = info
        if channel.topic not in self.topics:
            self.topics[channel.topic] = TopicInfo(
                channel.topic, info.schema_name, info.schema_encoding, info.message_encoding
            )

    def _inflate(self, body: bytes) -> bytes:
        """A chunk's records, decompressed within the caps and checked against its CRC."""
        if len(body) < _CHUNK.size + 4:
            raise CorruptError("a chunk record is cut short")
        _, _, size, expected_crc = _CHUNK.unpack_from(body)
        offset = _CHUNK.size
        (name_length,) = struct.unpack_from("<I", body, offset)
        offset += 4
        compression = bytes(body[offset : offset + name_length]).decode("utf-8")
        offset += name_length
        (data_length,) = struct.unpack_from("<Q", body, offset)
        offset += 8
        if data_length != len(body) - offset:
            raise CorruptError("a chunk's data length disagrees with its record")
        data = body[offset:]
        if size > limits.MAX_CHUNK_BYTES:
            raise CorruptError(
                f"a chunk claims {size} bytes uncompressed (at most {limits.MAX_CHUNK_BYTES})"
            )
        self._inflated += size
        budget = limits.INFLATION_FLOOR_BYTES + limits.MAX_INFLATION * self._size
        if self._inflated > budget:
            raise CorruptError(
                f"decompresses to more than {budget} bytes ({limits.MAX_INFLATION}x the file "
                f"plus {limits.INFLATION_FLOOR_BYTES}): a decompression bomb"
            )
        if compression == "":
            raw = data
        elif compression == "zstd":
            with zstandard.ZstdDecompressor().stream_reader(data, read_across_frames=True) as r:
                raw = r.read(size + 1)  # one byte more than claimed tells a lie
        elif compression == "lz4":
            raw = lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=size + 1)
        else:
            raise CorruptError(f"unsupported chunk compression {compression[:20]!r}")
        if len(raw) != size:
            raise CorruptError(f"a chunk inflates to {len(raw)} bytes, not the {size} it claims")
        if expected_crc != 0 and zlib.crc32(raw) != expected_crc:
            raise CorruptError("chunk CRC mismatch")
        return raw
