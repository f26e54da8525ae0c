"""The object detector's model in tests: there (`make test` installs it), or a skip where the
user chose not to install it (`MMSLAM_SKIP_MODELS=1`), else a failure."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from pipeline.frontend.model_files import resolve_model_path
from pipeline.frontend.objects import DEFAULT_MODEL


def installed(path: Path | None = None) -> Path:
    """`path` (default: the configured model), or a skip when the user chose not to install
    models, else a failure."""
    path = path if path is not None else resolve_model_path(DEFAULT_MODEL)
    if path.exists():
        return path
    if os.environ.get("MMSLAM_SKIP_MODELS") == "1":
        pytest.skip(f"{path} absent: MMSLAM_SKIP_MODELS=1 (the user chose not to install models)")
    pytest.fail(f"{path} absent: run `python -m data_tools.models install` (make test does)")
