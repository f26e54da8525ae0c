"""Pure conversions to Foxglove's well-known messages (`foxglove.messages`, from foxglove-sdk).

Each function builds one message from plain values: stamps in nanoseconds, translations [3],
quaternions [x, y, z, w] (the contract's order, which is also Foxglove's).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import foxglove.messages as fg
import numpy as np

from pipeline.geometry import quaternion_from_rotation
from pipeline.log.messages import Detection, StereoCalibration

WORLD = "world"
BODY = "body"
CAMERA = "camera_left"

# A colour per class id, cycling (matplotlib's tab10), and fixed colours for what is not a class.
CLASS_COLOURS = (
    (0.12, 0.47, 0.71),
    (1.00, 0.50, 0.05),
    (0.17, 0.63, 0.17),
    (0.84, 0.15, 0.16),
    (0.58, 0.40, 0.74),
    (0.55, 0.34, 0.29),
    (0.89, 0.47, 0.76),
    (0.50, 0.50, 0.50),
    (0.74, 0.74, 0.13),
    (0.09, 0.75, 0.81),
)
NULL_COLOUR = (0.9, 0.1, 0.1)
# Sizes in metres for the 3D panel: a landmark is drawn as a sphere, a detection smaller.
LANDMARK_SIZE_M = 0.5
DETECTION_SIZE_M = 0.25
LINE_THICKNESS_PX = 1.5


def class_name(names: Sequence[str], class_id: int) -> str:
    return names[class_id] if 0 <= class_id < len(names) else str(class_id)


def timestamp(stamp_ns: int) -> fg.Timestamp:
    return fg.Timestamp(sec=int(stamp_ns) // 1_000_000_000, nsec=int(stamp_ns) % 1_000_000_000)


def colour(rgb: Sequence[float], alpha: float = 1.0) -> fg.Color:
    r, g, b = rgb
    return fg.Color(r=float(r), g=float(g), b=float(b), a=float(alpha))


def class_colour(class_id: int, alpha: float = 1.0) -> fg.Color:
    return colour(CLASS_COLOURS[class_id % len(CLASS_COLOURS)], alpha)


def point3(p: Sequence[float]) -> fg.Point3:
    return fg.Point3(x=float(p[0]), y=float(p[1]), z=float(p[2]))


def pose(translation: Sequence[float], rotation: Sequence[float] = (0, 0, 0, 1)) -> fg.Pose:
    x, y, z, w = (float(v) for v in rotation)
    return fg.Pose(
        position=fg.Vector3(
            x=float(translation[0]), y=float(translation[1]), z=float(translation[2])
        ),
        orientation=fg.Quaternion(x=x, y=y, z=z, w=w),
    )


def pose_of_matrix(T: np.ndarray) -> fg.Pose:
    return pose(T[:3, 3], quaternion_from_rotation(T[:3, :3]))


def pose_in_frame(stamp_ns: int, value: fg.Pose, frame: str = WORLD) -> fg.PoseInFrame:
    return fg.PoseInFrame(timestamp=timestamp(stamp_ns), frame_id=frame, pose=value)


def poses_in_frame(stamp_ns: int, values: list[fg.Pose], frame: str = WORLD) -> fg.PosesInFrame:
    return fg.PosesInFrame(timestamp=timestamp(stamp_ns), frame_id=frame, poses=values)


def frame_transform(stamp_ns: int, parent: str, child: str, T: np.ndarray) -> fg.FrameTransform:
    """`T` = parent_from_child: takes `child` coordinates into `parent` ones."""
    x, y, z, w = (float(v) for v in quaternion_from_rotation(T[:3, :3]))
    return fg.FrameTransform(
        timestamp=timestamp(stamp_ns),
        parent_frame_id=parent,
        child_frame_id=child,
        translation=fg.Vector3(x=float(T[0, 3]), y=float(T[1, 3]), z=float(T[2, 3])),
        rotation=fg.Quaternion(x=x, y=y, z=z, w=w),
    )


def camera_calibration(calibration: StereoCalibration, frame: str = CAMERA) -> fg.CameraCalibration:
    """The left camera's pinhole model (rectified images: no distortion, R = I)."""
    c = calibration
    K = [c.fx, 0.0, c.cx, 0.0, c.fy, c.cy, 0.0, 0.0, 1.0]
    return fg.CameraCalibration(
        timestamp=timestamp(c.stamp_ns),
        frame_id=frame,
        width=int(c.width),
        height=int(c.height),
        distortion_model="plumb_bob",
        D=[0.0] * 5,
        K=[float(v) for v in K],
        R=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        P=[c.fx, 0.0, c.cx, 0.0, 0.0, c.fy, c.cy, 0.0, 0.0, 0.0, 1.0, 0.0],
    )


