"""Suite-wide hooks: where the development data must be there (CI), a test that skips for want
of it fails instead."""

from __future__ import annotations

import os

import pytest

from tests.real_data import ABSENT, REQUIRE_ENV


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    report = outcome.get_result()
    if os.environ.get(REQUIRE_ENV) != "1" or not report.skipped:
        return
    # a skip's longrepr is (file, line, "Skipped: reason")
    message = report.longrepr[2] if isinstance(report.longrepr, tuple) else str(report.longrepr)
    if ABSENT in message:
        report.outcome = "failed"
        report.longrepr = f"{message.removeprefix('Skipped: ')} ({REQUIRE_ENV}=1: it must be here)"


# pytester runs small suites in-process: how the hook above is tested (test_real_data.py)
pytest_plugins = ["pytester"]
