"""Stereo rectification for sequences whose images are not rectified (EuRoC, raw ROS topics).

The front-end wants one pinhole for both cameras, rows aligned, the right camera at +baseline
along the left camera's x. A `Rectification` holds, for each camera, its intrinsics and
distortion as calibrated, the rotation into the rectified frame and the rectified projection
(ROS's CameraInfo K, D, R, P, or what OpenCV's stereoRectify makes of two calibrated cameras),
and warps image pairs with OpenCV's remap. Where the pair is rectified already (no distortion,
no rotation, one pinhole) the images are passed through untouched.

Distortion models: "radtan" (OpenCV's k1, k2, p1, p2[, k3, ...]: ROS's plumb_bob and
rational_polynomial, EuRoC's radial-tangential) and "equidistant" (Kannala-Brandt k1..k4:
OpenCV's fisheye, ROS's and EuRoC's equidistant).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipeline.datasets.camera import StereoIntrinsics, check_intrinsics
from pipeline.errors import InputError

MODELS = ("radtan", "equidistant")
# A pair is taken as rectified when rectifying it would move no pixel by more than about this
# (px): rotations below it over the focal length, camera offsets off the x axis below it over
# the focal length, times the baseline.
RECTIFIED_PX = 0.01


@dataclass(frozen=True)
class CameraModel:
    """One camera as calibrated: pinhole K (3x3) and distortion coefficients of `model`."""

    width: int
    height: int
    K: np.ndarray
    distortion: np.ndarray
    model: str = "radtan"

    def __post_init__(self) -> None:
        if self.model not in MODELS:
            raise ValueError(f"distortion model {self.model!r}: not one of {MODELS}")


@dataclass(frozen=True)
class Rectification:
    """Each camera with its rectifying rotation R and rectified projection P (3x4)."""

    left: CameraModel
    right: CameraModel
    R_left: np.ndarray
    R_right: np.ndarray
    P_left: np.ndarray
    P_right: np.ndarray
    _maps: list = field(default_factory=list, repr=False, compare=False)

    @property
    def needed(self) -> bool:
        """Whether the images must be warped: some distortion, a rotation, or a rectified
        pinhole other than the cameras'."""
        for camera, R, P in (
            (self.left, self.R_left, self.P_left),
            (self.right, self.R_right, self.P_right),
        ):
            fx = P[0, 0]
            if np.any(np.abs(camera.distortion) > 0):
                return True
            if np.max(np.abs(R - np.eye(3))) * fx > RECTIFIED_PX:
                return True
            if np.max(np.abs(camera.K - P[:3, :3])) > RECTIFIED_PX:
                return True
        return False

    def intrinsics(self, where: str) -> StereoIntrinsics:
        """The rectified pair's pinhole and baseline, from the two projections: the right one
        is `P_left` with `-fx * baseline` in its top right corner. `where` names the source in
        messages."""
        left, right = self.P_left, self.P_right
        if not (np.all(np.isfinite(left)) and np.all(np.isfinite(right))):
            raise InputError(f"calibration {where}: a projection matrix is not finite")
        if np.max(np.abs(left[:3, :3] - right[:3, :3])) > 1e-6 * max(abs(left[0, 0]), 1.0):
            raise InputError(
                f"calibration {where}: the left and right projection matrices have different "
                "pinholes (fx, fy, cx, cy): not a rectified pair"
            )
        if abs(left[0, 3]) > 1e-9 * abs(left[0, 0]) or np.any(np.abs(right[1:, 3]) > 1e-9):
            raise InputError(
                f"calibration {where}: the left projection must have no offset and the right "
                "one an offset along x only"
            )
        fx = left[0, 0]
        baseline = -right[0, 3] / fx if fx > 0 else float("nan")
        if not baseline > 0:
            raise InputError(
                f"calibration {where}: the right projection matrix gives baseline {baseline:g} "
                "(the right camera must sit at +baseline along the left camera's x)"
            )
        intrinsics = StereoIntrinsics(
            self.left.width,
            self.left.height,
            float(fx),
            float(left[1, 1]),
            float(left[0, 2]),
            float(left[1, 2]),
            float(baseline),
        )
        check_intrinsics(intrinsics, where)
        return intrinsics

    def apply(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The rectified pair (the same images when none is `needed`)."""
        if not self.needed:
            return left, right
        import cv2

        if not self._maps:
            self._maps.extend(
                _maps(camera, R, P)
                for camera, R, P in (
                    (self.left, self.R_left, self.P_left),
                    (self.right, self.R_right, self.P_right),
                )
            )
        return tuple(  # type: ignore[return-value]
            cv2.remap(image, first, second, cv2.INTER_LINEAR)
            for image, (first, second) in zip((left, right), self._maps, strict=True)
        )


def _maps(camera: CameraModel, R: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    import cv2

    size = (camera.width, camera.height)
    if camera.model == "equidistant":
        return cv2.fisheye.initUndistortRectifyMap(
            camera.K, camera.distortion[:4], R, P, size, cv2.CV_16SC2
        )
    return cv2.initUndistortRectifyMap(camera.K, camera.distortion, R, P, size, cv2.CV_16SC2)


def stereo_rectification(
    left: CameraModel, right: CameraModel, right_from_left: np.ndarray
) -> Rectification:
    """Rectify two calibrated cameras: `right_from_left` (4x4) maps points of the left camera's
    frame into the right camera's. OpenCV's stereoRectify with zero disparity at infinity and
    alpha 0 (every rectified pixel sees the scene; no black borders), the images keeping
    their size. A pair rectified already keeps its own pinhole."""
    import cv2

    rotation, translation = right_from_left[:3, :3], right_from_left[:3, 3]
    # A column (OpenCV 5 refuses a row), contiguous (its fisheye module refuses a view).
    column = np.ascontiguousarray(translation, dtype=float).reshape(3, 1)
    baseline = float(np.linalg.norm(translation))
    fx = float(left.K[0, 0])
    angle = float(np.linalg.norm(cv2.Rodrigues(rotation)[0]))
    rectified = (
        not np.any(left.distortion)
        and not np.any(right.distortion)
        and np.max(np.abs(left.K - right.K)) * 1.0 <= RECTIFIED_PX
        and angle * fx <= RECTIFIED_PX
        and translation[0] < 0
        and np.hypot(translation[1], translation[2]) * fx <= RECTIFIED_PX * baseline
    )
    if rectified:
        P_left = np.hstack([left.K, np.zeros((3, 1))])
        P_right = P_left.copy()
        P_right[0, 3] = -left.K[0, 0] * baseline
        return Rectification(left, right, np.eye(3), np.eye(3), P_left, P_right)
    size = (left.width, left.height)
    if left.model != right.model:
        raise ValueError("both cameras must have the same distortion model")
    if left.model == "equidistant":
        R1, R2, P1, P2, _ = cv2.fisheye.stereoRectify(
            left.K,
            left.distortion[:4],
            right.K,
            right.distortion[:4],
            size,
            rotation,
            column,
            flags=cv2.CALIB_ZERO_DISPARITY,
            balance=0.0,
        )
    else:
        R1, R2, P1, P2, *_ = cv2.stereoRectify(
            left.K,
            left.distortion,
            right.K,
            right.distortion,
            size,
            rotation,
            column,
            flags=cv2.CALIB_ZERO_DISPARITY,
            alpha=0.0,
        )
    return Rectification(left, right, R1, R2, P1, P2)
