"""Ground truth of a rendered sequence (`landmarks.json`), and which landmark a detection saw.

`landmarks.json` (written by data_tools/render.py): `{"frame": "body0", "landmarks": [{"id",
"kind": "tag" | "box", "class_name", "tag_id", "position" [x, y, z], "rotation" [qx, qy, qz, qw],
"size" [3]}]}`, positions in the body frame of the sequence's first frame (pose 0 of the log).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.datasets.camera import BODY_FROM_CAMERA, StereoIntrinsics
from pipeline.errors import InputError
from pipeline.frontend.geometry import invert_pose, rotation_from_quaternion
from pipeline.log import GroundTruthLandmark, GroundTruthLandmarks

LANDMARKS_FILE = "landmarks.json"
KINDS = ("tag", "box")


@dataclass(frozen=True)
class TruthLandmark:
    id: int
    kind: str  # "tag" or "box"
    class_name: str
    tag_id: int | None
    position: np.ndarray  # (3,) body frame of pose 0
    rotation: np.ndarray  # 3x3 body0-from-landmark
    size: np.ndarray  # (3,): tags (edge, edge, 0); boxes (length, width, height)


def read_landmarks(path: str | Path) -> list[TruthLandmark]:
    """The landmarks of a `landmarks.json`; InputError naming the file and entry if malformed."""
    path = Path(path)
    try:
        document = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise InputError(f"ground truth {path}: cannot read ({exc})") from None
    if not isinstance(document, dict) or document.get("frame") != "body0":
        raise InputError(f"ground truth {path}: expected an object with frame 'body0'")
    entries = document.get("landmarks")
    if not isinstance(entries, list):
        raise InputError(f"ground truth {path}: 'landmarks' must be a list")
    landmarks = []
    for k, entry in enumerate(entries):
        try:
            kind = entry["kind"]
            if kind not in KINDS:
                raise ValueError(f"kind {kind!r}")
            tag_id = entry.get("tag_id")
            landmark = TruthLandmark(
                id=int(entry["id"]),
                kind=kind,
                class_name=str(entry["class_name"]),
                tag_id=None if tag_id is None else int(tag_id),
                position=np.array(entry["position"], float).reshape(3),
                rotation=rotation_from_quaternion(np.array(entry["rotation"], float).reshape(4)),
                size=np.array(entry["size"], float).reshape(3),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"ground truth {path}: landmarks[{k}] is malformed ({exc})") from None
        if kind == "tag" and landmark.tag_id is None:
            raise InputError(f"ground truth {path}: landmarks[{k}] is a tag without a tag_id")
        if not np.all(np.isfinite(landmark.position)):
            raise InputError(f"ground truth {path}: landmarks[{k}] has a non-finite position")
        landmarks.append(landmark)
    ids = [lm.id for lm in landmarks]
    if len(set(ids)) != len(ids):
        raise InputError(f"ground truth {path}: landmark ids are not unique")
    return landmarks


def landmarks_message(
    landmarks: list[TruthLandmark],
    num_tag_classes: int,
    object_classes: dict[str, int],
    stamp_ns: int,
) -> GroundTruthLandmarks:
    """The log's ground-truth landmarks: tags with class tag id mod C, boxes whose class the
    object stage reports (others cannot be detected and are left out)."""
    entries = []
    for lm in landmarks:
        if lm.kind == "tag":
            class_id = int(lm.tag_id) % num_tag_classes  # type: ignore[arg-type]
        elif lm.class_name in object_classes:
            class_id = object_classes[lm.class_name]
        else:
            continue
        entries.append(
            GroundTruthLandmark(
                id=lm.id,
                class_id=class_id,
                position=tuple(float(v) for v in lm.position),  # type: ignore[arg-type]
            )
        )
    return GroundTruthLandmarks(stamp_ns=stamp_ns, landmarks=tuple(entries))


def tag_truth_ids(landmarks: list[TruthLandmark]) -> dict[int, int]:
    """Landmark id of each tag id."""
    return {int(lm.tag_id): lm.id for lm in landmarks if lm.kind == "tag"}  # type: ignore[arg-type]


def box_corners(landmark: TruthLandmark) -> np.ndarray:
    """The 8 corners (8, 3) of a box landmark in the body frame of pose 0."""
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    local = signs * landmark.size / 2.0
    return local @ landmark.rotation.T + landmark.position


def projected_box(
    corners_body0: np.ndarray, body0_from_body: np.ndarray, intrinsics: StereoIntrinsics
) -> tuple[float, float, float, float] | None:
    """The image box `[u_min, v_min, u_max, v_max]` of 3-D corners seen from a body pose,
    clipped to the image; None if any corner is behind the camera or the box is outside."""
    camera_from_body0 = invert_pose(body0_from_body @ BODY_FROM_CAMERA)
    points = corners_body0 @ camera_from_body0[:3, :3].T + camera_from_body0[:3, 3]
    if np.any(points[:, 2] <= 0.1):
        return None
    u = intrinsics.fx * points[:, 0] / points[:, 2] + intrinsics.cx
    v = intrinsics.fy * points[:, 1] / points[:, 2] + intrinsics.cy
    box = (
        max(float(u.min()), 0.0),
        max(float(v.min()), 0.0),
        min(float(u.max()), intrinsics.width - 1.0),
        min(float(v.max()), intrinsics.height - 1.0),
    )
    if box[0] >= box[2] or box[1] >= box[3]:
        return None
    return box


def box_iou(a: tuple[float, ...], b: tuple[float, ...]) -> float:
    width = min(a[2], b[2]) - max(a[0], b[0])
    height = min(a[3], b[3]) - max(a[1], b[1])
    if width <= 0 or height <= 0:
        return 0.0
    overlap = width * height
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - overlap
    return overlap / union


def box_truth_id(
    bbox: tuple[float, float, float, float],
    landmarks: list[TruthLandmark],
    body0_from_body: np.ndarray,
    intrinsics: StereoIntrinsics,
    min_iou: float,
) -> int:
    """The box landmark whose projection overlaps `bbox` most (IoU >= min_iou), or -1. Whatever
    class the detector reported: the truth is the object seen, and a misclassified detection
    (a car boxed as a truck) still sees it. Occlusion is not modelled: the nearest of two
    overlapping boxes is not preferred."""
    best_id, best_iou = -1, min_iou
    for lm in landmarks:
        if lm.kind != "box":
            continue
        projected = projected_box(box_corners(lm), body0_from_body, intrinsics)
        if projected is None:
            continue
        iou = box_iou(bbox, projected)
        if iou >= best_iou:
            best_id, best_iou = lm.id, iou
    return best_id
