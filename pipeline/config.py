"""Typed configuration: defaults in configs/default.toml, overridden by a user's TOML file."""

from __future__ import annotations

import dataclasses
import sys
import tomllib
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, get_type_hints

from pipeline.errors import InputError

DEFAULT_CONFIG = Path(__file__).resolve().parents[1] / "configs" / "default.toml"
MIXTURE_SELECTIONS = ("between-updates", "custom-factor")
INSTALLED_CONFIG = Path(sys.prefix) / "share" / "mmslam" / "configs" / "default.toml"


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


def _read_toml(path: Path) -> dict[str, Any]:
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except FileNotFoundError:
        raise InputError(f"config {path}: no such file") from None
    except OSError as exc:
        raise InputError(f"config {path}: cannot be read ({exc.strerror})") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"config {path}: not valid TOML ({exc})") from None


def _merge(base: dict[str, Any], override: dict[str, Any], path: Path, prefix: str = "") -> None:
    for key, value in override.items():
        if key not in base:
            raise InputError(f"config {path}: unknown key '{prefix}{key}'")
        if isinstance(base[key], dict):
            if not isinstance(value, dict):
                raise InputError(f"config {path}: '{prefix}{key}' must be a table")
            _merge(base[key], value, path, f"{prefix}{key}.")
        else:
            base[key] = value


def _build(cls: type, table: dict[str, Any], path: Path, prefix: str) -> Any:
    """A config dataclass from a TOML table, type-checked key by key."""
    hints = get_type_hints(cls)
    kwargs = {}
    for f in fields(cls):
        if f.name not in table:
            raise InputError(f"config {path}: missing key '{prefix}{f.name}'")
        value, kind = table[f.name], hints[f.name]
        if dataclasses.is_dataclass(kind):
            kwargs[f.name] = _build(kind, value, path, f"{prefix}{f.name}.")
            continue
        accepted = (int, float) if kind is float else (kind,)
        if isinstance(value, bool) is not (kind is bool) or not isinstance(value, accepted):
            raise InputError(
                f"config {path}: '{prefix}{f.name}' must be {kind.__name__}, got {value!r}"
            )
        kwargs[f.name] = kind(value)
    return cls(**kwargs)


def load_config(path: str | Path | None = None) -> Config:
    """The defaults, with the keys of `path` (if given) put over them."""
    default_path = DEFAULT_CONFIG if DEFAULT_CONFIG.exists() else INSTALLED_CONFIG
    table = _read_toml(default_path)
    source = default_path
    if path is not None:
        source = Path(path)
        _merge(table, _read_toml(source), source)
    config = _build(Config, table, source, "")
    _check(config, source)
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
