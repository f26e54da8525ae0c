"""A rectified stereo camera: its intrinsics and its mount on the body, shared by every sequence
reader (`kitti.py`, `stereo.py`, `rosbag.py`, ...) and the front-end's stages."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated

import numpy as np

from pipeline.errors import InputError
from pipeline.log import StereoCalibration
from pipeline.settings import positive, within

# Columns: the camera's x (right), y (down) and z (forward) axes in the body frame.
BODY_FROM_CAMERA_ROTATION = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
BODY_FROM_CAMERA = np.eye(4)
BODY_FROM_CAMERA[:3, :3] = BODY_FROM_CAMERA_ROTATION

# A principal point further than this fraction of the image size from its centre means a
# calibration made for other images (real rectified cameras: a few per cent).
MAX_PRINCIPAL_OFFSET = 0.25


@dataclass(frozen=True)
class StereoIntrinsics:
    """Rectified stereo: one pinhole for both cameras, and the baseline between them."""

    width: Annotated[int, within(1, 2**15)]  # pixels
    height: Annotated[int, within(1, 2**15)]
    fx: Annotated[float, positive(1e5)]  # pixels
    fy: Annotated[float, positive(1e5)]
    cx: Annotated[float, within(-1e5, 1e5)]
    cy: Annotated[float, within(-1e5, 1e5)]
    baseline: Annotated[float, positive(100.0)]  # m

    @property
    def camera_matrix(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def calibration_message(self, stamp_ns: int) -> StereoCalibration:
        """The log's /calibration message: these intrinsics on the body frame's camera mount."""
        return StereoCalibration(
            stamp_ns=stamp_ns,
            width=self.width,
            height=self.height,
            fx=self.fx,
            fy=self.fy,
            cx=self.cx,
            cy=self.cy,
            baseline=self.baseline,
            body_from_camera=tuple(float(v) for v in BODY_FROM_CAMERA.ravel()),
        )


def check_intrinsics(intrinsics: StereoIntrinsics, where: str) -> None:
    """Refuse a calibration that cannot be that of these images: numbers that are not finite,
    a focal length or baseline that is not positive, a principal point outside the image or far
    from its centre (a calibration for another image size: KITTI's cx = 602 on half-size
    images, say). `where` names the file in the message."""
    k = intrinsics
    numbers = {"fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy, "baseline": k.baseline}
    for name, value in numbers.items():
        if not math.isfinite(value):
            raise InputError(f"calibration {where}: {name} is {value}")
    if min(k.fx, k.fy, k.baseline) <= 0:
        raise InputError(f"calibration {where}: fx, fy and baseline must be positive")
    size = f"{k.width}x{k.height}"
    if not (0 <= k.cx < k.width and 0 <= k.cy < k.height):
        raise InputError(
            f"calibration {where}: principal point ({k.cx:g}, {k.cy:g}) lies outside the "
            f"{size} images"
        )
    if (
        abs(k.cx - k.width / 2) > MAX_PRINCIPAL_OFFSET * k.width
        or abs(k.cy - k.height / 2) > MAX_PRINCIPAL_OFFSET * k.height
    ):
        raise InputError(
            f"calibration {where}: principal point ({k.cx:g}, {k.cy:g}) is far from the centre "
            f"of the {size} images (a calibration for another image size?)"
        )
