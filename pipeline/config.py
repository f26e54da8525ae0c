"""Typed configuration: defaults in configs/default.toml, overridden by a user's TOML file.

Each setting's type and valid range are declared beside it (`pipeline/settings.py`) and
checked at load; `load_config` checks what spans keys.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal, get_args

from pipeline import settings
from pipeline.settings import FRACTION, PROBABILITY, UNIT, positive, within

MixtureSelection = Literal["between-updates", "custom-factor"]
FirstChoice = Literal["joint", "prediction", "weights"]
NullModel = Literal["relative", "literal"]
PlanarMode = Literal["auto", "always", "never"]
MIXTURE_SELECTIONS = get_args(MixtureSelection)
FIRST_CHOICES = get_args(FirstChoice)
NULL_MODELS = get_args(NullModel)
PLANAR_MODES = get_args(PlanarMode)

Probability = Annotated[float, PROBABILITY]
LogOdds = Annotated[float, within(0.0, 1000.0)]  # nats
Sigmas = Annotated[float, within(0.0, 1000.0)]  # standard deviations
Scale = Annotated[float, positive(1e6)]  # a variance scale
Keyframes = Annotated[int, within(1, 10**6)]
SearchNodes = Annotated[int, within(1, 10**7)]
Rounds = Annotated[int, within(1, 1000)]
Metres = Annotated[float, within(0.0, 1e6)]
Sigma = Annotated[float, positive(1e6)]  # a standard deviation, m or rad


@dataclass(frozen=True)
class AssociationConfig:
    chi2_confidence: Probability
    null_weight: Probability
    null_model: NullModel
    null_sigma: Annotated[float, positive(1e9)]
    null_crossover_sq: Annotated[float, positive(1e6)]
    joint_candidate_confidence: Probability
    joint_confidence: Probability
    ambiguity_log_odds: LogOdds
    max_search_nodes: SearchNodes
    max_joint_detections: Rounds
    max_keyframe_nodes: SearchNodes
    min_loop_pairs: Rounds
    crowded_loop_pairs: Rounds
    joint_marginals: bool
    min_weight: Annotated[float, within(0.0, 1.0, high_open=True)]
    search_sigmas: Sigmas
    search_margin_m: Metres
    max_candidates: Rounds


@dataclass(frozen=True)
class LandmarkConfig:
    use_relative_pose: bool
    anchor_sigma_m: Annotated[float, positive(1e9)]


@dataclass(frozen=True)
class GpdaConfig:
    max_iterations: Rounds
    weight_tolerance: Annotated[float, UNIT]


@dataclass(frozen=True)
class MixtureConfig:
    selection: MixtureSelection
    first_choice: FirstChoice
    max_switch_rounds: Rounds


@dataclass(frozen=True)
class MergeConfig:
    enabled: bool
    every_keyframes: Keyframes
    recent_keyframes: Keyframes
    final_check: bool
    confidence: Probability
    local_confidence: Probability
    search_sigmas: Annotated[float, positive(1000.0)]
    min_class_agreement: Annotated[float, UNIT]
    # any finite number: negative favours a new landmark
    prior_log_odds: Annotated[float, within(-1000.0, 1000.0)]
    loop_log_odds: LogOdds
    local_log_odds: LogOdds
    ambiguity_log_odds: LogOdds
    max_search_nodes: SearchNodes
    search_seeds: Annotated[int, within(0, 10**4)]
    partner_prior: bool
    local_rivals: bool
    local_detection_noise: bool
    max_partners: Rounds
    max_landmarks: Annotated[int, within(2, 10**5)]
    max_marginals: Annotated[int, within(1, 10**6)]
    max_pairs: Annotated[int, within(1, 10**5)]
    max_check_nodes: SearchNodes
    drift_scale_weight: Annotated[float, UNIT]
    max_drift_scale: Annotated[float, within(1.0, 1e6)]
    drift_scale_steps: Rounds


@dataclass(frozen=True)
class NoiseConfig:
    estimate: bool
    odometry_scale: tuple[Scale, Scale, Scale, Scale, Scale, Scale]
    measurement_scale: tuple[Scale, Scale, Scale]
    update_every: Keyframes
    min_scale: Annotated[float, FRACTION]
    max_scale: Annotated[float, within(1.0, 1e6)]
    deadband: Annotated[float, within(1.0, 1e6)]
    evidence: Annotated[float, within(0.0, 1e6)]
    drop: Annotated[int, within(0, 1000)]
    drift_window: Keyframes
    long_drift_window: Annotated[int, within(0, 10**6)]
    drift_windows: Keyframes
    min_drift_windows: Keyframes
    contrasts: Keyframes
    min_contrasts: Keyframes


@dataclass(frozen=True)
class Isam2Config:
    relinearize_threshold: Metres
    per_type_thresholds: bool
    pose_rotation_threshold_rad: Annotated[float, within(0.0, 10.0)]
    pose_translation_threshold_m: Metres
    landmark_threshold_m: Metres
    partial_relinearization_check: bool
    wildfire_threshold: Metres
    relinearize_skip: Keyframes  # GTSAM takes a C int
    factorization: Literal["CHOLESKY", "QR"]
    batch_iterations: Annotated[int, within(0, 10**5)]
    max_root_landmarks: Annotated[int, within(1, 10**6)]


@dataclass(frozen=True)
class DcsamConfig:
    new_landmark_weight: Probability
    max_alternations: Rounds
    # landmarks a group may hold for the exact step (its cost grows exponentially with them)
    exact_class_variables: Annotated[int, within(0, 64)]


@dataclass(frozen=True)
class PriorConfig:
    pose0_sigma_rotation: Sigma
    pose0_sigma_translation: Sigma
    planar: PlanarMode
    planar_height_sigma_m: Sigma
    planar_tilt_sigma_rad: Sigma


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
    dcsam: DcsamConfig


def load_config(path: str | Path | None = None) -> Config:
    """The defaults, with the keys of `path` (if given) put over them."""
    return settings.load_checked(Config, settings.config_path("default.toml"), path, _check)


def _check(config: Config, source: Path | str) -> None:
    """What the keys' own ranges cannot say."""
    n, a = config.noise, config.association
    settings.require(
        all(n.min_scale <= x <= n.max_scale for x in (*n.odometry_scale, *n.measurement_scale)),
        source,
        "noise.odometry_scale and measurement_scale must lie within min_scale..max_scale",
    )
    settings.require(
        a.crowded_loop_pairs >= a.min_loop_pairs,
        source,
        "association.crowded_loop_pairs must be >= association.min_loop_pairs",
    )