def scene_entity(stamp_ns: int, frame: str, entity_id: str, **primitives: Any) -> fg.SceneEntity:
    """An entity of `primitives` (spheres=, lines=, texts=: lists of them) in `frame`, that
    replaces the previous of its id."""
    return fg.SceneEntity(timestamp=timestamp(stamp_ns), frame_id=frame, id=entity_id, **primitives)


def sphere_entity(
    stamp_ns: int,
    entity_id: str,
    position: Sequence[float],
    rgb_alpha: fg.Color,
    size_m: float,
    label: str | None = None,
    frame: str = WORLD,
) -> fg.SceneEntity:
    """One sphere (and its label above it) that stays until replaced."""
    texts = []
    if label:
        above = (position[0], position[1], position[2] + size_m)
        texts = [
            fg.TextPrimitive(
                pose=pose(above),
                billboard=True,
                font_size=12.0,
                scale_invariant=True,
                color=colour((1.0, 1.0, 1.0)),
                text=label,
            )
        ]
    size = fg.Vector3(x=size_m, y=size_m, z=size_m)
    sphere = fg.SpherePrimitive(pose=pose(position), size=size, color=rgb_alpha)
    return scene_entity(stamp_ns, frame, entity_id, spheres=[sphere], texts=texts)


def landmark_update(
    stamp_ns: int,
    landmarks: Iterable[tuple[int, Sequence[float], int, str]],
    prefix: str = "landmark",
) -> fg.SceneUpdate:
    """A sphere per landmark (id, position, class id, label), coloured by class."""
    return fg.SceneUpdate(
        entities=[
            sphere_entity(stamp_ns, f"{prefix} {i}", p, class_colour(c), LANDMARK_SIZE_M, label)
            for i, p, c, label in landmarks
        ]
    )


def lines_entity(
    stamp_ns: int,
    entity_id: str,
    segments: Sequence[tuple[Sequence[float], Sequence[float], fg.Color]],
    frame: str = WORLD,
) -> fg.SceneEntity:
    """Line segments (start, end, colour), one entity that replaces the previous of its id."""
    points, colours = [], []
    for start, end, segment_colour in segments:
        points += [point3(start), point3(end)]
        colours += [segment_colour, segment_colour]
    lines = [
        fg.LinePrimitive(
            type=fg.LinePrimitiveLineType.LineList,
            pose=pose((0.0, 0.0, 0.0)),
            thickness=LINE_THICKNESS_PX,
            scale_invariant=True,
            points=points,
            colors=colours,
        )
    ]
    return scene_entity(stamp_ns, frame, entity_id, lines=lines if points else [])


def detection_update(
    stamp_ns: int, points: Sequence[Sequence[float]], class_ids: Sequence[int]
) -> fg.SceneUpdate:
    """This keyframe's detections where they put their objects, in the body frame; one entity
    per keyframe, replaced by the next."""
    spheres = [
        fg.SpherePrimitive(
            pose=pose(p),
            size=fg.Vector3(x=DETECTION_SIZE_M, y=DETECTION_SIZE_M, z=DETECTION_SIZE_M),
            color=class_colour(c, 0.8),
        )
        for p, c in zip(points, class_ids, strict=True)
    ]
    return fg.SceneUpdate(entities=[scene_entity(stamp_ns, BODY, "detections", spheres=spheres)])


def image_annotations(
    stamp_ns: int, detections: Iterable[Detection], class_names: Sequence[str]
) -> fg.ImageAnnotations:
    """Each detection's box (tags and object boxes alike) with its class and score, to lay over
    the left image of the same stamp."""
    boxes, texts = [], []
    for detection in detections:
        if detection.bbox is None:
            continue
        u0, v0, u1, v1 = (float(v) for v in detection.bbox)
        outline = class_colour(detection.class_id)
        boxes.append(
            fg.PointsAnnotation(
                timestamp=timestamp(stamp_ns),
                type=fg.PointsAnnotationType.LineLoop,
                points=[fg.Point2(x=u, y=v) for u, v in ((u0, v0), (u1, v0), (u1, v1), (u0, v1))],
                outline_color=outline,
                thickness=2.0,
            )
        )
        name = class_name(class_names, detection.class_id)
        texts.append(
            fg.TextAnnotation(
                timestamp=timestamp(stamp_ns),
                position=fg.Point2(x=u0, y=v0),
                text=f"{detection.source} {name} {detection.score:.2f}",
                font_size=12.0,
                text_color=colour((1.0, 1.0, 1.0)),
                background_color=class_colour(detection.class_id, 0.6),
            )
        )
    return fg.ImageAnnotations(timestamp=timestamp(stamp_ns), points=boxes, texts=texts)


def event(stamp_ns: int, text: str, warning: bool = False) -> fg.Log:
    return fg.Log(
        timestamp=timestamp(stamp_ns),
        level=fg.LogLevel.Warning if warning else fg.LogLevel.Info,
        message=text,
        name="mmslam",
    )
