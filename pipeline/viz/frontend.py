"""What the front-end shows a sink: per keyframe, the left image, the tags and boxes found, and
the visual-odometry pose. No Rerun here: `pipeline/frontend/run.py` calls `show_keyframes`
once its stages are done, with whatever sink it was given."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from pipeline.log.messages import Detection, LogMetadata

if TYPE_CHECKING:
    from pipeline.frontend.stereo_vo import KeyframeStep


@dataclass(frozen=True)
class TagOutline:
    tag_id: int
    corners: np.ndarray  # (4, 2) left-image pixels, libapriltag's order
    detection: Detection | None = None  # the log's detection of this tag (its range, class)


@dataclass(frozen=True)
class FrontendKeyframe:
    pose_index: int
    stamp_ns: int
    left: np.ndarray | None  # the left image as read (grey or BGR); None unless wanted
    body_pose: np.ndarray  # 4x4: visual odometry's pose of the body, pose 0 the origin
    step: KeyframeStep | None  # the motion that reached this keyframe (none for pose 0)
    tags: list[TagOutline] = field(default_factory=list)
    detections: list[Detection] = field(default_factory=list)


class FrontendSink(Protocol):
    """Sees a front-end run's keyframes once its stages are done (see `show_keyframes`)."""

    wants_images: bool  # the keyframes' images are read again only for a sink that shows them

    def frontend_start(self, metadata: LogMetadata, extent: np.ndarray | None = None) -> None: ...

    def frontend_keyframe(self, keyframe: FrontendKeyframe) -> None: ...

    def frontend_finish(self) -> None: ...


def show_keyframes(
    sink: FrontendSink,
    sequence: Any,
    keyframes: Any,
    stamps_ns: list[int],
    outlines: list[list[tuple[int, np.ndarray]]],
    detections: list[list[Detection]],
    metadata: LogMetadata,
) -> None:
    """Hand every keyframe to `sink`, in order. `keyframes` is the front-end's `Keyframes`
    (frames, steps); `outlines` per keyframe (tag id, corners), or empty without tags. Images
    are read again from `sequence`: only the keyframes', and only for a sink that wants them."""
    poses = [np.eye(4)]
    for step in keyframes.steps[: len(keyframes.frames) - 1]:
        poses.append(poses[-1] @ step.motion)
    sink.frontend_start(metadata, np.array([pose[:3, 3] for pose in poses]))
    for index, frame in enumerate(keyframes.frames):
        step = keyframes.steps[index - 1] if index > 0 else None
        left = sequence[frame][0] if sink.wants_images else None
        tags = outlines[index] if index < len(outlines) else []
        found = list(detections[index])
        sink.frontend_keyframe(
            FrontendKeyframe(
                pose_index=index,
                stamp_ns=stamps_ns[frame],
                left=left,
                body_pose=poses[index].copy(),
                step=step,
                tags=[tag_outline(int(tag_id), np.asarray(c, float), found) for tag_id, c in tags],
                detections=found,
            )
        )
    sink.frontend_finish()


def tag_outline(tag_id: int, corners: np.ndarray, detections: list[Detection]) -> TagOutline:
    """A tag's outline with its detection: the tag detection whose box bounds these corners."""
    low, high = corners.min(axis=0), corners.max(axis=0)
    box = (float(low[0]), float(low[1]), float(high[0]), float(high[1]))
    for d in detections:
        if d.source == "apriltag" and d.bbox is not None and np.allclose(d.bbox, box):
            return TagOutline(tag_id, corners, d)
    return TagOutline(tag_id, corners)
