"""Where the development data must be there (MMSLAM_REQUIRE_REAL_DATA=1, as in CI), a test that
skips for want of it fails; other skips stay skips."""

from tests.real_data import REQUIRE_ENV

SUITE = """
import pytest
from tests import real_data

@real_data.needs(real_data.REAL_DATA / "no-such-folder")
def test_marked():
    pass

def test_skipped_inside():
    real_data.skip_unless_present(real_data.REAL_DATA / "no-such-file.png")

def test_skipped_for_another_reason():
    pytest.skip("a reason of its own")

def test_passing():
    pass
"""


def run(pytester, monkeypatch, required: bool):
    pytester.makeconftest("from tests.conftest import pytest_runtest_makereport  # noqa: F401")
    pytester.makepyfile(SUITE)
    if required:
        monkeypatch.setenv(REQUIRE_ENV, "1")
    else:
        monkeypatch.delenv(REQUIRE_ENV, raising=False)
    return pytester.runpytest("-p", "no:cacheprovider")


def test_without_the_requirement_a_missing_file_skips(pytester, monkeypatch):
    run(pytester, monkeypatch, required=False).assert_outcomes(passed=1, skipped=3)


def test_with_the_requirement_a_missing_file_fails_and_says_why(pytester, monkeypatch):
    result = run(pytester, monkeypatch, required=True)
    # a skip at setup (a marker, a fixture) becomes an error, one in the test's body a
    # failure: either fails the run
    result.assert_outcomes(passed=1, errors=1, failed=1, skipped=1)
    assert result.ret != 0
    result.stdout.fnmatch_lines(
        [f"*the development data*is absent: no *no-such-folder*{REQUIRE_ENV}=1*"]
    )
