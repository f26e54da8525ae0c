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


@dataclass(frozen=True)
class FrontendKeyframe:
    pose_index: int
    stamp_ns: int
    left: np.ndarray  # the left image as read (grey or BGR)
    body_pose: np.ndarray  # 4x4: visual odometry's pose of the body, pose 0 the origin
    step: KeyframeStep | None  # the motion that reached this keyframe (none for pose 0)
    tags: list[TagOutline] = field(default_factory=list)
    detections: list[Detection] = field(default_factory=list)


class FrontendSink(Protocol):
    def frontend_start(self, metadata: LogMetadata) -> None: ...

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
    are read again from `sequence`: only the keyframes', and only when something is shown."""
    sink.frontend_start(metadata)
    pose = np.eye(4)
    for index, frame in enumerate(keyframes.frames):
        step = keyframes.steps[index - 1] if index > 0 else None
        if step is not None:
            pose = pose @ step.motion
        left, _ = sequence[frame]
        tags = outlines[index] if index < len(outlines) else []
        sink.frontend_keyframe(
            FrontendKeyframe(
                pose_index=index,
                stamp_ns=stamps_ns[frame],
                left=left,
                body_pose=pose.copy(),
                step=step,
                tags=[TagOutline(int(tag_id), np.asarray(c, float)) for tag_id, c in tags],
                detections=list(detections[index]),
            )
        )
    sink.frontend_finish()
