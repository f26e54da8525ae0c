"""The MCAP container's structural checks (`log/mcap_stream.py`), each on a log changed by hand
in the one place it checks, and refused in one line naming what is wrong: no header first, a
record running past the file's end or past its chunk, a channel defined twice differently; and
the time span `inspect` reports, against mcap's own reader. The logs are written uncompressed,
a chunk a message, without CRCs, so that a change reaches the check it is for."""

from __future__ import annotations

import contextlib
import io
import json
import struct
from pathlib import Path

from mcap.reader import make_reader
from mcap.writer import CompressionType

from pipeline.cli import main
from tests.fuzz_logs import _records_of, _with

CHUNK, CHANNEL = 0x06, 0x04
CHUNK_HEAD = 8 + 8 + 8 + 4  # start, end, uncompressed size, CRC


def plain() -> bytearray:
    def layout(spec):
        spec.compression, spec.chunk_size = CompressionType.NONE, 1
        spec.crcs, spec.data_crc = False, False

    return bytearray(_with(layout))


def inspect(tmp_path: Path, data: bytes, *options: str) -> tuple[int, str, str]:
    path = tmp_path / "log.mcap"
    path.write_bytes(data)
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
        status = main(["inspect", str(path), *options])
    return status, out.getvalue(), err.getvalue()


def refused(tmp_path: Path, data: bytes) -> str:
    status, _, err = inspect(tmp_path, data)
    assert status == 2 and err.count("\n") == 1, err
    return err


def chunk_records(data: bytes, chunk: int) -> list[tuple[int, int, int]]:
    """(offset in the file, opcode, length with head) of the records inside the chunk record
    at `chunk` (uncompressed)."""
    body = chunk + 9
    (name_length,) = struct.unpack_from("<I", data, body + CHUNK_HEAD)
    start = body + CHUNK_HEAD + 4 + name_length + 8
    (size,) = struct.unpack_from("<Q", data, start - 8)
    out, offset = [], start
    while offset < start + size:
        length = 9 + struct.unpack_from("<Q", data, offset + 1)[0]
        out.append((offset, data[offset], length))
        offset += length
    return out


def test_the_plain_log_reads(tmp_path):
    assert inspect(tmp_path, bytes(plain()))[0] == 0


def test_a_file_whose_first_record_is_not_a_header_is_refused(tmp_path):
    data = plain()
    header_end = 8 + 9 + struct.unpack_from("<Q", data, 9)[0]
    err = refused(tmp_path, bytes(data[:8] + data[header_end:]))
    assert "first record is not a header" in err


def test_a_record_running_past_the_file_s_end_is_refused(tmp_path):
    data = plain()
    offset, _, length = _records_of(bytes(data))[-1]  # the footer
    struct.pack_into("<Q", data, offset + 1, length - 9 + 100)
    assert "ends inside a record" in refused(tmp_path, bytes(data))


def test_a_record_running_past_its_chunk_is_refused(tmp_path):
    data = plain()
    chunk = next(o for o, opcode, _ in _records_of(bytes(data)) if opcode == CHUNK)
    offset, _, length = chunk_records(bytes(data), chunk)[-1]
    struct.pack_into("<Q", data, offset + 1, length - 9 + 1)
    assert "runs past the chunk" in refused(tmp_path, bytes(data))


def test_a_channel_defined_twice_differently_is_refused(tmp_path):
    """A log without chunks or summary: its first channel record stated again right after
    it, once as it is (harmless) and once with its topic changed by one letter."""

    def layout(spec):
        spec.chunked, spec.summary, spec.crcs, spec.data_crc = False, False, False, False

    data = _with(layout)
    offset, _, length = next(r for r in _records_of(data) if r[1] == CHANNEL)
    (channel_id,) = struct.unpack_from("<H", data, offset + 9)
    (topic_length,) = struct.unpack_from("<I", data, offset + 9 + 4)
    record = bytearray(data[offset : offset + length])

    def stated_again(record: bytes) -> bytes:
        out = bytearray(data[: offset + length] + record + data[offset + length :])
        footer = len(out) - 8 - 20  # the footer's body: where the summary starts, moved on
        struct.pack_into("<Q", out, footer, struct.unpack_from("<Q", out, footer)[0] + length)
        return bytes(out)

    assert inspect(tmp_path, stated_again(bytes(record)))[0] == 0
    record[9 + 8 + topic_length - 1] ^= 1
    err = refused(tmp_path, stated_again(bytes(record)))
    assert f"channel id {channel_id} is defined twice, differently" in err


def test_the_time_span_is_from_the_first_message_to_the_last(tmp_path):
    """A topic the contract does not know (harmless) whose two messages come first, a quarter
    of the first stamp apart: the span runs from the first of them, as mcap's own reader
    reads the times."""

    def early_topic(spec):
        first = min(m[2] for m in spec.messages)
        spec.channels["extra"] = ("/lidar/points", "foo.Bar", "protobuf", "cdr")
        for k, stamp in enumerate((first // 4, first // 2)):
            spec.messages.insert(k, ["extra", b"\x00\x01 anything", stamp])

    data = _with(early_topic)
    path = tmp_path / "log.mcap"
    path.write_bytes(data)
    with path.open("rb") as f:
        times = [message.log_time for _, _, message in make_reader(f).iter_messages()]
    status, out, _ = inspect(tmp_path, data, "--json")
    assert status == 0
    span = (max(times) - min(times)) / 1e9
    assert span > (max(times) - min(times[2:])) / 1e9 + 0.1  # the early topic counts
    assert abs(json.loads(out)["time_span_s"] - span) < 1e-9
