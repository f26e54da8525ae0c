"""The KITTI odometry layout: `image_0/`, `image_1/`, `calib.txt`, `times.txt`, poses.

KITTI poses are those of the left camera (x right, y down, z forward) in the frame of the first
left camera. mmslam's body frame follows REP-103 (x forward, y left, z up); `BODY_FROM_CAMERA`
turns one into the other, and `camera_poses_to_body` gives body poses in the frame of the first
body pose, which is what a log's ground truth holds.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline.datasets.camera import BODY_FROM_CAMERA, StereoIntrinsics, check_intrinsics
from pipeline.datasets.stereo import StereoSequence, pair_files, read_image
from pipeline.errors import InputError

# KITTI's two stereo pairs: image folders and their projection matrices in calib.txt.
GREY_PAIR = ("image_0", "image_1", "P0", "P1")
COLOUR_PAIR = ("image_2", "image_3", "P2", "P3")


def _read_numbers(path: Path, what: str, ndmin: int) -> np.ndarray:
    """The numbers of a text file, a line a row; one that cannot be read is refused naming
    `what` it should hold."""
    try:
        return np.loadtxt(path, ndmin=ndmin)
    except (OSError, ValueError) as exc:
        raise InputError(f"{what} {path}: cannot read ({exc})") from None


def read_poses(path: str | Path, images: int | None = None) -> np.ndarray:
    """KITTI poses file: N lines of 12 numbers (3x4 row-major) to an (N, 4, 4) array; one pose
    an image where the sequence's `images` are given."""
    path = Path(path)
    rows = _read_numbers(path, "poses", 2)
    if rows.shape[1] != 12:
        raise InputError(f"poses {path}: expected 12 numbers a line, got {rows.shape[1]}")
    if not np.all(np.isfinite(rows)):
        raise InputError(f"poses {path}: holds non-finite numbers")
    if images is not None and len(rows) != images:
        raise InputError(f"poses {path}: {len(rows)} poses for {images} images")
    poses = np.tile(np.eye(4), (rows.shape[0], 1, 1))
    poses[:, :3, :] = rows.reshape(-1, 3, 4)
    return poses


def write_poses(path: str | Path, poses: np.ndarray) -> None:
    rows = np.asarray(poses)[:, :3, :].reshape(-1, 12)
    np.savetxt(path, rows, fmt="%.9e")


def read_times(path: str | Path, images: int | None = None) -> np.ndarray:
    """A times file: one increasing time (s) a line; one an image where the sequence's
    `images` are given."""
    path = Path(path)
    times = _read_numbers(path, "times", 1)
    if times.ndim != 1 or not np.all(np.isfinite(times)) or np.any(np.diff(times) <= 0):
        raise InputError(f"times {path}: expected one increasing time a line")
    if images is not None and len(times) != images:
        raise InputError(
            f"sequence {path.parent}: {path.name} has {len(times)} lines for {images} images"
        )
    return times


def write_times(path: str | Path, times: np.ndarray) -> None:
    # KITTI's own files use %e; ten significant digits keep microseconds past 100 s.
    np.savetxt(path, np.asarray(times), fmt="%.9e")


def read_calibration_rows(path: str | Path) -> dict[str, np.ndarray]:
    """The named rows of a KITTI calibration file (`P0: 12 numbers`, `R0_rect: 9 numbers`,
    ...) as flat arrays."""
    path = Path(path)
    rows = {}
    try:
        for line in path.read_text().splitlines():
            if ":" in line:
                name, values = line.split(":", 1)
                rows[name.strip()] = np.array([float(v) for v in values.split()])
    except (OSError, ValueError) as exc:
        raise InputError(f"calibration {path}: cannot read ({exc})") from None
    return rows


def read_calibration(
    path: str | Path, width: int, height: int, cameras: tuple[str, str] = ("P0", "P1")
) -> StereoIntrinsics:
    """`calib.txt` (lines `P0: 12 numbers` ...): the left intrinsics and the stereo baseline of
    the `cameras` pair (KITTI: P0, P1 grey; P2, P3 colour), checked against the image size."""
    path = Path(path)
    projections = {
        name: row.reshape(3, 4)
        for name, row in read_calibration_rows(path).items()
        if row.size == 12
    }
    left_name, right_name = cameras
    if left_name not in projections or right_name not in projections:
        raise InputError(
            f"calibration {path}: needs the {left_name} and {right_name} projection matrices"
        )
    left, right = projections[left_name], projections[right_name]
    for name, matrix in ((left_name, left), (right_name, right)):
        if not np.all(np.isfinite(matrix)):
            raise InputError(f"calibration {path}: {name} holds a number that is not finite")
    fx = left[0, 0]
    baseline = -(right[0, 3] - left[0, 3]) / fx if fx > 0 else float("nan")
    if fx <= 0 or not baseline > 0:
        raise InputError(
            f"calibration {path}: {left_name}/{right_name} give no positive focal length and "
            "baseline"
        )
    intrinsics = StereoIntrinsics(
        width, height, fx, left[1, 1], left[0, 2], left[1, 2], float(baseline)
    )
    check_intrinsics(intrinsics, str(path))
    return intrinsics


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

    `root` holds a stereo pair of image folders, `calib.txt` and `times.txt`; ground truth is read
    from `poses.txt` in `root` or `../../poses/<name>.txt` when either exists. The pair is the
    grey one (`image_0/`, `image_1/`, P0 and P1), or the colour one (`image_2/`, `image_3/`,
    P2 and P3) when only it is there or `prefer_colour` (object detectors are trained on
    colour). Left and right images are paired by name.
    """

    def __init__(self, root: str | Path, prefer_colour: bool = False):
        self.root = Path(root)
        if not self.root.is_dir():
            raise InputError(f"sequence {self.root}: no such directory")
        pairs = [p for p in (GREY_PAIR, COLOUR_PAIR) if (self.root / p[0]).is_dir()]
        if not pairs:
            raise InputError(f"sequence {self.root}: missing image_0 (or image_2)")
        left, right, left_camera, right_camera = pairs[-1] if prefer_colour else pairs[0]
        for name in (right, "calib.txt", "times.txt"):
            if not (self.root / name).exists():
                raise InputError(f"sequence {self.root}: missing {name}")
        self.left_files, self.right_files = pair_files(
            self.root / left, self.root / right, self.root
        )
        self.times = read_times(self.root / "times.txt", len(self.left_files))
        first = read_image(self.left_files[0])
        self.colour = first.ndim == 3
        height, width = first.shape[:2]
        self.intrinsics = read_calibration(
            self.root / "calib.txt", width, height, (left_camera, right_camera)
        )
        self.gt_poses = self._ground_truth()

    def _ground_truth(self) -> np.ndarray | None:
        for path in (
            self.root / "poses.txt",
            self.root.parent.parent / "poses" / f"{self.root.name}.txt",
        ):
            if path.exists():
                return read_poses(path, len(self))
        return None
