"""Where the front-end's network files live: below the config (which names a model) and the
object stage (which loads it), so that neither imports the other."""

from __future__ import annotations

import os
import sys
from pathlib import Path

MODELS_ENV = "MMSLAM_MODELS"


def models_dir() -> Path:
    """Where installed models live: `$MMSLAM_MODELS`, else `<sys.prefix>/share/mmslam/models`."""
    env = os.environ.get(MODELS_ENV)
    return Path(env).expanduser() if env else Path(sys.prefix) / "share" / "mmslam" / "models"


def resolve_model_path(name: str) -> Path:
    """A bare file name is looked up in the models directory; any other path is used as is."""
    path = Path(name).expanduser()
    return models_dir() / path if path.parent == Path(".") else path
