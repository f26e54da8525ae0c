"""Suite-wide hooks: the marks of the tests in files others are editing; where the development
data must be there (CI), a test that skips for want of it fails instead."""

from __future__ import annotations

import os

import pytest

from tests.real_data import ABSENT, REQUIRE_ENV

# Marks for tests/test_backend.py and tests/test_solver.py, kept here while those files are
# the back-end's to change (they can move onto the tests themselves): test name -> its marks.
# slow: over about 3 s on a 2-core machine; e2e: runs a whole replay, sweep or front-end.
MARKS_ELSEWHERE = {
    "tests/test_backend.py": {
        "test_known_association_is_exact_on_noise_free_data": ("e2e",),
        "test_every_method_maps_a_noisy_loop": ("e2e",),
        "test_wrong_loop_closure_accepted_by_ml_is_rejected_by_the_null_hypothesis": ("e2e",),
        "test_max_mixture_switches_component_when_the_estimate_moves": ("e2e",),
        "test_class_posterior_follows_the_reports": ("e2e",),
        "test_same_input_gives_byte_identical_outputs": ("e2e",),
        "test_keyframes_without_detections_before_the_first_landmark": ("e2e",),
        "test_an_understated_odometry_is_found_and_reweighted": ("slow", "e2e"),
        "test_an_overstated_start_comes_down_to_what_the_windows_say": ("slow", "e2e"),
        "test_loops_close_where_the_log_understates_its_drift": ("slow", "e2e"),
    },
    "tests/test_solver.py": {
        # the three share one planar log, made by the first that runs
        "test_a_planar_log_with_stiff_odometry_replays": ("slow", "e2e"),
        "test_a_diverged_estimate_ends_in_one_line": ("e2e",),
        "test_known_association_solves_a_bent_loop_without_a_fallback": ("slow", "e2e"),
    },
}


def pytest_collection_modifyitems(config, items):
    for item in items:
        path, _, name = item.nodeid.partition("::")
        for mark in MARKS_ELSEWHERE.get(path, {}).get(name.split("[")[0], ()):
            item.add_marker(getattr(pytest.mark, mark))


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
