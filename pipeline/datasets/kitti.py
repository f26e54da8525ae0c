"""The KITTI odometry layout: `image_0/`, `image_1/`, `calib.txt`, `times.txt`, poses.

KITTI poses are those of the left camera (x right, y down, z forward) in the frame of the first
left camera. mmslam's body frame follows REP-103 (x forward, y left, z up); `BODY_FROM_CAMERA`
turns one into the other, and `camera_poses_to_body` gives body poses in the frame of the first
body pose, which is what a log's ground truth holds.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.datasets.stereo import StereoSequence, image_files, read_grey
from pipeline.errors import InputError
from pipeline.log import StereoCalibration

# Columns: the camera's x (right), y (down) and z (forward) axes in the body frame.
BODY_FROM_CAMERA_ROTATION = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
BODY_FROM_CAMERA = np.eye(4)
BODY_FROM_CAMERA[:3, :3] = BODY_FROM_CAMERA_ROTATION


@dataclass(frozen=True)
class StereoIntrinsics:
    """Rectified stereo: one pinhole for both cameras, and the baseline between them."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    baseline: float

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


def read_poses(path: str | Path) -> np.ndarray:
    """KITTI poses file: N lines of 12 numbers (3x4 row-major) to an (N, 4, 4) array."""
    path = Path(path)
    try:
        rows = np.loadtxt(path, ndmin=2)
    except (OSError, ValueError) as exc:
        raise InputError(f"poses {path}: cannot read ({exc})") from None
    if rows.shape[1] != 12:
        raise InputError(f"poses {path}: expected 12 numbers a line, got {rows.shape[1]}")
    if not np.all(np.isfinite(rows)):
        raise InputError(f"poses {path}: holds non-finite numbers")
    poses = np.tile(np.eye(4), (rows.shape[0], 1, 1))
    poses[:, :3, :] = rows.reshape(-1, 3, 4)
    return poses


def write_poses(path: str | Path, poses: np.ndarray) -> None:
    rows = np.asarray(poses)[:, :3, :].reshape(-1, 12)
    np.savetxt(path, rows, fmt="%.9e")


def read_times(path: str | Path) -> np.ndarray:
    path = Path(path)
    try:
        times = np.loadtxt(path, ndmin=1)
    except (OSError, ValueError) as exc:
        raise InputError(f"times {path}: cannot read ({exc})") from None
    if times.ndim != 1 or not np.all(np.isfinite(times)) or np.any(np.diff(times) <= 0):
        raise InputError(f"times {path}: expected one increasing time a line")
    return times


def write_times(path: str | Path, times: np.ndarray) -> None:
    # KITTI's own files use %e; ten significant digits keep microseconds past 100 s.
    np.savetxt(path, np.asarray(times), fmt="%.9e")


def read_calibration(path: str | Path, width: int, height: int) -> StereoIntrinsics:
    """`calib.txt` (lines `P0: 12 numbers` ...): the left intrinsics and the stereo baseline."""
    path = Path(path)
    projections: dict[str, np.ndarray] = {}
    try:
        for line in path.read_text().splitlines():
            if ":" not in line:
                continue
            name, values = line.split(":", 1)
            numbers = np.array([float(v) for v in values.split()])
            if numbers.size == 12:
                projections[name.strip()] = numbers.reshape(3, 4)
    except (OSError, ValueError) as exc:
        raise InputError(f"calibration {path}: cannot read ({exc})") from None
    if "P0" not in projections or "P1" not in projections:
        raise InputError(f"calibration {path}: needs the P0 and P1 projection matrices")
    p0, p1 = projections["P0"], projections["P1"]
    fx = p0[0, 0]
    baseline = -(p1[0, 3] - p0[0, 3]) / fx
    if fx <= 0 or baseline <= 0:
        raise InputError(f"calibration {path}: P0/P1 give no positive focal length and baseline")
    return StereoIntrinsics(width, height, fx, p0[1, 1], p0[0, 2], p0[1, 2], float(baseline))


def write_calibration(path: str | Path, intrinsics: StereoIntrinsics) -> None:
    k = intrinsics.camera_matrix
    p0 = np.hstack([k, np.zeros((3, 1))])
    p1 = p0.copy()
    p1[0, 3] = -intrinsics.fx * intrinsics.baseline
    lines = [
        f"{name}: " + " ".join(f"{v:.12e}" for v in p.ravel())
        for name, p in [("P0", p0), ("P1", p1), ("P2", p0), ("P3", p1)]
    ]
    Path(path).write_text("\n".join(lines) + "\n")


def camera_poses_to_body(camera_poses: np.ndarray) -> np.ndarray:
    """Left-camera poses (KITTI) to body poses in the frame of the first body pose."""
    b = BODY_FROM_CAMERA
    b_inv = np.linalg.inv(b)
    body = b @ np.asarray(camera_poses) @ b_inv
    return np.linalg.inv(body[0]) @ body


def body_poses_to_camera(body_poses: np.ndarray) -> np.ndarray:
    """The inverse of `camera_poses_to_body` (for a first pose at identity)."""
    b = BODY_FROM_CAMERA
    return np.linalg.inv(b) @ np.asarray(body_poses) @ b


class KittiSequence(StereoSequence):
    """A sequence in the KITTI odometry layout, frame by frame.

    `root` holds `image_0/` and `image_1/` (left and right), `calib.txt` and `times.txt`; ground
    truth is read from `poses.txt` in `root` or `../../poses/<name>.txt` when either exists.
    """

    def __init__(self, root: str | Path):
        self.root = Path(root)
        if not self.root.is_dir():
            raise InputError(f"sequence {self.root}: no such directory")
        for name in ("image_0", "image_1", "calib.txt", "times.txt"):
            if not (self.root / name).exists():
                raise InputError(f"sequence {self.root}: missing {name}")
        self.left_files = image_files(self.root / "image_0")
        self.right_files = image_files(self.root / "image_1")
        if len(self.left_files) != len(self.right_files) or not self.left_files:
            raise InputError(
                f"sequence {self.root}: image_0 has {len(self.left_files)} images, image_1 has "
                f"{len(self.right_files)}"
            )
        self.times = read_times(self.root / "times.txt")
        if len(self.times) != len(self.left_files):
            raise InputError(
                f"sequence {self.root}: times.txt has {len(self.times)} lines for "
                f"{len(self.left_files)} images"
            )
        height, width = read_grey(self.left_files[0]).shape[:2]
        self.intrinsics = read_calibration(self.root / "calib.txt", width, height)
        self.gt_poses = self._ground_truth()

    def _ground_truth(self) -> np.ndarray | None:
        for path in (
            self.root / "poses.txt",
            self.root.parent.parent / "poses" / f"{self.root.name}.txt",
        ):
            if path.exists():
                poses = read_poses(path)
                if len(poses) != len(self):
                    raise InputError(f"poses {path}: {len(poses)} poses for {len(self)} images")
                return poses
        return None
