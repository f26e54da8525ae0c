"""Every byte of a log we wrote is protected: the data section's CRC (`DataEnd`) is written
by every mmslam MCAP writer and checked on reading, so a flipped bit anywhere before it is
refused with exit 2, in one line naming the file. Logs written with no data-section CRC (0)
still read as before."""

from __future__ import annotations

import contextlib
import io
import random
import struct
import zlib
from pathlib import Path

import pytest

from pipeline.cli import main
from pipeline.log import read_log
from pipeline.log.mcap_stream import MAGIC
from tests.fuzz_logs import _data_end, _records_of
from tests.synthetic import small_square_log


def data_section_crc(data: bytes) -> tuple[int, int]:
    """The CRC `DataEnd` states, and the one of the bytes it covers (the magic to DataEnd)."""
    end = _data_end(data)
    (stated,) = struct.unpack_from("<I", data, end + 9)
    return stated, zlib.crc32(data[:end])


@pytest.fixture(scope="module")
def small_log(tmp_path_factory) -> Path:
    return small_square_log(tmp_path_factory.mktemp("log") / "small.mcap")


def inspect(path: Path) -> tuple[int, str]:
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        status = main(["inspect", str(path)])
    return status, err.getvalue()


def test_our_writer_states_the_data_section_crc(small_log):
    stated, computed = data_section_crc(small_log.read_bytes())
    assert stated != 0
    assert stated == computed


def test_a_flipped_bit_anywhere_before_data_end_is_refused(tmp_path, small_log):
    data = small_log.read_bytes()
    end = _data_end(data) + 9 + 4  # through the DataEnd record itself
    rng = random.Random(39)
    # every record's first bytes (opcodes, lengths), then bits drawn all over the section
    offsets = {o + k for o, _, n in _records_of(data) if o < end for k in range(min(n, 12))}
    offsets |= {rng.randrange(end) for _ in range(300)}
    offsets |= set(range(len(MAGIC)))
    flipped_log = tmp_path / "flipped.mcap"
    accepted = []
    for offset in sorted(offsets):
        flipped = bytearray(data)
        flipped[offset] ^= 1 << rng.randrange(8)
        flipped_log.write_bytes(flipped)
        status, err = inspect(flipped_log)
        if status != 2 or err.count("\n") != 1 or str(flipped_log) not in err:
            accepted.append((offset, status, err))
    assert len(offsets) > 300
    assert accepted == []


def test_a_data_section_crc_that_does_not_match_is_named(tmp_path, small_log):
    data = bytearray(small_log.read_bytes())
    end = _data_end(bytes(data))
    struct.pack_into("<I", data, end + 9, data_section_crc(bytes(data))[0] ^ 1)
    bad = tmp_path / "bad-crc.mcap"
    bad.write_bytes(data)
    status, err = inspect(bad)
    assert status == 2 and err.count("\n") == 1
    assert str(bad) in err and "data section CRC" in err


def test_a_log_without_a_data_section_crc_reads_the_same(tmp_path, small_log):
    """A log written before (mcap's default writer leaves DataEnd's CRC at 0)."""
    data = bytearray(small_log.read_bytes())
    struct.pack_into("<I", data, _data_end(bytes(data)) + 9, 0)
    legacy = tmp_path / "legacy.mcap"
    legacy.write_bytes(data)
    assert inspect(legacy)[0] == 0
    assert read_log(legacy) == read_log(small_log)
