"""Which mmslam made a run, and how: the version text of `mmslam --version`, and `run.json`
(version, source commit, library versions, command, resolved config, input files, start and
wall time), written beside a run's outputs so that a folder explains itself."""

from __future__ import annotations

import dataclasses
import datetime
import hashlib
import json
import logging
import subprocess
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import Any

from pipeline import __version__

log = logging.getLogger(__name__)

RUN_RECORD = "run.json"
# The checkout this package runs from, when it does: the folder above `pipeline/`.
SOURCE_ROOT = Path(__file__).resolve().parent.parent
# The libraries whose versions change results, by the name they are reported under, and the
# distributions that may provide each (OpenCV comes as several wheels).
LIBRARIES = {
    "gtsam": ("gtsam",),
    "numpy": ("numpy",),
    "opencv": ("opencv-python-headless", "opencv-python", "opencv-contrib-python"),
    "rerun-sdk": ("rerun-sdk",),
    "mcap": ("mcap",),
}
GIT_TIMEOUT_S = 5.0


@dataclass(frozen=True)
class GitState:
    """The commit a checkout is at, and whether tracked files differ from it."""

    commit: str
    dirty: bool

    def text(self) -> str:
        return f"git {self.commit[:12]}" + (", dirty" if self.dirty else "")


def _git(root: Path, *args: str) -> str | None:
    try:
        done = subprocess.run(
            ["git", "-C", str(root), *args],
            capture_output=True,
            text=True,
            timeout=GIT_TIMEOUT_S,
            check=False,
        )
    except (OSError, subprocess.SubprocessError) as exc:  # no git, or it hangs
        log.debug("git %s in %s: %s", " ".join(args), root, exc)
        return None
    return done.stdout.strip() if done.returncode == 0 else None


def git_state(root: Path = SOURCE_ROOT) -> GitState | None:
    """The git state of `root` when `root` is the top of a git work tree, else None (an
    installed package: a virtualenv inside some other repository must not report that
    repository's commit). Untracked files do not make the tree dirty (outputs, caches)."""
    top = _git(root, "rev-parse", "--show-toplevel")
    if top is None or Path(top).resolve() != Path(root).resolve():
        return None
    commit = _git(root, "rev-parse", "HEAD")
    status = _git(root, "status", "--porcelain", "--untracked-files=no")
    if not commit or status is None:
        return None
    return GitState(commit, bool(status))


def library_versions() -> dict[str, str | None]:
    """The installed versions of the libraries in `LIBRARIES` (None where one is missing),
    read from package metadata, without importing them."""
    versions: dict[str, str | None] = {}
    for name, distributions in LIBRARIES.items():
        versions[name] = None
        for distribution in distributions:
            try:
                versions[name] = metadata.version(distribution)
                break
            except metadata.PackageNotFoundError:
                continue
    return versions


def build_record(root: Path = SOURCE_ROOT) -> dict[str, Any]:
    """mmslam's version, the checkout's commit and dirtiness (None when not run from one),
    Python's and the libraries' versions."""
    git = git_state(root)
    return {
        "version": __version__,
        "git_commit": git.commit if git else None,
        "git_dirty": git.dirty if git else None,
        "python": sys.version.split()[0],
        "libraries": library_versions(),
    }


def version_text(root: Path = SOURCE_ROOT) -> str:
    """What `mmslam --version` prints: mmslam's version (with the commit when run from a
    checkout), then the libraries'."""
    record = build_record(root)
    first = f"mmslam {record['version']}"
    if record["git_commit"]:
        first += f" ({GitState(record['git_commit'], record['git_dirty']).text()})"
    libraries = ", ".join(
        f"{name} {version or 'not installed'}" for name, version in record["libraries"].items()
    )
    return f"{first}\npython {record['python']}, {libraries}"


def file_record(path: str | Path) -> dict[str, Any]:
    """Path, size and SHA-256 of an input file."""
    path = Path(path)
    with open(path, "rb") as f:
        digest = hashlib.file_digest(f, "sha256").hexdigest()
    return {"path": str(path), "size_bytes": path.stat().st_size, "sha256": digest}


def utc_now() -> datetime.datetime:
    return datetime.datetime.now(datetime.UTC)


def _plain(value: Any) -> Any:
    """JSON for what `json` does not know: dataclasses as objects, paths and the rest as text."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return dataclasses.asdict(value)
    return str(value)


def run_json(
    config: Any,
    inputs: Sequence[str | Path],
    started: datetime.datetime,
    wall_s: float,
    command: Sequence[str] | None = None,
    source_root: Path = SOURCE_ROOT,
) -> str:
    """The text of `run.json`; `config` the resolved settings (dataclasses, dicts), `command`
    the command line (default: this process's), `source_root` the checkout whose commit is
    recorded (default: this package's)."""
    build = build_record(source_root)
    record = {
        "mmslam_version": build["version"],
        "git_commit": build["git_commit"],
        "git_dirty": build["git_dirty"],
        "python": build["python"],
        "libraries": build["libraries"],
        "command": list(command) if command is not None else list(sys.argv),
        "config": config,
        "inputs": [file_record(path) for path in inputs],
        "started_utc": started.isoformat(timespec="seconds"),
        "wall_s": round(wall_s, 3),
    }
    return json.dumps(record, indent=2, default=_plain) + "\n"
