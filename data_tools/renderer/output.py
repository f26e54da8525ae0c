"""Ground-truth files written beside the KITTI layout: `landmarks.json` and `visibility.json`.

The KITTI files themselves (`calib.txt`, `times.txt`, `poses.txt`) are written by
`pipeline.datasets.kitti`, the module that reads them back.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from data_tools.renderer.geometry import invert_transform
from data_tools.renderer.scene import Scene
from pipeline.geometry import quaternion_from_rotation, transform_points

TAG_CLASS_NAME = "apriltag"
TAG_FAMILY = "tag36h11"


def _rounded(values: np.ndarray, digits: int = 9) -> list[float]:
    # Fixed rounding keeps the files byte-identical across runs and short to read.
    return [round(float(v), digits) + 0.0 for v in np.ravel(values)]


def landmark_records(scene: Scene, world_from_body0: np.ndarray) -> list[dict[str, Any]]:
    """Tags and boxes in the body frame of pose 0 (x forward, y left, z up)."""
    body0_from_world = invert_transform(world_from_body0)
    rotation = body0_from_world[:3, :3]
    records = []
    for tag in scene.tags:
        corners = transform_points(body0_from_world, tag.corners())
        records.append(
            {
                "id": tag.tag_id,
                "kind": "tag",
                "class_name": TAG_CLASS_NAME,
                "tag_id": tag.tag_id,
                "family": TAG_FAMILY,
                "position": _rounded(transform_points(body0_from_world, tag.centre[None])[0]),
                "rotation": _rounded(quaternion_from_rotation(rotation @ tag.rotation)),
                "size": [tag.size, tag.size, 0.0],
                "corners": [_rounded(c) for c in corners],
            }
        )
    for obj in scene.objects:
        records.append(
            {
                "id": obj.landmark_id,
                "kind": "box",
                "class_name": obj.class_name,
                "tag_id": None,
                "position": _rounded(transform_points(body0_from_world, obj.centre[None])[0]),
                "rotation": _rounded(quaternion_from_rotation(rotation @ obj.rotation)),
                "size": _rounded(obj.size),
            }
        )
    return records


def write_landmarks(path: Path, scene: Scene, world_from_body0: np.ndarray) -> None:
    document = {"frame": "body0", "landmarks": landmark_records(scene, world_from_body0)}
    path.write_text(json.dumps(document, indent=1) + "\n")


def visible_landmarks(owner: np.ndarray, supersample: int) -> list[dict[str, Any]]:
    """What each landmark covers in one image, from a renderer's owner buffer: `pixels` (area
    in pixels, occlusion included) and `bbox` `[u_min, v_min, u_max, v_max]` (inclusive pixel
    indices)."""
    rows, cols = np.nonzero(owner >= 0)
    if rows.size == 0:
        return []
    ids = owner[rows, cols]
    order = np.argsort(ids, kind="stable")
    ids, rows, cols = ids[order], rows[order], cols[order]
    unique, starts, counts = np.unique(ids, return_index=True, return_counts=True)
    entries = []
    for landmark, start, count in zip(unique, starts, counts, strict=True):
        r = rows[start : start + count] // supersample
        c = cols[start : start + count] // supersample
        entries.append(
            {
                "id": int(landmark),
                "pixels": round(float(count) / supersample**2, 2),
                "bbox": [int(c.min()), int(r.min()), int(c.max()), int(r.max())],
            }
        )
    return entries


def write_visibility(path: Path, frames: list[list[dict[str, Any]]]) -> None:
    document = {
        "camera": "left",
        "frames": [{"index": i, "landmarks": seen} for i, seen in enumerate(frames)],
    }
    path.write_text(json.dumps(document, separators=(",", ":")) + "\n")
