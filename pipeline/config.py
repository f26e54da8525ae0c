"""Typed configuration: defaults in configs/default.toml, overridden by a user's TOML file."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from pipeline import settings
from pipeline.errors import InputError

MIXTURE_SELECTIONS = ("between-updates", "custom-factor")


@dataclass(frozen=True)
class AssociationConfig:
    chi2_confidence: float
    null_weight: float
    null_sigma: float
    joint_marginals: bool
    min_weight: float
    search_sigmas: float
    search_margin_m: float


@dataclass(frozen=True)
class LandmarkConfig:
    use_relative_pose: bool


@dataclass(frozen=True)
class GpdaConfig:
    max_iterations: int
    weight_tolerance: float


@dataclass(frozen=True)
class MixtureConfig:
    selection: str
    max_switch_rounds: int


@dataclass(frozen=True)
class Isam2Config:
    relinearize_threshold: float
    relinearize_skip: int
    factorization: str


@dataclass(frozen=True)
class PriorConfig:
    pose0_sigma_rotation: float
    pose0_sigma_translation: float


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
    config = settings.load(Config, settings.config_path("default.toml"), path)
    _check(config, Path(path) if path is not None else settings.config_path("default.toml"))
    return config


def _check(config: Config, path: Path) -> None:
    a = config.association
    if not 0.0 < a.chi2_confidence < 1.0:
        raise InputError(f"config {path}: association.chi2_confidence must be in (0, 1)")
    if not 0.0 < a.null_weight < 1.0:
        raise InputError(f"config {path}: association.null_weight must be in (0, 1)")
    if a.null_sigma <= 0.0:
        raise InputError(f"config {path}: association.null_sigma must be positive")
    if config.mixture.selection not in MIXTURE_SELECTIONS:
        raise InputError(
            f"config {path}: mixture.selection must be one of {', '.join(MIXTURE_SELECTIONS)}"
        )
    if config.isam2.factorization not in ("CHOLESKY", "QR"):
        raise InputError(f"config {path}: isam2.factorization must be CHOLESKY or QR")
    if config.gpda.max_iterations < 1 or config.mixture.max_switch_rounds < 1:
        raise InputError(f"config {path}: iteration counts must be >= 1")
