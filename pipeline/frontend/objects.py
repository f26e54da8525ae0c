"""Object boxes: a YOLO-family ONNX detector, then stereo range inside each box.

Any YOLO ONNX model with one image input `(1, 3, H, W)` (RGB in [0, 1]) whose first output holds
decoded rows works: `(1, N, 5 + C)` = `[cx, cy, w, h, objectness, class scores]` (YOLOv3/v5/v7
style; our darknet conversion, `data_tools/darknet_to_onnx.py`, writes this) or `(1, 4 + C, N)`
without objectness (YOLOv8 style), boxes in input pixels. Class names come from the model's
metadata (`names`, as Ultralytics exports write it) or from `class_names_file`.

The stage: letterbox the left image (colour, where the sequence is) to the model's input, run it
(onnxruntime), keep rows whose score (objectness x best class score) reaches the model's own
threshold (`[objects.thresholds]`: scores of different models do not compare) and whose class
the config maps to one of ours, suppress overlaps, undo the letterbox, then range each box from
stereo (`stereo_range.py`). A box without a stereo range is dropped: a detection needs one. A box
mostly inside another at the same disparity is a part of its object (a car's rear, boxed apart
from the whole car) and is merged into it.

No model is downloaded here: `python -m data_tools.models install` puts yolov3-tiny (COCO) into
the models directory (`MMSLAM_MODELS`, default `<venv>/share/mmslam/models`).
"""

from __future__ import annotations

import ast
import dataclasses
import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.datasets.camera import StereoIntrinsics
from pipeline.errors import InputError
from pipeline.frontend.config import ObjectDetectorConfig, StereoRangeConfig
from pipeline.frontend.model_files import MODELS_ENV
from pipeline.frontend.stereo_range import BBox, BoxRange, measure_box

log = logging.getLogger(__name__)

DEFAULT_MODEL = "yolov3-tiny.onnx"
LETTERBOX_FILL = 127  # darknet pads with 0.5 grey


# --- pre- and post-processing: pure functions ------------------------------------------------


@dataclass(frozen=True)
class Letterbox:
    scale: float  # input pixels per image pixel
    pad_x: float
    pad_y: float


def letterbox(image: np.ndarray, width: int, height: int) -> tuple[np.ndarray, Letterbox]:
    """An image (grey or BGR, uint8) as the network's input `(1, 3, height, width)` float32 RGB
    in [0, 1]: scaled to fit whole, centred, the rest grey (darknet's letterbox)."""
    import cv2

    if image.ndim == 2:
        rgb = cv2.cvtColor(image, cv2.COLOR_GRAY2RGB)
    else:
        rgb = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    h, w = rgb.shape[:2]
    scale = min(width / w, height / h)
    new_w, new_h = max(1, round(w * scale)), max(1, round(h * scale))
    resized = cv2.resize(rgb, (new_w, new_h), interpolation=cv2.INTER_LINEAR)
    pad_x, pad_y = (width - new_w) // 2, (height - new_h) // 2
    canvas = np.full((height, width, 3), LETTERBOX_FILL, np.uint8)
    canvas[pad_y : pad_y + new_h, pad_x : pad_x + new_w] = resized
    tensor = canvas.transpose(2, 0, 1)[None].astype(np.float32) / 255.0
    return tensor, Letterbox(scale, float(pad_x), float(pad_y))


def prediction_rows(output: np.ndarray, num_classes: int) -> tuple[np.ndarray, bool]:
    """The model's first output as rows `(N, K)`, and whether the rows hold an objectness
    column (K = 5 + C) or not (K = 4 + C, YOLOv8 style `(1, 4 + C, N)`)."""
    out = np.asarray(output, np.float32)
    if out.ndim == 3 and out.shape[0] == 1:
        out = out[0]
    if out.ndim != 2:
        raise InputError(f"object detector: output of shape {output.shape} is not (1, N, K)")
    for k, objectness in ((5 + num_classes, True), (4 + num_classes, False)):
        if out.shape[1] == k:
            return out, objectness
        if out.shape[0] == k:
            return out.T, objectness
    raise InputError(
        f"object detector: output of shape {output.shape} fits neither 5 + {num_classes} nor "
        f"4 + {num_classes} columns"
    )


