"""The fuzz of issue 13's cases about the container's structure, fast: each refused by `mmslam
inspect` in one line, or read as the original (test_fuzz.py runs every case, marked slow).
Without the byte flips and truncations at random, these are the cases that name one check each:
bytes after the closing magic, no header first, a second channel for a topic, and the harmless
layouts (chunk sizes, compressions, no summary, no CRCs) that must read the same. (The
decompression bombs take seconds to build: test_log_checksums.py has one, test_fuzz.py all.)"""

from __future__ import annotations

import pytest

from tests import fuzz_logs
from tests.fuzz_logs import read_log, write_spec

CASES = [
    *fuzz_logs.container_cases(count_flips=0, count_cuts=0),
    *fuzz_logs.channel_cases(),
    *fuzz_logs.harmless_cases(),
]


@pytest.fixture(scope="module")
def original(tmp_path_factory):
    base = tmp_path_factory.mktemp("fuzz") / "base.mcap"
    base.write_bytes(write_spec(fuzz_logs.base_spec()))
    return read_log(base, load_images=True)


@pytest.mark.parametrize("case", CASES, ids=lambda c: f"{c.kind}: {c.name}")
def test_a_structural_case_is_refused_in_one_line_or_reads_the_same(tmp_path, original, case):
    outcome = fuzz_logs.judge(case, tmp_path, original)
    assert outcome.meets(case.expect), outcome.stderr
