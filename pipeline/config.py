"""Typed configuration: defaults in configs/default.toml, overridden by a user's TOML file.

Each setting's valid range is declared beside it (`pipeline/settings.py`) and checked at load;
`load_config` checks what spans keys.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from pipeline import settings
from pipeline.settings import (
    ANY,
    FRACTION,
    POSITIVE,
    PROBABILITY,
    at_least,
    between,
    one_of,
    setting,
)

MIXTURE_SELECTIONS = ("between-updates", "custom-factor")
FIRST_CHOICES = ("joint", "prediction", "weights")
NULL_MODELS = ("relative", "literal")
PLANAR_MODES = ("auto", "always", "never")


@dataclass(frozen=True)
class AssociationConfig:
    chi2_confidence: float = setting(PROBABILITY)
    null_weight: float = setting(PROBABILITY)
    null_model: str = setting(one_of(*NULL_MODELS))
    null_sigma: float = setting(POSITIVE)
    null_crossover_sq: float = setting(POSITIVE)
    joint_candidate_confidence: float = setting(PROBABILITY)
    joint_confidence: float = setting(PROBABILITY)
    ambiguity_log_odds: float = setting(at_least(0.0))
    max_search_nodes: int = setting(at_least(1))
    min_loop_pairs: int = setting(at_least(1))
    crowded_loop_pairs: int = setting(at_least(1))
    joint_marginals: bool
    min_weight: float = setting(between(0.0, 1.0, high_open=True))
    search_sigmas: float = setting(at_least(0.0))
    search_margin_m: float = setting(at_least(0.0))
    max_candidates: int = setting(at_least(1))


@dataclass(frozen=True)
class LandmarkConfig:
    use_relative_pose: bool
    anchor_sigma_m: float = setting(POSITIVE)


@dataclass(frozen=True)
class GpdaConfig:
    max_iterations: int = setting(at_least(1))
    weight_tolerance: float = setting(between(0.0, 1.0))


@dataclass(frozen=True)
class MixtureConfig:
    selection: str = setting(one_of(*MIXTURE_SELECTIONS))
    first_choice: str = setting(one_of(*FIRST_CHOICES))
    max_switch_rounds: int = setting(at_least(1))


@dataclass(frozen=True)
class MergeConfig:
    enabled: bool
    every_keyframes: int = setting(at_least(1))
    recent_keyframes: int = setting(at_least(1))
    confidence: float = setting(PROBABILITY)
    local_confidence: float = setting(PROBABILITY)
    search_sigmas: float = setting(POSITIVE)
    min_class_agreement: float = setting(between(0.0, 1.0))
    prior_log_odds: float = setting(ANY)  # any finite number: negative favours a new landmark
    loop_log_odds: float = setting(at_least(0.0))
    local_log_odds: float = setting(at_least(0.0))
    ambiguity_log_odds: float = setting(at_least(0.0))
    max_search_nodes: int = setting(at_least(1))
    search_seeds: int = setting(at_least(0))
    partner_prior: bool
    local_rivals: bool
    local_detection_noise: bool
    max_partners: int = setting(at_least(1))
    max_landmarks: int = setting(at_least(2))
    drift_scale_weight: float = setting(between(0.0, 1.0))
    max_drift_scale: float = setting(at_least(1.0))
    drift_scale_steps: int = setting(at_least(1))


@dataclass(frozen=True)
class NoiseConfig:
    estimate: bool
    odometry_scale: float = setting(POSITIVE)
    odometry_start_scale: float = setting(POSITIVE)
    measurement_scale: tuple[float, float, float] = setting(POSITIVE)
    update_every: int = setting(at_least(1))
    sample_every: int = setting(at_least(1))
    window: int = setting(at_least(1))
    min_pairings: int = setting(at_least(1))
    min_scale: float = setting(FRACTION)
    max_scale: float = setting(at_least(1.0))
    max_step: float = setting(at_least(1.0))
    drift_window: int = setting(at_least(1))
    long_drift_window: int = setting(at_least(0))
    drift_windows: int = setting(at_least(1))
    min_drift_windows: int = setting(at_least(1))
    drift_deadband: float = setting(at_least(1.0))
    drift_evidence: float = setting(at_least(0.0))


@dataclass(frozen=True)
class Isam2Config:
    relinearize_threshold: float = setting(at_least(0.0))
    per_type_thresholds: bool
    pose_rotation_threshold_rad: float = setting(at_least(0.0))
    pose_translation_threshold_m: float = setting(at_least(0.0))
    landmark_threshold_m: float = setting(at_least(0.0))
    partial_relinearization_check: bool
    wildfire_threshold: float = setting(at_least(0.0))
    relinearize_skip: int = setting(at_least(1))
    factorization: str = setting(one_of("CHOLESKY", "QR"))
    batch_iterations: int = setting(at_least(0))


@dataclass(frozen=True)
class PriorConfig:
    pose0_sigma_rotation: float = setting(POSITIVE)
    pose0_sigma_translation: float = setting(POSITIVE)
    planar: str = setting(one_of(*PLANAR_MODES))
    planar_height_sigma_m: float = setting(POSITIVE)
    planar_tilt_sigma_rad: float = setting(POSITIVE)


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
    default = settings.config_path("default.toml")
    config = settings.load(Config, default, path)
    n, a = config.noise, config.association
    source = path if path is not None else default
    settings.require(
        all(n.min_scale <= x <= n.max_scale for x in (n.odometry_scale, *n.measurement_scale)),
        source,
        "noise.odometry_scale and measurement_scale must lie within min_scale..max_scale",
    )
    settings.require(
        n.odometry_start_scale <= n.max_scale,
        source,
        "noise.odometry_start_scale must be <= max_scale",
    )
    settings.require(
        a.crowded_loop_pairs >= a.min_loop_pairs,
        source,
        "association.crowded_loop_pairs must be >= association.min_loop_pairs",
    )
    return config