def decode_rows(
    rows: np.ndarray, objectness: bool, threshold: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows `[cx, cy, w, h, (objectness,) scores...]` to boxes `[u0, v0, u1, v1]` (input px),
    scores and class indices, of the rows whose best score reaches `threshold`."""
    first = 5 if objectness else 4
    class_scores = rows[:, first:]
    classes = np.argmax(class_scores, axis=1)
    scores = class_scores[np.arange(len(rows)), classes]
    if objectness:
        scores = scores * rows[:, 4]
    keep = scores >= threshold
    cx, cy, w, h = (rows[keep, i] for i in range(4))
    boxes = np.stack([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2], axis=1)
    return boxes.astype(np.float64), scores[keep].astype(np.float64), classes[keep]


def undo_letterbox(boxes: np.ndarray, box: Letterbox, width: int, height: int) -> np.ndarray:
    """Boxes in network-input pixels to image pixels, clipped to the image."""
    out = np.array(boxes, float).reshape(-1, 4)
    out[:, [0, 2]] = (out[:, [0, 2]] - box.pad_x) / box.scale
    out[:, [1, 3]] = (out[:, [1, 3]] - box.pad_y) / box.scale
    out[:, [0, 2]] = out[:, [0, 2]].clip(0, width)
    out[:, [1, 3]] = out[:, [1, 3]].clip(0, height)
    return out


def suppress(boxes: np.ndarray, scores: np.ndarray, iou: float) -> np.ndarray:
    """Indices of the boxes non-maximum suppression keeps, best score first. Class-agnostic on
    purpose: one object gives one detection even when two classes fire on it (which class is the
    confusion matrix's business, not the detector's)."""
    import cv2

    if len(boxes) == 0:
        return np.empty(0, int)
    xywh = [[b[0], b[1], b[2] - b[0], b[3] - b[1]] for b in np.asarray(boxes, float)]
    kept = cv2.dnn.NMSBoxes(xywh, [float(s) for s in scores], 0.0, float(iou))
    kept = np.asarray(kept, int).ravel()
    return kept[np.argsort(-np.asarray(scores)[kept], kind="stable")]


def box_iou(a: BBox, b: BBox) -> float:
    width = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    height = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = width * height
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return inter / union if union > 0 else 0.0


def inside_fraction(inner: BBox, outer: BBox) -> float:
    """The fraction of `inner`'s area that lies inside `outer`."""
    width = max(0.0, min(inner[2], outer[2]) - max(inner[0], outer[0]))
    height = max(0.0, min(inner[3], outer[3]) - max(inner[1], outer[1]))
    area = (inner[2] - inner[0]) * (inner[3] - inner[1])
    return width * height / area if area > 0 else 0.0


def nested_duplicates(
    boxes: list[BBox],
    disparities: np.ndarray,
    sigmas: np.ndarray,
    fraction: float,
    max_sigmas: float,
) -> dict[int, int]:
    """Boxes that are parts of another box's object: `{inner: outer}` for each box with at
    least `fraction` of its area inside a larger box whose disparity agrees with its own within
    `max_sigmas` standard deviations (`hypot` of the two `sigmas`). The outer box is the largest
    such one that is itself no part of another."""
    order = sorted(range(len(boxes)), key=lambda i: -_area(boxes[i]))
    owner: dict[int, int] = {}
    for position, inner in enumerate(order):
        for outer in order[:position]:
            if outer in owner or inside_fraction(boxes[inner], boxes[outer]) < fraction:
                continue
            difference = abs(disparities[inner] - disparities[outer])
            if difference <= max_sigmas * math.hypot(sigmas[inner], sigmas[outer]):
                owner[inner] = outer
                break
    return owner


def _area(box: BBox) -> float:
    return (box[2] - box[0]) * (box[3] - box[1])


# --- the stage -------------------------------------------------------------------------------


@dataclass(frozen=True)
class BoxDetection:
    class_id: int  # ours: an index into the config's `classes`
    class_name: str
    score: float
    bbox: BBox  # [u_min, v_min, u_max, v_max] in image pixels
    detector_class: str  # the detector's own class name (e.g. COCO "truck")


@dataclass(frozen=True)
class ObjectRecord:
    """A box with its stereo range: what the front-end pipeline turns into a log detection."""

    class_id: int
    class_name: str
    score: float
    bbox: BBox
    point: np.ndarray  # (3,) left camera optical frame, m
    covariance: np.ndarray  # (3, 3)
    detector_class: str
    disparity: float  # the box's median disparity (px)
    disparity_sigma: float  # its standard deviation (px)


def add_stereo_range(
    box: BoxDetection,
    left: np.ndarray,
    right: np.ndarray,
    intrinsics: StereoIntrinsics,
    config: StereoRangeConfig,
) -> ObjectRecord | None:
    """The box with its stereo range, or None where stereo finds too few matches in it."""
    found: BoxRange | None = measure_box(left, right, box.bbox, intrinsics, config)
    if found is None:
        return None
    return ObjectRecord(
        box.class_id,
        box.class_name,
        box.score,
        box.bbox,
        found.point,
        found.covariance,
        box.detector_class,
        found.disparity.disparity,
        math.hypot(config.disparity_sigma, found.disparity.spread),
    )


def read_class_names(metadata: dict[str, str], names_file: str) -> list[str]:
    """Class names from a names file if given, else from the model's `names` metadata."""
    if names_file:
        path = Path(names_file).expanduser()
        try:
            return [n.strip() for n in path.read_text().splitlines() if n.strip()]
        except OSError as exc:
            raise InputError(f"objects.class_names_file {path}: cannot read ({exc})") from None
    if "names" in metadata:
        try:
            names = ast.literal_eval(metadata["names"])
        except (ValueError, SyntaxError):
            names = None
        if isinstance(names, dict):
            return [str(names[k]) for k in sorted(names)]
        if isinstance(names, list | tuple):
            return [str(n) for n in names]
    raise InputError(
        "object detector: the model carries no class names; set objects.class_names_file"
    )


class ObjectDetector:
    """The object-box stage: `detect_boxes(image)` finds boxes, `detect(left, right,
    intrinsics)` adds their stereo range (what `pipeline/frontend/run.py` calls)."""

    def __init__(self, config: ObjectDetectorConfig):
        import onnxruntime as ort

        self.config = config
        self.class_names: tuple[str, ...] = config.classes
        path = config.model_path
        if not path.is_file():
            raise InputError(
                f"object detector: no model at {path}; run `python -m data_tools.models install` "
                f"(or set objects.model, or {MODELS_ENV})"
            )
        options = ort.SessionOptions()
        options.intra_op_num_threads = config.num_threads
        options.inter_op_num_threads = 1
        try:
            self.session = ort.InferenceSession(
                str(path), options, providers=["CPUExecutionProvider"]
            )
        except Exception as exc:  # onnxruntime raises its own types for unreadable models
            raise InputError(f"object detector: cannot load {path} ({exc})") from None
        model_input = self.session.get_inputs()[0]
        self.input_name = model_input.name
        shape = model_input.shape
        width, height = config.input_size
        fixed = [d for d in shape[2:] if isinstance(d, int)]
        if len(shape) != 4 or (len(fixed) == 2 and (shape[3], shape[2]) != (width, height)):
            raise InputError(
                f"object detector: {path.name} takes input {shape}; objects.input_size is "
                f"[{width}, {height}]"
            )
        metadata = self.session.get_modelmeta().custom_metadata_map
        self.detector_classes = read_class_names(metadata, config.class_names_file)
        ours = {name: i for i, name in enumerate(config.classes)}
        self._class_of: dict[int, int] = {}
        for detector_name, our_name in config.class_map.items():
            if detector_name not in self.detector_classes:
                raise InputError(
                    f"config: objects.class_map.{detector_name}: the model has no such class"
                )
            self._class_of[self.detector_classes.index(detector_name)] = ours[our_name]
        log.info(
            "object detector %s: %d classes, %s mapped",
            path.name,
            len(self.detector_classes),
            ", ".join(f"{d}->{o}" for d, o in config.class_map.items()),
        )

    def detect_boxes(self, image: np.ndarray) -> list[BoxDetection]:
        """Boxes of our classes in one image (grey or BGR), best score first."""
        width, height = self.config.input_size
        tensor, box = letterbox(image, width, height)
        output = self.session.run(None, {self.input_name: tensor})[0]
        rows, objectness = prediction_rows(output, len(self.detector_classes))
        boxes, scores, classes = decode_rows(rows, objectness, self.config.confidence_threshold)
        mapped = np.array([int(c) in self._class_of for c in classes], bool)
        boxes, scores, classes = boxes[mapped], scores[mapped], classes[mapped]
        boxes = undo_letterbox(boxes, box, image.shape[1], image.shape[0])
        found = []
        for i in suppress(boxes, scores, self.config.nms_iou):
            ours = self._class_of[int(classes[i])]
            found.append(
                BoxDetection(
                    class_id=ours,
                    class_name=self.class_names[ours],
                    score=float(scores[i]),
                    bbox=tuple(float(v) for v in boxes[i]),  # type: ignore[arg-type]
                    detector_class=self.detector_classes[int(classes[i])],
                )
            )
        return found

    def detect(
        self, left: np.ndarray, right: np.ndarray, intrinsics: StereoIntrinsics
    ) -> list[ObjectRecord]:
        """Boxes in the left image with their stereo range, best score first; boxes stereo
        cannot range are dropped, and boxes of parts of another box's object are merged into
        it (`nested_duplicates`; it keeps the better score)."""
        records = []
        for box in self.detect_boxes(left):
            record = add_stereo_range(box, left, right, intrinsics, self.config.stereo)
            if record is None:
                log.debug("object box %s: no stereo range", box.bbox)
            else:
                records.append(record)
        owner = nested_duplicates(
            [r.bbox for r in records],
            np.array([r.disparity for r in records]),
            np.array([r.disparity_sigma for r in records]),
            self.config.nested_fraction,
            self.config.nested_sigmas,
        )
        scores = [r.score for r in records]
        for inner, outer in owner.items():
            log.debug("object box %s: part of %s", records[inner].bbox, records[outer].bbox)
            scores[outer] = max(scores[outer], scores[inner])
        kept = [
            dataclasses.replace(r, score=scores[i]) for i, r in enumerate(records) if i not in owner
        ]
        return sorted(kept, key=lambda r: -r.score)
