"""Writing a sweep's own files all-or-nothing: to a temporary name, then renamed into place."""

from __future__ import annotations

import os
from pathlib import Path

from pipeline.log.mcap_io import atomic_output


def write_text(path: Path, text: str) -> None:
    """Write `text` to `path` atomically (a reader sees the old file or the new, never half)."""
    fd, tmp = atomic_output(path)
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
