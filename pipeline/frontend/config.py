"""Typed front-end configuration: defaults in configs/frontend.toml, overridden by a user file."""

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
    min_inlier_fraction: float
    recovery_features: int
    recovery_ratio: float
    pixel_sigma: float
    min_sigma_rotation: float
    min_sigma_translation: float
    translation_sigma_fraction: float
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
class StereoRangeConfig:
    """`[objects.stereo]`: stereo range inside a box (pipeline/frontend/stereo_range.py)."""

    max_disparity: int
    block_size: int
    uniqueness_ratio: int
    margin: int
    central_fraction: float
    min_valid_fraction: float
    min_disparity: float
    disparity_sigma: float
    center_sigma: float
    center_sigma_fraction: float
    surface_to_centre: float
    surface_to_centre_sigma: float


@dataclass(frozen=True)
class ObjectDetectorConfig:
    """`[objects]`: the object-box stage (pipeline/frontend/objects.py)."""

    enabled: bool
    model: str  # a bare file name is looked up in the models directory
    class_names_file: str
    input_size: tuple[int, int]
    nms_iou: float
    nested_fraction: float
    nested_sigmas: float
    num_threads: int
    classes: tuple[str, ...]
    class_map: dict  # detector class name -> one of `classes`
    thresholds: dict  # model file name -> the score a box must reach
    stereo: StereoRangeConfig

    @property
    def model_path(self) -> Path:
        from pipeline.frontend.objects import resolve_model_path

        return resolve_model_path(self.model)

    @property
    def confidence_threshold(self) -> float:
        """The score threshold of the configured model (`thresholds`, by its file name)."""
        return float(self.thresholds[Path(self.model).name])


@dataclass(frozen=True)
class FrontendConfig:
    classes: ClassConfig
    apriltags: AprilTagConfig
    vo: VoConfig
    keyframes: KeyframeConfig
    output: OutputConfig
    objects: ObjectDetectorConfig


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
    need(0.0 <= v.min_inlier_fraction <= 1.0, "vo.min_inlier_fraction must be in [0, 1]")
    need(v.recovery_features >= 10, "vo.recovery_features must be >= 10")
    need(0.0 < v.recovery_ratio <= 1.0, "vo.recovery_ratio must be in (0, 1]")
    need(v.translation_sigma_fraction >= 0.0, "vo.translation_sigma_fraction must be >= 0")
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
    ob = config.objects
    model = Path(ob.model).name
    need(
        model in ob.thresholds,
        f"objects.thresholds has no score threshold for the model {model!r}: scores differ "
        "between models, measure one (python -m data_tools.bench_objects --thresholds)",
    )
    for name, value in ob.thresholds.items():
        ok = isinstance(value, int | float) and not isinstance(value, bool) and 0.0 < value <= 1.0
        need(ok, f"objects.thresholds.{name!r} must be a number in (0, 1]")
    need(0.0 < ob.nms_iou <= 1.0, "objects.nms_iou must be in (0, 1]")
    need(0.0 < ob.nested_fraction <= 1.0, "objects.nested_fraction must be in (0, 1]")
    need(ob.nested_sigmas > 0.0, "objects.nested_sigmas must be positive")
    need(ob.num_threads >= 1, "objects.num_threads must be >= 1")
    need(
        min(ob.input_size) >= 32 and all(v % 32 == 0 for v in ob.input_size),
        "objects.input_size: multiples of 32 (the YOLO networks' stride)",
    )
    need(len(ob.classes) >= 1, "objects.classes must name at least one class")
    need(len(set(ob.classes)) == len(ob.classes), "objects.classes must not repeat a name")
    need(len(ob.class_map) >= 1, "objects.class_map must map at least one detector class")
    for detector_name, ours in ob.class_map.items():
        need(ours in ob.classes, f"objects.class_map.{detector_name}: {ours!r} is not in classes")
    st = ob.stereo
    need(
        st.max_disparity >= 16 and st.max_disparity % 16 == 0,
        "objects.stereo.max_disparity: 16, 32, ...",
    )
    need(st.block_size >= 1 and st.block_size % 2 == 1, "objects.stereo.block_size must be odd")
    need(0 <= st.uniqueness_ratio <= 100, "objects.stereo.uniqueness_ratio must be in 0..100")
    need(st.margin >= 0, "objects.stereo.margin must be >= 0")
    need(0.0 < st.central_fraction <= 1.0, "objects.stereo.central_fraction must be in (0, 1]")
    need(0.0 < st.min_valid_fraction <= 1.0, "objects.stereo.min_valid_fraction must be in (0, 1]")
    need(
        0.0 < st.min_disparity < st.max_disparity,
        "objects.stereo.min_disparity: in (0, max_disparity)",
    )
    need(st.disparity_sigma > 0.0, "objects.stereo.disparity_sigma must be positive")
    need(st.center_sigma > 0.0, "objects.stereo.center_sigma must be positive")
    need(st.center_sigma_fraction >= 0.0, "objects.stereo.center_sigma_fraction must be >= 0")
    need(st.surface_to_centre >= 0.0, "objects.stereo.surface_to_centre must be >= 0")
    need(st.surface_to_centre_sigma >= 0.0, "objects.stereo.surface_to_centre_sigma must be >= 0")
