"""Scenario configuration: defaults in `configs/scenarios/<name>.toml`, read with the shared
loader (`pipeline/settings.py`) into the scenario's frozen dataclasses, whose fields declare
their ranges with the kinds of value below."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Protocol, TypeVar

from pipeline import settings
from pipeline.settings import UNIT, positive, read_toml, require, within

# Times the paper's added odometry noise, at most: the paper sweeps 0..10; far beyond, the
# drawn steps overflow.
MAX_NOISE_SCALE = 100.0

WorldSeed = Annotated[int, within(0, 2**32 - 1)]
NumClasses = Annotated[int, within(1, 1000)]
Length = Annotated[float, positive(1e5)]  # m: a size or a distance in the world
Distance = Annotated[float, within(0.0, 1e5)]  # m, may be 0
Coordinate = Annotated[float, within(-1e5, 1e5)]  # m
Sigma = Annotated[float, positive(100.0)]  # a standard deviation, m or rad
Spread = Annotated[float, within(0.0, 100.0)]  # a standard deviation that may be 0
Probability = Annotated[float, UNIT]
PerFrame = Annotated[float, within(0.0, 1000.0)]  # a mean count of each frame
# Landmarks in a world at the most (tags, parked vehicles, trees): the ground truth of a log is
# one message, and every keyframe is tested against every landmark.
MAX_LANDMARKS = 10**5
Count = Annotated[int, within(1, MAX_LANDMARKS)]

__all__ = [
    "MAX_LANDMARKS",
    "MAX_NOISE_SCALE",
    "Coordinate",
    "Count",
    "Distance",
    "Length",
    "NumClasses",
    "PerFrame",
    "Probability",
    "Sigma",
    "Spread",
    "WorldSeed",
    "default_config_path",
    "load_checked",
    "read_toml",
    "require",
]


def default_config_path(scenario: str) -> Path:
    """Where the defaults of `scenario` live (the source tree first, then an installed copy)."""
    return settings.config_path(f"scenarios/{scenario}.toml")


class CheckedConfig(Protocol):
    def check(self, path: Path | str) -> None:
        """What the keys' own ranges cannot say, refused naming the file at `path`."""


C = TypeVar("C", bound=CheckedConfig)


def load_checked(cls: type[C], scenario: str, override: Path | None) -> C:
    """The defaults of `scenario` as `cls`, with the keys of `override` (if given) put over
    them; then the config's own `check`, for what the keys' own ranges cannot say (a refusal
    names `override` if given, else the defaults' file)."""
    return settings.load_checked(cls, default_config_path(scenario), override, cls.check)
