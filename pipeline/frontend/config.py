"""Typed front-end configuration: defaults in configs/frontend.toml, overridden by a user file.

The `[objects]` table is kept as a plain table and handed to the object stage, which checks it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from pipeline import settings
from pipeline.errors import InputError

IMAGE_FORMATS = ("jpeg", "png")


@dataclass(frozen=True)
class ClassConfig:
    num_classes: int
    tag_confusion_diagonal: float


@dataclass(frozen=True)
class AprilTagConfig:
    enabled: bool
    family: str
    size: float
    decimate: float
    blur: float
    refine_edges: bool
    decode_sharpening: float
    max_hamming: int
    min_decision_margin: float
    full_score_margin: float
    corner_sigma: float
    right_search_margin: int
    max_row_error: float
    min_disparity: float


@dataclass(frozen=True)
class VoConfig:
    max_features: int
    fast_threshold: int
    feature_cell: int
    tracking_window: int
    tracking_levels: int
    stereo_levels: int
    tracking_iterations: int
    max_backward_error: float
    temporal_backward_check: bool
    max_row_error: float
    min_disparity: float
    max_disparity: float
    ransac_threshold: float
    ransac_iterations: int
    refine_iterations: int
    min_inliers: int
    pixel_sigma: float
    min_sigma_rotation: float
    min_sigma_translation: float
    lost_sigma_rotation: float
    lost_sigma_translation: float


@dataclass(frozen=True)
class KeyframeConfig:
    min_translation: float
    min_rotation: float
    max_frames: int
    min_tracked_fraction: float


@dataclass(frozen=True)
class OutputConfig:
    images: bool
    image_format: str
    jpeg_quality: int
    truth_min_iou: float


@dataclass(frozen=True)
class FrontendConfig:
    classes: ClassConfig
    apriltags: AprilTagConfig
    vo: VoConfig
    keyframes: KeyframeConfig
    output: OutputConfig
    objects: dict  # the object stage's own table, checked by that stage


def load_frontend_config(path: str | Path | None = None) -> FrontendConfig:
    """The front-end defaults, with the keys of `path` (if given) put over them."""
    default = settings.config_path("frontend.toml")
    config = settings.load(FrontendConfig, default, path)
    check_frontend_config(config, path if path is not None else default)
    return config


def check_frontend_config(config: FrontendConfig, path: Path | str = "<config>") -> None:
    """Values a run cannot work with; raises InputError naming the key."""

    def need(ok: bool, what: str) -> None:
        if not ok:
            raise InputError(f"config {path}: {what}")

    c, t, v, k, o = config.classes, config.apriltags, config.vo, config.keyframes, config.output
    need(c.num_classes >= 1, "classes.num_classes must be >= 1")
    need(0.0 < c.tag_confusion_diagonal <= 1.0, "classes.tag_confusion_diagonal must be in (0, 1]")
    need(
        c.num_classes > 1 or c.tag_confusion_diagonal == 1.0,
        "classes.tag_confusion_diagonal must be 1 with a single class",
    )
    need(t.family == "tag36h11", "apriltags.family: only tag36h11 is supported")
    need(t.size > 0.0, "apriltags.size must be positive")
    need(t.decimate >= 1.0, "apriltags.decimate must be >= 1")
    need(t.blur >= 0.0, "apriltags.blur must be >= 0")
    need(t.max_hamming >= 0, "apriltags.max_hamming must be >= 0")
    need(t.full_score_margin > 0.0, "apriltags.full_score_margin must be positive")
    need(t.corner_sigma > 0.0, "apriltags.corner_sigma must be positive")
    need(t.right_search_margin >= 0, "apriltags.right_search_margin must be >= 0")
    need(t.max_row_error > 0.0, "apriltags.max_row_error must be positive")
    need(t.min_disparity > 0.0, "apriltags.min_disparity must be positive")
    need(v.max_features >= 10, "vo.max_features must be >= 10")
    need(v.fast_threshold >= 1, "vo.fast_threshold must be >= 1")
    need(v.feature_cell >= 4, "vo.feature_cell must be >= 4")
    need(v.tracking_iterations >= 1, "vo.tracking_iterations must be >= 1")
    need(v.tracking_window >= 5 and v.tracking_window % 2 == 1, "vo.tracking_window: odd, >= 5")
    need(v.tracking_levels >= 0 and v.stereo_levels >= 0, "vo pyramid levels must be >= 0")
    need(0.0 < v.min_disparity < v.max_disparity, "vo: need 0 < min_disparity < max_disparity")
    need(v.min_inliers >= 6, "vo.min_inliers must be >= 6")
    need(v.ransac_iterations >= 1 and v.refine_iterations >= 1, "vo iteration counts >= 1")
    for name in (
        "max_backward_error",
        "max_row_error",
        "ransac_threshold",
        "pixel_sigma",
        "min_sigma_rotation",
        "min_sigma_translation",
        "lost_sigma_rotation",
        "lost_sigma_translation",
    ):
        need(getattr(v, name) > 0.0, f"vo.{name} must be positive")
    need(k.min_translation > 0.0 and k.min_rotation > 0.0, "keyframes thresholds must be > 0")
    need(k.max_frames >= 1, "keyframes.max_frames must be >= 1")
    need(0.0 <= k.min_tracked_fraction < 1.0, "keyframes.min_tracked_fraction must be in [0, 1)")
    need(o.image_format in IMAGE_FORMATS, f"output.image_format must be one of {IMAGE_FORMATS}")
    need(1 <= o.jpeg_quality <= 100, "output.jpeg_quality must be in 1..100")
    need(0.0 < o.truth_min_iou <= 1.0, "output.truth_min_iou must be in (0, 1]")
    need(
        isinstance(config.objects.get("enabled", False), bool), "objects.enabled must be a boolean"
    )
