"""mmslam's own plain layout: two image folders and a calibration file.

    SEQUENCE/
      calibration.toml   the rectified stereo camera (below; see configs/plain-calibration.toml)
      left/  right/      rectified grey or colour images, paired by name (left/000012.png with
                         right/000012.png; the suffix may differ), in name order
      times.txt          optional: one time (s) a line; else frames are 1/frame_rate apart
      poses.txt          optional: left-camera poses, KITTI's format (12 numbers a line)

calibration.toml:

    [camera]
    fx = 707.0912        # focal lengths and principal point (px), shared by both cameras
    fy = 707.0912
    cx = 601.8873
    cy = 183.1104
    baseline = 0.5372    # m: the right camera sits at +baseline along the left camera's x
    # width = 1226       # optional: checked against the images
    # height = 370

    [sequence]           # optional table
    left = "left"        # the image folders
    right = "right"
    frame_rate = 10.0    # Hz, used when there is no times.txt

The reader has the same face as `KittiSequence`: `len`, `[i]` -> (left, right) grey images,
`images(i)` -> as stored, `times`, `intrinsics`, `gt_poses` (left-camera poses, or None),
`colour`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from pipeline.datasets.camera import StereoIntrinsics, check_intrinsics
from pipeline.datasets.kitti import (
    read_poses,
    read_times,
)
from pipeline.datasets.stereo import StereoSequence, pair_files, read_image
from pipeline.errors import InputError
from pipeline.settings import read_toml

CALIBRATION_FILE = "calibration.toml"
CAMERA_KEYS = ("fx", "fy", "cx", "cy", "baseline")


def _number(table: dict[str, Any], key: str, path: Path, where: str) -> float:
    value = table.get(key)
    if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value):
        raise InputError(f"calibration {path}: '{where}{key}' must be a number, got {value!r}")
    return float(value)


def read_plain_calibration(path: str | Path) -> tuple[dict[str, float], dict[str, Any]]:
    """The `[camera]` numbers and the `[sequence]` settings of a calibration.toml."""
    path = Path(path)
    document = read_toml(path, "calibration")
    camera = document.get("camera")
    if not isinstance(camera, dict):
        raise InputError(f"calibration {path}: needs a [camera] table")
    unknown = set(camera) - set(CAMERA_KEYS) - {"width", "height"}
    if unknown:
        raise InputError(f"calibration {path}: unknown key 'camera.{sorted(unknown)[0]}'")
    numbers = {key: _number(camera, key, path, "camera.") for key in CAMERA_KEYS}
    for key in ("width", "height"):
        if key in camera:
            numbers[key] = _number(camera, key, path, "camera.")
    if min(numbers["fx"], numbers["fy"], numbers["baseline"]) <= 0:
        raise InputError(f"calibration {path}: fx, fy and baseline must be positive")
    sequence = {"left": "left", "right": "right", "frame_rate": 10.0}
    given = document.get("sequence", {})
    if not isinstance(given, dict):
        raise InputError(f"calibration {path}: [sequence] must be a table")
    for key, value in given.items():
        if key not in sequence:
            raise InputError(f"calibration {path}: unknown key 'sequence.{key}'")
        sequence[key] = value
    if not isinstance(sequence["left"], str) or not isinstance(sequence["right"], str):
        raise InputError(f"calibration {path}: sequence.left and sequence.right must be names")
    if _number(sequence, "frame_rate", path, "sequence.") <= 0:
        raise InputError(f"calibration {path}: sequence.frame_rate must be positive")
    return numbers, sequence


def intrinsics_for_images(
    path: Path, camera: dict[str, Any], width: int, height: int
) -> StereoIntrinsics:
    """The `[camera]` table of the plain calibration file `path`, for images of this size:
    its width and height, where it gives them, must be the images'."""
    for key, actual in (("width", width), ("height", height)):
        if key in camera and int(camera[key]) != actual:
            raise InputError(
                f"calibration {path}: camera.{key} is {int(camera[key])} but the images are "
                f"{actual}"
            )
    keys = ("fx", "fy", "cx", "cy", "baseline")
    intrinsics = StereoIntrinsics(width, height, *(camera[key] for key in keys))
    check_intrinsics(intrinsics, str(path))
    return intrinsics


class PlainSequence(StereoSequence):
    """A stereo sequence in the plain layout (see the module's description)."""

    def __init__(self, root: str | Path):
        self.root = Path(root)
        if not self.root.is_dir():
            raise InputError(f"sequence {self.root}: no such directory")
        calibration = self.root / CALIBRATION_FILE
        if not calibration.exists():
            raise InputError(f"sequence {self.root}: missing {CALIBRATION_FILE}")
        camera, sequence = read_plain_calibration(calibration)
        folders = [self.root / sequence["left"], self.root / sequence["right"]]
        for folder in folders:
            if not folder.is_dir():
                raise InputError(f"sequence {self.root}: missing image folder {folder.name}/")
        self.left_files, self.right_files = pair_files(folders[0], folders[1], self.root)
        times_path = self.root / "times.txt"
        if times_path.exists():
            self.times = read_times(times_path, len(self))
        else:
            self.times = np.arange(len(self)) / float(sequence["frame_rate"])
        first = read_image(self.left_files[0])
        self.colour = first.ndim == 3
        height, width = first.shape[:2]
        self.intrinsics = intrinsics_for_images(calibration, camera, width, height)
        poses_path = self.root / "poses.txt"
        self.gt_poses = read_poses(poses_path, len(self)) if poses_path.exists() else None
