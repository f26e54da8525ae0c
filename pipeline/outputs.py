"""The files `replay --out DIR` writes (../shared/CONTRACT.md), written all-or-nothing.

Every file goes to a temporary name in DIR first; only when all are complete are they renamed
into place, so a failed run leaves an earlier run's outputs as they were. Numbers are written
with fixed formats so that the same run gives the same bytes.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from pipeline.geometry import quaternion_from_rotation
from pipeline.log.mcap_io import atomic_output

TRAJECTORY = "trajectory.tum"
LANDMARKS = "landmarks.csv"
ASSOCIATIONS = "associations.csv"
METRICS = "metrics.json"


def trajectory_tum(stamps_s: Iterable[float], poses: Iterable[np.ndarray]) -> str:
    """evo's TUM format: `stamp tx ty tz qx qy qz qw`, a line a pose."""
    lines = []
    for stamp, T in zip(stamps_s, poses, strict=True):
        q = quaternion_from_rotation(T[:3, :3])
        values = [stamp, *T[:3, 3], *q]
        lines.append(" ".join(f"{v:.9f}" for v in values))
    return "\n".join(lines) + "\n"


def landmarks_csv(rows: Iterable[tuple[int, np.ndarray, int, float, int]]) -> str:
    lines = ["id,x,y,z,class_id,class_probability,observations"]
    for landmark_id, position, class_id, probability, observations in rows:
        x, y, z = position
        lines.append(
            f"{landmark_id},{x:.6f},{y:.6f},{z:.6f},{class_id},{probability:.6f},{observations}"
        )
    return "\n".join(lines) + "\n"


def associations_csv(rows: Iterable[tuple[int, int, int, float]]) -> str:
    lines = ["pose_index,detection_index,landmark_id,weight"]
    lines += [f"{p},{d},{lm},{w:.6f}" for p, d, lm, w in rows]
    return "\n".join(lines) + "\n"


def metrics_json(metrics: dict) -> str:
    return json.dumps(metrics, indent=2, sort_keys=True) + "\n"


def write_outputs(out_dir: Path, files: dict[str, str], stale: Iterable[str] = ()) -> None:
    """Write every file or none; remove `stale` files of an earlier run once all are in place."""
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise NotADirectoryError(f"{out_dir} exists and is not a directory")
    temporary: dict[str, Path] = {}
    try:
        for name, text in files.items():
            fd, tmp = atomic_output(out_dir / name)
            temporary[name] = tmp
            with os.fdopen(fd, "w", encoding="utf-8", newline="\n") as f:
                f.write(text)
    except BaseException:
        for tmp in temporary.values():
            tmp.unlink(missing_ok=True)
        raise
    for name, tmp in temporary.items():
        os.replace(tmp, out_dir / name)
    for name in stale:
        if name not in files:
            (out_dir / name).unlink(missing_ok=True)
