"""Typed front-end configuration: defaults in configs/frontend.toml, overridden by a user file.

Each setting's valid range is declared beside it (`pipeline/settings.py`) and checked at load;
`check_frontend_config` checks what spans keys.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from pipeline import settings
from pipeline.errors import InputError
from pipeline.settings import ANY, FRACTION, POSITIVE, at_least, between, one_of, setting

IMAGE_FORMATS = ("jpeg", "png")


@dataclass(frozen=True)
class InputConfig:
    """`[input]`: reading sequences whose left and right frames are paired by their stamps."""

    stereo_stamp_tolerance: float = setting(POSITIVE)


@dataclass(frozen=True)
class ClassConfig:
    num_classes: int = setting(at_least(1))
    tag_confusion_diagonal: float = setting(FRACTION)


@dataclass(frozen=True)
class AprilTagConfig:
    enabled: bool
    family: str = setting(one_of("tag36h11"))
    size: float = setting(POSITIVE)
    decimate: float = setting(at_least(1.0))
    blur: float = setting(at_least(0.0))
    refine_edges: bool
    decode_sharpening: float = setting(at_least(0.0))
    max_hamming: int = setting(at_least(0))
    min_decision_margin: float = setting(at_least(0.0))
    full_score_margin: float = setting(POSITIVE)
    corner_sigma: float = setting(POSITIVE)
    right_search_margin: int = setting(at_least(0))
    max_row_error: float = setting(POSITIVE)
    min_disparity: float = setting(POSITIVE)


@dataclass(frozen=True)
class VoConfig:
    max_features: int = setting(at_least(10))
    fast_threshold: int = setting(at_least(1))
    feature_cell: int = setting(at_least(4))
    tracking_window: int = setting(at_least(5))
    tracking_levels: int = setting(at_least(0))
    stereo_levels: int = setting(at_least(0))
    tracking_iterations: int = setting(at_least(1))
    max_backward_error: float = setting(POSITIVE)
    temporal_backward_check: bool
    max_row_error: float = setting(POSITIVE)
    min_disparity: float = setting(POSITIVE)
    max_disparity: float = setting(POSITIVE)
    ransac_threshold: float = setting(POSITIVE)
    ransac_iterations: int = setting(at_least(1))
    refine_iterations: int = setting(at_least(1))
    min_inliers: int = setting(at_least(6))
    min_inlier_fraction: float = setting(between(0.0, 1.0))
    recovery_features: int = setting(at_least(10))
    recovery_ratio: float = setting(FRACTION)
    pixel_sigma: float = setting(POSITIVE)
    min_residual_scale: float = setting(FRACTION)
    min_sigma_rotation: float = setting(POSITIVE)
    min_sigma_translation: float = setting(POSITIVE)
    translation_sigma_fraction: float = setting(at_least(0.0))
    lost_sigma_rotation: float = setting(POSITIVE)
    lost_sigma_translation: float = setting(POSITIVE)


@dataclass(frozen=True)
class KeyframeConfig:
    min_translation: float = setting(POSITIVE)
    min_rotation: float = setting(POSITIVE)
    max_frames: int = setting(at_least(1))
    min_tracked_fraction: float = setting(between(0.0, 1.0, high_open=True))


@dataclass(frozen=True)
class OutputConfig:
    images: bool
    image_format: str = setting(one_of(*IMAGE_FORMATS))
    jpeg_quality: int = setting(between(1, 100))
    truth_min_iou: float = setting(FRACTION)


@dataclass(frozen=True)
class StereoRangeConfig:
    """`[objects.stereo]`: stereo range inside a box (pipeline/frontend/stereo_range.py)."""

    max_disparity: int = setting(at_least(16))
    block_size: int = setting(at_least(1))
    uniqueness_ratio: int = setting(between(0, 100))
    margin: int = setting(at_least(0))
    central_fraction: float = setting(FRACTION)
    min_valid_fraction: float = setting(FRACTION)
    min_disparity: float = setting(POSITIVE)
    disparity_sigma: float = setting(POSITIVE)
    center_sigma: float = setting(POSITIVE)
    center_sigma_fraction: float = setting(at_least(0.0))
    surface_to_centre: float = setting(at_least(0.0))
    surface_to_centre_sigma: float = setting(at_least(0.0))


@dataclass(frozen=True)
class ObjectDetectorConfig:
    """`[objects]`: the object-box stage (pipeline/frontend/objects.py)."""

    enabled: bool
    model: str = setting(ANY)  # a bare file name is looked up in the models directory
    class_names_file: str = setting(ANY)
    input_size: tuple[int, int] = setting(at_least(32))
    nms_iou: float = setting(FRACTION)
    nested_fraction: float = setting(FRACTION)
    nested_sigmas: float = setting(POSITIVE)
    num_threads: int = setting(at_least(1))
    classes: tuple[str, ...] = setting(ANY)
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
    input: InputConfig
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
    """What the keys' own ranges cannot say; raises InputError naming the key."""

    def need(ok: bool, what: str) -> None:
        if not ok:
            raise InputError(f"config {path}: {what}")

    c, v, ob = config.classes, config.vo, config.objects
    need(
        c.num_classes > 1 or c.tag_confusion_diagonal == 1.0,
        "classes.tag_confusion_diagonal must be 1 with a single class",
    )
    need(v.tracking_window % 2 == 1, "vo.tracking_window must be odd")
    need(v.min_disparity < v.max_disparity, "vo: need min_disparity < max_disparity")
    model = Path(ob.model).name
    need(
        model in ob.thresholds,
        f"objects.thresholds has no score threshold for the model {model!r}: scores differ "
        "between models, measure one (python -m data_tools.bench_objects --thresholds)",
    )
    for name, value in ob.thresholds.items():  # a free-form table: its values checked here
        ok = isinstance(value, int | float) and not isinstance(value, bool) and 0.0 < value <= 1.0
        need(ok, f"objects.thresholds.{name!r} must be a number in (0, 1]")
    need(
        all(v % 32 == 0 for v in ob.input_size),
        "objects.input_size: multiples of 32 (the YOLO networks' stride)",
    )
    need(len(ob.classes) >= 1, "objects.classes must name at least one class")
    need(len(set(ob.classes)) == len(ob.classes), "objects.classes must not repeat a name")
    need(len(ob.class_map) >= 1, "objects.class_map must map at least one detector class")
    for detector_name, ours in ob.class_map.items():
        need(ours in ob.classes, f"objects.class_map.{detector_name}: {ours!r} is not in classes")
    st = ob.stereo
    need(st.max_disparity % 16 == 0, "objects.stereo.max_disparity: 16, 32, ...")
    need(st.block_size % 2 == 1, "objects.stereo.block_size must be odd")
    need(
        st.min_disparity < st.max_disparity,
        "objects.stereo.min_disparity: in (0, max_disparity)",
    )
