"""Typed front-end configuration: defaults in configs/frontend.toml, overridden by a user file.

Each setting's type and valid range are declared beside it (`pipeline/settings.py`) and
checked at load;
`check_frontend_config` checks what spans keys.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal, get_args

from pipeline import settings
from pipeline.errors import InputError
from pipeline.frontend.model_files import resolve_model_path
from pipeline.settings import FRACTION, UNIT, positive, within

ImageFormat = Literal["jpeg", "png"]
IMAGE_FORMATS = get_args(ImageFormat)
Pixels = Annotated[float, positive(1e4)]
Count = Annotated[int, within(1, 10**6)]
InputSide = Annotated[int, within(32, 8192)]  # pixels


@dataclass(frozen=True)
class InputConfig:
    """`[input]`: reading sequences whose left and right frames are paired by their stamps."""

    stereo_stamp_tolerance: Annotated[float, positive(10.0)]  # s


@dataclass(frozen=True)
class ClassConfig:
    num_classes: Annotated[int, within(1, 1000)]
    tag_confusion_diagonal: Annotated[float, FRACTION]


@dataclass(frozen=True)
class AprilTagConfig:
    enabled: bool
    family: Literal["tag36h11"]
    size: Annotated[float, positive(100.0)]  # m
    decimate: Annotated[float, within(1.0, 16.0)]
    blur: Annotated[float, within(0.0, 100.0)]
    refine_edges: bool
    decode_sharpening: Annotated[float, within(0.0, 100.0)]
    max_hamming: Annotated[int, within(0, 3)]
    min_decision_margin: Annotated[float, within(0.0, 1e4)]
    full_score_margin: Annotated[float, positive(1e4)]
    corner_sigma: Pixels
    right_search_margin: Annotated[int, within(0, 10**4)]
    max_row_error: Pixels
    min_disparity: Pixels


@dataclass(frozen=True)
class VoConfig:
    max_features: Annotated[int, within(10, 10**6)]
    fast_threshold: Annotated[int, within(1, 255)]
    feature_cell: Annotated[int, within(4, 4096)]
    tracking_window: Annotated[int, within(5, 255)]
    tracking_levels: Annotated[int, within(0, 16)]
    stereo_levels: Annotated[int, within(0, 16)]
    tracking_iterations: Annotated[int, within(1, 10**4)]
    max_backward_error: Pixels
    temporal_backward_check: bool
    max_row_error: Pixels
    min_disparity: Pixels
    max_disparity: Pixels
    ransac_threshold: Pixels
    ransac_iterations: Count
    refine_iterations: Annotated[int, within(1, 1000)]
    min_inliers: Annotated[int, within(6, 10**6)]
    min_inlier_fraction: Annotated[float, UNIT]
    recovery_features: Annotated[int, within(10, 10**6)]
    recovery_ratio: Annotated[float, FRACTION]
    pixel_sigma: Pixels
    min_residual_scale: Annotated[float, FRACTION]
    min_sigma_rotation: Annotated[float, positive(10.0)]  # rad
    min_sigma_translation: Annotated[float, positive(1e3)]  # m
    rotation_sigma_fraction: Annotated[float, within(0.0, 1.0)]
    direction_sigma: Annotated[float, within(0.0, 1.0)]  # rad
    disparity_offset_sigma: Annotated[float, positive(1000.0)]  # px
    disparity_offset_memory: Annotated[float, within(1.0, 1e9)]  # keyframes
    lost_sigma_rotation: Annotated[float, positive(10.0)]  # rad
    lost_sigma_translation: Annotated[float, positive(1e6)]  # m


@dataclass(frozen=True)
class KeyframeConfig:
    min_translation: Annotated[float, positive(1e3)]  # m
    min_rotation: Annotated[float, positive(10.0)]  # rad
    max_frames: Count
    min_tracked_fraction: Annotated[float, within(0.0, 1.0, high_open=True)]


@dataclass(frozen=True)
class OutputConfig:
    images: bool
    image_format: ImageFormat
    jpeg_quality: Annotated[int, within(1, 100)]
    truth_min_iou: Annotated[float, FRACTION]


@dataclass(frozen=True)
class StereoRangeConfig:
    """`[objects.stereo]`: stereo range inside a box (pipeline/frontend/stereo_range.py)."""

    max_disparity: Annotated[int, within(16, 4096)]
    block_size: Annotated[int, within(1, 255)]
    uniqueness_ratio: Annotated[int, within(0, 100)]
    margin: Annotated[int, within(0, 10**4)]
    central_fraction: Annotated[float, FRACTION]
    min_valid_fraction: Annotated[float, FRACTION]
    min_disparity: Pixels
    disparity_sigma: Pixels
    center_sigma: Pixels
    center_sigma_fraction: Annotated[float, within(0.0, 1000.0)]
    surface_to_centre: Annotated[float, within(0.0, 100.0)]  # m
    surface_to_centre_sigma: Annotated[float, within(0.0, 100.0)]  # m


@dataclass(frozen=True)
class ObjectDetectorConfig:
    """`[objects]`: the object-box stage (pipeline/frontend/objects.py)."""

    enabled: bool
    require_model: bool  # False: without the model, a note and no boxes; True: an error
    model: str  # a bare file name is looked up in the models directory
    class_names_file: str
    input_size: tuple[InputSide, InputSide]
    nms_iou: Annotated[float, FRACTION]
    nested_fraction: Annotated[float, FRACTION]
    nested_sigmas: Annotated[float, positive(1000.0)]
    num_threads: Annotated[int, within(1, 1024)]
    classes: tuple[str, ...]
    class_map: dict[str, str]  # detector class name -> one of `classes`
    thresholds: dict  # model file name -> the score a box must reach
    stereo: StereoRangeConfig

    @property
    def model_path(self) -> Path:
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
    return settings.load_checked(FrontendConfig, default, path, check_frontend_config)


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
