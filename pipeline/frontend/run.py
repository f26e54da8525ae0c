"""The front-end pipeline: a stereo sequence in, a contract-v1 detection log out.

Stages, each with its own progress bar: visual odometry over every frame (it chooses the
keyframes, which are the log's poses), AprilTags at the keyframes, object boxes at the keyframes
(wherever the detector model is installed), then the log. The stages know nothing of each
other; this module only runs them and writes what they give.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, TypeVar

import numpy as np

from pipeline.datasets.kitti import camera_poses_to_body
from pipeline.datasets.layouts import SequenceOptions, open_sequence
from pipeline.datasets.stereo import StereoSequence
from pipeline.errors import InputError
from pipeline.foxglove.log_topics import foxglove_mirror
from pipeline.frontend.apriltags import AprilTagDetector, tag_detection
from pipeline.frontend.classes import tag_class_names
from pipeline.frontend.config import FrontendConfig, OutputConfig, load_frontend_config
from pipeline.frontend.geometry import camera_point_measurement, quaternion_from_rotation
from pipeline.frontend.ground_truth import (
    LANDMARKS_FILE,
    TruthLandmark,
    box_truth_id,
    landmarks_message,
    read_landmarks,
    tag_truth_ids,
)
from pipeline.frontend.stereo_vo import KeyframeStep, StereoOdometry, stereo_diagnosis
from pipeline.log import (
    CompressedImage,
    Detection,
    Detections,
    GroundTruthLandmarks,
    GroundTruthPose,
    LogMetadata,
    LogWriter,
    Odometry,
)
from pipeline.log.schemas import LEFT_IMAGE, RIGHT_IMAGE
from pipeline.progress import track
from pipeline.viz.frontend import show_keyframes
from pipeline.viz.sink import NullSink

if TYPE_CHECKING:
    from pipeline.viz.frontend import FrontendSink

log = logging.getLogger(__name__)

Sequence = StereoSequence
T = TypeVar("T")


@dataclass(frozen=True)
class FrontendSummary:
    sequence: Path
    out: Path
    num_frames: int
    num_poses: int
    num_tag_detections: int
    num_box_detections: int
    vo_lost: int  # keyframes whose motion is a constant-velocity guess
    stage_seconds: dict[str, float] = field(default_factory=dict)
    unpaired_frames: int = 0  # left or right frames without a partner, left out
    object_boxes: bool = True  # whether the object-box stage ran

    def summary_line(self) -> str:
        stages = ", ".join(f"{name} {s:.1f} s" for name, s in self.stage_seconds.items())
        unpaired = (
            f", {self.unpaired_frames} frames without a stereo partner left out"
            if self.unpaired_frames
            else ""
        )
        boxes = (
            f"{self.num_box_detections} box detections"
            if self.object_boxes
            else "no box detections (object boxes off)"
        )
        return (
            f"{self.out}: {self.num_poses} poses from {self.num_frames} frames, "
            f"{self.num_tag_detections} tag and {boxes}, "
            f"{self.vo_lost} odometry losses{unpaired} ({stages})"
        )


class ObjectStage(Protocol):
    """What the pipeline needs of the object-box stage (pipeline/frontend/objects.py)."""

    class_names: tuple[str, ...]

    def detect(self, left: np.ndarray, right: np.ndarray, intrinsics: Any) -> list[Any]: ...


def _progress(items: Iterable[T], enabled: bool, description: str, total: int) -> Iterator[T]:
    return track(items, total, description, "frame", enabled=enabled)


def stamps_ns(sequence: Sequence) -> list[int]:
    """The frames' stamps (ns), refused if negative (a log's stamps are not)."""
    stamps = sequence.stamps_ns()
    if stamps[0] < 0:
        raise InputError(
            f"sequence {sequence.root}: times start at {sequence.times[0]} s: stamps must not "
            "be negative"
        )
    return stamps


def run_apriltags(
    sequence: Sequence,
    keyframes: list[int],
    config: FrontendConfig,
    truth_ids: dict[int, int] | None,
    progress: bool,
    outlines: list[list[tuple[int, np.ndarray]]] | None = None,
) -> list[list[Detection]]:
    """The tag detections of every keyframe; with `outlines`, each keyframe's (tag id, corners)
    are appended to it too (for a viewer)."""
    detector = AprilTagDetector(config.apriltags, sequence.intrinsics)
    per_keyframe = []
    for frame in _progress(keyframes, progress, "apriltags", len(keyframes)):
        left, right = sequence[frame]
        detections = []
        observations = detector.observe(left, right)
        if outlines is not None:
            outlines.append([(o.tag_id, o.corners) for o in observations])
        for observation in observations:
            truth = None if truth_ids is None else truth_ids.get(observation.tag_id, -1)
            detections.append(
                tag_detection(
                    observation,
                    sequence.intrinsics,
                    config.classes.num_classes,
                    config.apriltags.full_score_margin,
                    truth,
                )
            )
        per_keyframe.append(detections)
    log.info(
        "apriltags: right image %d detected, %d tracked, %d dropped",
        detector.right_detected,
        detector.right_tracked,
        detector.dropped,
    )
    return per_keyframe


def boxes_wanted(config: FrontendConfig) -> bool:
    """Whether the object-box stage runs: `[objects] enabled`, and its model installed (or
    `require_model`, which makes a missing model an error)."""
    objects = config.objects
    return objects.enabled and (objects.require_model or objects.model_path.is_file())


def make_object_stage(config: FrontendConfig) -> ObjectStage | None:
    """The object-box stage where `boxes_wanted` (enabled without its model: a note, no
    stage); imported only then (it loads a model)."""
    objects = config.objects
    if not boxes_wanted(config):
        if objects.enabled:
            log.warning(
                "object boxes off: no detector model at %s; `make models` (or `python -m "
                "data_tools.models install`) installs yolov3-tiny there",
                objects.model_path,
            )
        return None
    from pipeline.frontend.objects import ObjectDetector

    return ObjectDetector(objects)


def run_objects(
    sequence: Sequence,
    keyframes: list[int],
    stage: ObjectStage,
    class_offset: int,
    truth: list[TruthLandmark] | None,
    body_poses: np.ndarray | None,
    config: FrontendConfig,
    progress: bool,
) -> list[list[Detection]]:
    """The box detections of every keyframe; classes follow the tags' (offset)."""
    per_keyframe = []
    for frame in _progress(keyframes, progress, "objects", len(keyframes)):
        left, right = sequence.images(frame)  # colour where the sequence is: detectors want it
        detections = []
        for record in stage.detect(left, right, sequence.intrinsics):
            truth_id = None
            if truth is not None and body_poses is not None:
                truth_id = box_truth_id(
                    tuple(record.bbox),
                    truth,
                    body_poses[frame],
                    sequence.intrinsics,
                    config.output.truth_min_iou,
                )
            detections.append(box_detection(record, class_offset, truth_id))
        per_keyframe.append(detections)
    return per_keyframe


