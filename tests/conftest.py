"""Suite-wide hooks: where the development data must be there (CI), a test that skips for want
of it fails instead. And hypothesis's settings for the property-based tests."""

from __future__ import annotations

import os

import pytest
from hypothesis import HealthCheck, settings

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


# The same examples on every run (a failure seen once is seen again), no example database in the
# tree, and no timing: a shared 2-core machine makes any deadline or "slow input" check flaky.
settings.register_profile(
    "mmslam",
    derandomize=True,
    database=None,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.load_profile("mmslam")

# pytester runs small suites in-process: how the hook above is tested (test_real_data.py)
pytest_plugins = ["pytester"]
