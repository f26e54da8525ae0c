"""Typed configuration: defaults in configs/default.toml, overridden by a user's TOML file.

Each setting's valid range is declared beside it (`pipeline/settings.py`) and checked at load.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from pipeline import settings
from pipeline.settings import POSITIVE, PROBABILITY, at_least, between, one_of, setting

MIXTURE_SELECTIONS = ("between-updates", "custom-factor")


@dataclass(frozen=True)
class AssociationConfig:
    chi2_confidence: float = setting(PROBABILITY)
    null_weight: float = setting(PROBABILITY)
    null_sigma: float = setting(POSITIVE)
    joint_marginals: bool
    min_weight: float = setting(between(0.0, 1.0, high_open=True))
    search_sigmas: float = setting(at_least(0.0))
    search_margin_m: float = setting(at_least(0.0))


@dataclass(frozen=True)
class LandmarkConfig:
    use_relative_pose: bool


@dataclass(frozen=True)
class GpdaConfig:
    max_iterations: int = setting(at_least(1))
    weight_tolerance: float = setting(between(0.0, 1.0))


@dataclass(frozen=True)
class MixtureConfig:
    selection: str = setting(one_of(*MIXTURE_SELECTIONS))
    max_switch_rounds: int = setting(at_least(1))


@dataclass(frozen=True)
class Isam2Config:
    relinearize_threshold: float = setting(at_least(0.0))
    relinearize_skip: int = setting(at_least(1))
    factorization: str = setting(one_of("CHOLESKY", "QR"))


@dataclass(frozen=True)
class PriorConfig:
    pose0_sigma_rotation: float = setting(POSITIVE)
    pose0_sigma_translation: float = setting(POSITIVE)


@dataclass(frozen=True)
class Config:
    association: AssociationConfig
    landmarks: LandmarkConfig
    gpda: GpdaConfig
    mixture: MixtureConfig
    isam2: Isam2Config
    prior: PriorConfig


def load_config(path: str | Path | None = None) -> Config:
    """The defaults, with the keys of `path` (if given) put over them."""
    return settings.load(Config, settings.config_path("default.toml"), path)
