"""The development data of ../shared/data/real (real photos, a KITTI clip and object frame,
Middlebury's teddy): tests that need it skip where it is absent, and fail instead where it must
be there (`MMSLAM_REQUIRE_REAL_DATA=1`, as `.ci/run` sets: tests/conftest.py turns the skip
into a failure)."""

from __future__ import annotations

from pathlib import Path

import pytest

from data_tools.bench_frontend import REAL_DATA

REQUIRE_ENV = "MMSLAM_REQUIRE_REAL_DATA"
# Every skip for want of the data says this, so that the conftest hook can tell it from others.
ABSENT = "the development data (../shared/data/real) is absent"


def reason(path: Path) -> str:
    return f"{ABSENT}: no {path}"


def needs(path: Path) -> pytest.MarkDecorator:
    """A test that needs `path`, a file or folder of the development data."""
    return pytest.mark.skipif(not Path(path).exists(), reason=reason(path))


def skip_unless_present(path: Path) -> None:
    """Inside a test or fixture: skip it if `path` is absent."""
    if not Path(path).exists():
        pytest.skip(reason(path))


__all__ = ["ABSENT", "REAL_DATA", "REQUIRE_ENV", "needs", "reason", "skip_unless_present"]
