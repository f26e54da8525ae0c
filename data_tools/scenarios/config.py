"""Scenario configuration: defaults in `configs/scenarios/<name>.toml`, read with the shared
loader (`pipeline/settings.py`) into the scenario's frozen dataclasses."""

from __future__ import annotations

from pathlib import Path
from typing import TypeVar

from pipeline import settings
from pipeline.settings import read_toml, require

T = TypeVar("T")

__all__ = ["default_config_path", "load", "read_toml", "require"]


def default_config_path(scenario: str) -> Path:
    """Where the defaults of `scenario` live (the source tree first, then an installed copy)."""
    return settings.config_path(f"scenarios/{scenario}.toml")


def load(cls: type[T], scenario: str, override: Path | None = None) -> T:
    """The defaults of `scenario` as `cls`, with the keys of `override` (if given) put over them."""
    return settings.load(cls, default_config_path(scenario), override)
