"""Typed configuration: defaults in configs/default.toml, overridden by a user's TOML file."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from pipeline import settings
from pipeline.errors import InputError

MIXTURE_SELECTIONS = ("between-updates", "custom-factor")
FIRST_CHOICES = ("joint", "prediction", "weights")
NULL_MODELS = ("relative", "literal")


@dataclass(frozen=True)
class AssociationConfig:
    chi2_confidence: float
    null_weight: float
    null_model: str
    null_sigma: float
    null_crossover_sq: float
    joint_candidate_confidence: float
    joint_confidence: float
    ambiguity_log_odds: float
    max_search_nodes: int
    min_loop_pairs: int
    joint_marginals: bool
    min_weight: float
    search_sigmas: float
    search_margin_m: float


@dataclass(frozen=True)
class LandmarkConfig:
    use_relative_pose: bool
    anchor_sigma_m: float


@dataclass(frozen=True)
class GpdaConfig:
    max_iterations: int
    weight_tolerance: float


@dataclass(frozen=True)
class MixtureConfig:
    selection: str
    first_choice: str
    max_switch_rounds: int


@dataclass(frozen=True)
class MergeConfig:
    enabled: bool
    every_keyframes: int
    recent_keyframes: int
    confidence: float
    local_confidence: float
    search_sigmas: float
    min_class_agreement: float
    prior_log_odds: float
    loop_log_odds: float
    local_log_odds: float
    ambiguity_log_odds: float
    max_search_nodes: int


@dataclass(frozen=True)
class NoiseConfig:
    estimate: bool
    odometry_scale: float
    measurement_scale: tuple[float, float, float]
    update_every: int
    sample_every: int
    window: int
    min_pairings: int
    min_scale: float
    max_scale: float


@dataclass(frozen=True)
class Isam2Config:
    relinearize_threshold: float
    per_type_thresholds: bool
    pose_rotation_threshold_rad: float
    pose_translation_threshold_m: float
    landmark_threshold_m: float
    partial_relinearization_check: bool
    wildfire_threshold: float
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
    merges: MergeConfig
    noise: NoiseConfig
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
    if a.null_model not in NULL_MODELS:
        raise InputError(
            f"config {path}: association.null_model must be one of {', '.join(NULL_MODELS)}"
        )
    if not (0.0 < a.joint_confidence < 1.0 and 0.0 < a.joint_candidate_confidence < 1.0):
        raise InputError(
            f"config {path}: association.joint_confidence and joint_candidate_confidence must "
            "be in (0, 1)"
        )
    if a.ambiguity_log_odds < 0.0 or a.max_search_nodes < 1 or a.min_loop_pairs < 1:
        raise InputError(
            f"config {path}: association.ambiguity_log_odds >= 0, max_search_nodes >= 1, "
            "min_loop_pairs >= 1"
        )
    if a.null_crossover_sq <= 0.0:
        raise InputError(f"config {path}: association.null_crossover_sq must be positive")
    if config.mixture.first_choice not in FIRST_CHOICES:
        raise InputError(
            f"config {path}: mixture.first_choice must be one of {', '.join(FIRST_CHOICES)}"
        )
    g = config.merges
    if not (0.0 < g.confidence < 1.0 and 0.0 < g.local_confidence < 1.0) or not (
        0.0 <= g.min_class_agreement <= 1.0
    ):
        raise InputError(
            f"config {path}: merges.confidence in (0, 1), min_class_agreement in [0, 1]"
        )
    if min(g.every_keyframes, g.recent_keyframes, g.max_search_nodes) < 1 or g.search_sigmas <= 0:
        raise InputError(f"config {path}: merges counts must be >= 1, search_sigmas positive")
    if min(g.loop_log_odds, g.local_log_odds, g.ambiguity_log_odds) < 0:
        raise InputError(f"config {path}: merges log odds must be >= 0")
    n = config.noise
    if not 0.0 < n.min_scale <= 1.0 <= n.max_scale:
        raise InputError(f"config {path}: noise.min_scale in (0, 1], max_scale >= 1")
    scales = (n.odometry_scale, *n.measurement_scale)
    if not all(n.min_scale <= x <= n.max_scale for x in scales):
        raise InputError(f"config {path}: noise scales must lie within min_scale..max_scale")
    if min(n.update_every, n.sample_every, n.window, n.min_pairings) < 1:
        raise InputError(f"config {path}: noise counts must be >= 1")
    if config.mixture.selection not in MIXTURE_SELECTIONS:
        raise InputError(
            f"config {path}: mixture.selection must be one of {', '.join(MIXTURE_SELECTIONS)}"
        )
    if config.isam2.factorization not in ("CHOLESKY", "QR"):
        raise InputError(f"config {path}: isam2.factorization must be CHOLESKY or QR")
    if config.gpda.max_iterations < 1 or config.mixture.max_switch_rounds < 1:
        raise InputError(f"config {path}: iteration counts must be >= 1")