def box_detection(record: Any, class_offset: int, truth_landmark_id: int | None) -> Detection:
    """The log's detection of an object box from the object stage's record: `class_id` (in the
    stage's own classes), `score`, `bbox`, and `point` (3) with `covariance` (3x3) in the camera
    frame."""
    measurement, covariance = camera_point_measurement(
        np.asarray(record.point, float), np.asarray(record.covariance, float)
    )
    return Detection(
        class_id=class_offset + int(record.class_id),
        score=float(np.clip(record.score, 0.0, 1.0)),
        bearing=float(measurement[0]),
        elevation=float(measurement[1]),
        range=float(measurement[2]),
        covariance=tuple(float(v) for v in covariance.ravel()),
        source="bbox",
        bbox=tuple(float(v) for v in record.bbox),  # type: ignore[arg-type]
        truth_landmark_id=truth_landmark_id,
    )


def class_metadata(
    config: FrontendConfig, object_stage: ObjectStage | None, source: str
) -> LogMetadata:
    """Tag classes (id mod C) first, then the object stage's classes; the confusion matrix is
    block-diagonal: tags as configured, objects as the stage says (identity if it says
    nothing)."""
    count = config.classes.num_classes
    names = tag_class_names(count)
    diagonal = config.classes.tag_confusion_diagonal
    off = (1.0 - diagonal) / (count - 1) if count > 1 else 0.0
    blocks = [np.full((count, count), off) + np.eye(count) * (diagonal - off)]
    if object_stage is not None:
        names += list(object_stage.class_names)
        confusion = getattr(object_stage, "confusion_matrix", None)
        size = len(object_stage.class_names)
        blocks.append(np.eye(size) if confusion is None else np.asarray(confusion, float))
    total = sum(len(b) for b in blocks)
    matrix = np.zeros((total, total))
    start = 0
    for block in blocks:
        matrix[start : start + len(block), start : start + len(block)] = block
        start += len(block)
    return LogMetadata(
        num_classes=total,
        confusion_matrix=tuple(tuple(float(v) for v in row) for row in matrix),
        class_names=tuple(names),
        source=source,
    )


