"""`run.json`: how a run's outputs were made (version, command, resolved config, input files,
start and wall time), written beside them so that a folder explains itself."""

from __future__ import annotations

import dataclasses
import datetime
import hashlib
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from pipeline import __version__

RUN_RECORD = "run.json"


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
) -> str:
    """The text of `run.json`; `config` the resolved settings (dataclasses, dicts), `command`
    the command line (default: this process's)."""
    record = {
        "mmslam_version": __version__,
        "python": sys.version.split()[0],
        "command": list(command) if command is not None else list(sys.argv),
        "config": config,
        "inputs": [file_record(path) for path in inputs],
        "started_utc": started.isoformat(timespec="seconds"),
        "wall_s": round(wall_s, 3),
    }
    return json.dumps(record, indent=2, default=_plain) + "\n"
