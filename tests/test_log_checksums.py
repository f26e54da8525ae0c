"""The checksums and sizes an MCAP file states besides the data section's (that one is
test_log_integrity.py's), each checked: a summary CRC, a chunk's CRC or a chunk's size that
does not match what the bytes hold is refused in one line naming it. The data section's CRC is
zeroed where a chunk is changed (a log written without it), so that the chunk's own check is
the one that speaks. And the decompression budget, which the fuzz cases (slow) exercise too."""

from __future__ import annotations

import contextlib
import io
import struct
from pathlib import Path

import pytest

from pipeline.cli import main
from pipeline.log import read_log
from tests.fuzz_logs import _chunk, _data_end, _file_of_chunks, _records_of, _zstd_of_zeros
from tests.synthetic import small_square_log

CHUNK, FOOTER = 0x06, 0x02
CHUNK_HEAD = struct.Struct("<QQQI")  # start, end, uncompressed size, uncompressed CRC


@pytest.fixture(scope="module")
def small_log(tmp_path_factory) -> Path:
    return small_square_log(tmp_path_factory.mktemp("log") / "small.mcap")


def refusal(tmp_path: Path, data: bytes, name: str) -> str:
    """What `mmslam inspect` says of these bytes: exit 2 and one line naming the file."""
    path = tmp_path / name
    path.write_bytes(data)
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        status = main(["inspect", str(path)])
    assert status == 2 and err.getvalue().count("\n") == 1 and str(path) in err.getvalue()
    return err.getvalue()


def without_data_crc(data: bytes) -> bytearray:
    out = bytearray(data)
    struct.pack_into("<I", out, _data_end(data) + 9, 0)
    return out


def first_chunk(data: bytes) -> int:
    """Offset of the first chunk record's body."""
    return next(o for o, opcode, _ in _records_of(data) if opcode == CHUNK) + 9


def test_a_summary_crc_that_does_not_match_is_named(tmp_path, small_log):
    data = bytearray(small_log.read_bytes())
    footer = next(o for o, opcode, _ in _records_of(bytes(data)) if opcode == FOOTER)
    (stated,) = struct.unpack_from("<I", data, footer + 9 + 16)
    assert stated != 0  # our writer states it
    struct.pack_into("<I", data, footer + 9 + 16, stated ^ 1)
    assert "summary CRC" in refusal(tmp_path, bytes(data), "summary.mcap")


def test_a_chunk_crc_that_does_not_match_is_named(tmp_path, small_log):
    data = without_data_crc(small_log.read_bytes())
    chunk = first_chunk(bytes(data))
    start, end, size, crc = CHUNK_HEAD.unpack_from(data, chunk)
    assert crc != 0  # our writer states it
    CHUNK_HEAD.pack_into(data, chunk, start, end, size, crc ^ 1)
    assert "chunk CRC" in refusal(tmp_path, bytes(data), "chunk-crc.mcap")


@pytest.mark.parametrize("change", [-1, 1])
def test_a_chunk_that_inflates_to_another_size_than_it_claims_is_named(tmp_path, small_log, change):
    data = without_data_crc(small_log.read_bytes())
    chunk = first_chunk(bytes(data))
    start, end, size, crc = CHUNK_HEAD.unpack_from(data, chunk)
    CHUNK_HEAD.pack_into(data, chunk, start, end, size + change, crc)
    assert f"not the {size + change} it claims" in refusal(tmp_path, bytes(data), "size.mcap")


def test_the_unchanged_log_without_its_data_crc_reads_the_same(tmp_path, small_log):
    """The cases above change one field each: the rest is a log that reads."""
    data = without_data_crc(small_log.read_bytes())
    chunk = first_chunk(bytes(data))
    *_, size, crc = CHUNK_HEAD.unpack_from(data, chunk)
    assert size > 0 and crc != 0
    path = tmp_path / "same.mcap"
    path.write_bytes(data)
    assert read_log(path) == read_log(small_log)


def test_chunks_each_under_the_cap_that_inflate_past_the_budget_are_a_bomb(tmp_path):
    """Twenty chunks of 9 MiB each (under the 128 MiB a chunk may hold) in a file of a few
    kilobytes: 180 MiB is past the budget (16 MiB plus 100 times the file), refused as a bomb
    before the rest is inflated."""
    mib = 2**20
    one_record = _zstd_of_zeros(9 * mib, struct.pack("<BQ", 0x80, 9 * mib - 9))
    data = _file_of_chunks([_chunk("zstd", one_record, 9 * mib)] * 20)
    assert 16 * mib + 100 * len(data) < 180 * mib
    assert "decompression bomb" in refusal(tmp_path, data, "bomb.mcap")