def encode_image(image: np.ndarray, image_format: str, jpeg_quality: int) -> bytes:
    import cv2

    if image_format == "jpeg":
        ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality])
    else:
        ok, data = cv2.imencode(".png", image)
    if not ok:
        raise RuntimeError(f"could not encode an image as {image_format}")
    return data.tobytes()


def _pose_parts(pose: np.ndarray) -> tuple[tuple[float, float, float], tuple[float, ...]]:
    translation = tuple(float(v) for v in pose[:3, 3])
    return translation, tuple(quaternion_from_rotation(pose[:3, :3]).tolist())  # type: ignore[return-value]


@dataclass(frozen=True)
class Keyframes:
    """What visual odometry gives the other stages: the log's poses."""

    frames: list[int]  # frame index of each pose; the first is 0
    steps: list[KeyframeStep]  # steps[k] links pose k to pose k + 1
    lost: int


def run_odometry(sequence: Sequence, config: FrontendConfig, progress: bool) -> Keyframes:
    """Visual odometry over every frame; it chooses the keyframes. Every step lost is bad
    input: the log would hold no motion at all."""
    odometry = StereoOdometry(sequence.intrinsics, config.vo, config.keyframes)
    frames, steps = [], []
    for index in _progress(range(len(sequence)), progress, "visual odometry", len(sequence)):
        left, right = sequence[index]
        step = odometry.process(index, left, right)
        if index == 0:
            frames.append(0)
        elif step is not None:
            frames.append(index)
            steps.append(step)
    last = odometry.finish()
    if last is not None:
        frames.append(last.frame_index)
        steps.append(last)
    lost = [step.frame_index for step in steps if step.lost]
    if steps and len(lost) == len(steps):
        raise InputError(
            f"sequence {sequence.root}: visual odometry lost every frame "
            f"({stereo_diagnosis(*sequence[0], config.vo)})"
        )
    if lost:
        shown = ", ".join(str(frame) for frame in lost[:10]) + (", ..." if len(lost) > 10 else "")
        log.warning(
            "visual odometry lost %d of %d keyframe steps (frames %s): constant velocity with "
            "a large covariance there",
            len(lost),
            len(steps),
            shown,
        )
    return Keyframes(frames, steps, odometry.lost_count)


def write_log(
    out: Path,
    metadata: LogMetadata,
    sequence: Sequence,
    keyframes: Keyframes,
    detections: list[list[Detection]],
    body_poses: np.ndarray | None,
    truth: GroundTruthLandmarks | None,
    images: OutputConfig | None,
    progress: bool,
) -> None:
    """The log: calibration and ground-truth landmarks first, then pose by pose its odometry,
    detections, ground-truth pose and (if `images` says how) images."""
    stamps = stamps_ns(sequence)
    with LogWriter(out, metadata, foxglove_mirror) as writer:
        writer.write(sequence.intrinsics.calibration_message(stamps[0]))
        if truth is not None:
            writer.write(dataclasses.replace(truth, stamp_ns=stamps[0]))
        frames = keyframes.frames
        for pose_index, frame in enumerate(_progress(frames, progress, "write log", len(frames))):
            stamp = stamps[frame]
            if pose_index > 0:
                step = keyframes.steps[pose_index - 1]
                translation, rotation = _pose_parts(step.motion)
                writer.write(
                    Odometry(
                        stamp_ns=stamp,
                        from_index=pose_index - 1,
                        to_index=pose_index,
                        translation=translation,
                        rotation=rotation,  # type: ignore[arg-type]
                        covariance=tuple(float(v) for v in step.covariance.ravel()),
                    )
                )
            writer.write(Detections(stamp, pose_index, tuple(detections[pose_index])))
            if body_poses is not None:
                translation, rotation = _pose_parts(body_poses[frame])
                writer.write(GroundTruthPose(stamp, pose_index, translation, rotation))  # type: ignore[arg-type]
            if images is not None:
                pair = sequence.images(frame)
                for topic, image in zip((LEFT_IMAGE, RIGHT_IMAGE), pair, strict=True):
                    data = encode_image(image, images.image_format, images.jpeg_quality)
                    frame_id = "camera_left" if topic == LEFT_IMAGE else "camera_right"
                    writer.write(CompressedImage(stamp, frame_id, images.image_format, data), topic)


@contextmanager
def _timed(seconds: dict[str, float], stage: str) -> Iterator[None]:
    started = time.perf_counter()
    yield
    seconds[stage] = time.perf_counter() - started


