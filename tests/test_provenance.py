"""Provenance: `mmslam --version` and run.json name the commit of the checkout they run from,
whether it was dirty, and the libraries' versions."""

from __future__ import annotations

import datetime
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import pipeline
from pipeline import provenance

PACKAGE = Path(pipeline.__file__).resolve().parent

pytestmark = pytest.mark.skipif(shutil.which("git") is None, reason="needs git")


def git(root: Path, *args: str) -> str:
    done = subprocess.run(
        ["git", "-C", str(root), "-c", "user.name=t", "-c", "user.email=t@t", *args],
        capture_output=True,
        text=True,
        check=True,
    )
    return done.stdout.strip()


@pytest.fixture
def checkout(tmp_path):
    """A git repository holding a copy of the package, committed once."""
    root = tmp_path / "checkout"
    shutil.copytree(PACKAGE, root / "pipeline", ignore=shutil.ignore_patterns("__pycache__"))
    git(root.parent, "init", "-q", str(root))
    git(root, "add", "pipeline")
    git(root, "commit", "-q", "-m", "first")
    return root


def run_copy(root: Path, *args: str) -> str:
    """Run Python with the copy of the package in `root` first on the path."""
    env = {**os.environ, "PYTHONPATH": str(root)}
    done = subprocess.run(
        [sys.executable, *args], cwd=root, env=env, capture_output=True, text=True, check=True
    )
    return done.stdout


def version_of(root: Path) -> str:
    return run_copy(root, "-m", "pipeline.cli", "--version")


RUN_JSON = (
    "import datetime, sys; from pipeline.provenance import run_json; "
    "sys.stdout.write(run_json({}, [], datetime.datetime.now(datetime.UTC), 0.0))"
)


def test_two_commits_give_different_versions_and_run_records(checkout):
    first_commit = git(checkout, "rev-parse", "HEAD")
    first_version = version_of(checkout)
    first_record = json.loads(run_copy(checkout, "-c", RUN_JSON))
    assert first_commit[:12] in first_version and "dirty" not in first_version
    assert first_record["git_commit"] == first_commit
    assert first_record["git_dirty"] is False

    init = checkout / "pipeline" / "__init__.py"
    init.write_text(init.read_text() + "# changed\n")
    dirty_version = version_of(checkout)
    assert first_commit[:12] in dirty_version and "dirty" in dirty_version
    assert json.loads(run_copy(checkout, "-c", RUN_JSON))["git_dirty"] is True

    git(checkout, "commit", "-q", "-am", "second")
    second_commit = git(checkout, "rev-parse", "HEAD")
    second_version = version_of(checkout)
    second_record = json.loads(run_copy(checkout, "-c", RUN_JSON))
    assert second_commit != first_commit
    assert second_version != first_version
    assert second_commit[:12] in second_version and "dirty" not in second_version
    assert second_record["git_commit"] == second_commit
    assert second_record["git_dirty"] is False


def test_untracked_files_do_not_make_a_checkout_dirty(checkout):
    (checkout / "out").mkdir()
    (checkout / "out" / "run.mcap").write_bytes(b"x")
    state = provenance.git_state(checkout)
    assert state is not None
    assert state.commit == git(checkout, "rev-parse", "HEAD")
    assert not state.dirty


def test_a_package_inside_another_repository_reports_no_commit(tmp_path):
    # An installed package (site-packages) inside someone else's repository: its commit is not
    # mmslam's.
    outer = tmp_path / "outer"
    installed = outer / "venv" / "site-packages"
    installed.mkdir(parents=True)
    git(tmp_path, "init", "-q", str(outer))
    (outer / "README").write_text("another project\n")
    git(outer, "add", "README")
    git(outer, "commit", "-q", "-m", "theirs")
    assert provenance.git_state(installed) is None
    assert provenance.git_state(tmp_path / "not-a-repo") is None
    record = json.loads(
        provenance.run_json({}, [], datetime.datetime.now(datetime.UTC), 1.0, ["x"], installed)
    )
    assert record["git_commit"] is None and record["git_dirty"] is None


def test_the_records_name_the_libraries_versions():
    from importlib import metadata

    versions = provenance.library_versions()
    assert set(versions) == {"gtsam", "numpy", "opencv", "rerun-sdk", "mcap"}
    assert versions["numpy"] == metadata.version("numpy")
    assert versions["gtsam"] == metadata.version("gtsam")
    text = provenance.version_text()
    assert text.startswith(f"mmslam {pipeline.__version__}")
    for name, version in versions.items():
        assert f"{name} {version}" in text