def run_frontend(
    sequence_dir: Path,
    out: Path,
    config_path: Path | None = None,
    *,
    images: bool = False,
    progress: bool = True,
    sink: FrontendSink | None = None,
    left_topic: str | None = None,
    right_topic: str | None = None,
    calibration: Path | None = None,
) -> FrontendSummary:
    """Turn a stereo sequence (KITTI, EuRoC or plain layout, or a ROS bag) into a contract-v1
    log at `out`. A bag's stereo topics are `left_topic` and `right_topic` (found when None),
    its calibration `calibration` (a plain-layout calibration.toml; default: its CameraInfo).

    `images` (or `[output] images` in the config) also writes the keyframes' images;
    `progress` shows a progress bar per stage when stderr is a terminal; `sink` (a Rerun sink,
    `pipeline/viz`; default: one that shows nothing) is shown every keyframe once the stages are
    done. The caller closes it.
    """
    import cv2

    sink = sink or NullSink()
    cv2.setNumThreads(1)  # one core a run: runs are parallelised by the caller
    config = load_frontend_config(config_path)
    options = SequenceOptions(
        config.input.stereo_stamp_tolerance, left_topic, right_topic, calibration
    )
    sequence = open_sequence(sequence_dir, boxes_wanted(config), options)
    if len(sequence) < 2:
        raise InputError(f"sequence {sequence_dir}: needs at least two frames")
    stamps_ns(sequence)  # refuse bad times before the work
    landmarks_path = Path(sequence_dir) / LANDMARKS_FILE
    truth = read_landmarks(landmarks_path) if landmarks_path.is_file() else None
    body_poses = None if sequence.gt_poses is None else camera_poses_to_body(sequence.gt_poses)
    object_stage = make_object_stage(config)
    seconds: dict[str, float] = {}

    with _timed(seconds, "odometry"):
        keyframes = run_odometry(sequence, config, progress)
    log.info("visual odometry: %d keyframes of %d frames", len(keyframes.frames), len(sequence))
    tags: list[list[Detection]] = [[] for _ in keyframes.frames]
    outlines: list[list[tuple[int, np.ndarray]]] = []  # per keyframe (tag id, corners), to show
    if config.apriltags.enabled:
        with _timed(seconds, "apriltags"):
            truth_ids = None if truth is None else tag_truth_ids(truth)
            tags = run_apriltags(sequence, keyframes.frames, config, truth_ids, progress, outlines)
    boxes: list[list[Detection]] = [[] for _ in keyframes.frames]
    if object_stage is not None:
        with _timed(seconds, "objects"):
            boxes = run_objects(
                sequence,
                keyframes.frames,
                object_stage,
                config.classes.num_classes,
                truth,
                body_poses,
                config,
                progress,
            )

    metadata = class_metadata(
        config, object_stage, _source_text(config, object_stage, sequence_dir)
    )
    truth_message = None
    if truth is not None:
        object_classes = {
            name: metadata.class_names.index(name)
            for name in getattr(object_stage, "class_names", ())
        }
        truth_message = landmarks_message(truth, config.classes.num_classes, object_classes, 0)
    found = [t + b for t, b in zip(tags, boxes, strict=True)]
    with _timed(seconds, "viz"):
        show_keyframes(sink, sequence, keyframes, stamps_ns(sequence), outlines, found, metadata)
    with _timed(seconds, "write"):
        write_log(
            out,
            metadata,
            sequence,
            keyframes,
            found,
            body_poses,
            truth_message,
            config.output if images or config.output.images else None,
            progress,
        )

    summary = FrontendSummary(
        sequence=Path(sequence_dir),
        out=Path(out),
        num_frames=len(sequence),
        num_poses=len(keyframes.frames),
        num_tag_detections=sum(len(d) for d in tags),
        num_box_detections=sum(len(d) for d in boxes),
        vo_lost=keyframes.lost,
        stage_seconds=seconds,
        unpaired_frames=sequence.unmatched_left + sequence.unmatched_right,
        object_boxes=object_stage is not None,
    )
    return summary


def _source_text(
    config: FrontendConfig, object_stage: ObjectStage | None, sequence_dir: Path
) -> str:
    stages = ["stereo visual odometry"]
    if config.apriltags.enabled:
        stages.append(
            f"apriltag {config.apriltags.family} (class = id mod {config.classes.num_classes})"
        )
    if object_stage is not None:
        stages.append("object boxes")
    return f"mmslam frontend: {', '.join(stages)}; sequence {Path(sequence_dir).name}"
