"""The EuRoC / ASL layout (EuRoC MAV, TUM-VI and others):

    SEQUENCE/mav0/           (or SEQUENCE itself holding cam0/ and cam1/)
      cam0/data.csv          `#timestamp [ns],filename`, a line an image
      cam0/data/*.png        the left camera's images
      cam0/sensor.yaml       intrinsics [fu, fv, cu, cv], distortion_model and
                             distortion_coefficients, resolution [w, h], T_BS (the camera's pose
                             in the sensor body: 4x4, row-major `data`)
      cam1/...               the right camera, the same way

cam0 is the left camera and cam1 the right one. Images are paired by their timestamps in
`data.csv` (each the other's nearest, within `[input] stereo_stamp_tolerance`); an image
without a partner is left out and reported. The pair's relative pose comes from the two `T_BS`
(nothing else of them is used: the log's body frame is the rectified left camera's, turned to
x forward, as for every sequence). Distortion models: radial-tangential (k1 k2 p1 p2) and
equidistant (k1..k4); pinhole cameras only. Unless the pair is rectified already (no
distortion, one pinhole, no rotation between the cameras, the right one along the left one's
x), every image is rectified with OpenCV's stereoRectify (alpha 0: only pixels that see the
scene, the images keeping their size). Ground truth (`state_groundtruth_estimate0/`, of the
IMU, at other times) is not read.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.datasets.pairing import pair_stamps
from pipeline.datasets.rectification import CameraModel, stereo_rectification
from pipeline.datasets.stereo import StereoSequence, read_image
from pipeline.errors import InputError

log = logging.getLogger(__name__)

CAMERAS = ("cam0", "cam1")
DISTORTION_MODELS = {
    "radial-tangential": "radtan",
    "radtan": "radtan",
    "equidistant": "equidistant",
}


def euroc_root(path: Path) -> Path | None:
    """The folder holding cam0/ and cam1/ (`mav0/`), if `path` is in the EuRoC layout."""
    for candidate in (path / "mav0", path):
        if (candidate / "cam0" / "data.csv").exists():
            return candidate
    return None


def read_data_csv(path: Path) -> tuple[list[int], list[str]]:
    """Timestamps (ns) and file names of a `data.csv`, in file order, strictly increasing."""
    stamps: list[int] = []
    names: list[str] = []
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"sequence {path}: cannot read ({exc})") from None
    for number, line in enumerate(lines, 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        fields = [f.strip() for f in line.split(",")]
        if len(fields) != 2 or not fields[0].isdigit() or not fields[1]:
            raise InputError(
                f"sequence {path}: line {number} is not `timestamp_ns,filename`: {line[:80]!r}"
            )
        stamp = int(fields[0])
        if stamps and stamp <= stamps[-1]:
            raise InputError(f"sequence {path}: line {number}: timestamps must increase")
        stamps.append(stamp)
        names.append(fields[1])
    if not stamps:
        raise InputError(f"sequence {path}: no images listed")
    return stamps, names


def _numbers(document: dict[str, Any], key: str, count: int, path: Path) -> np.ndarray:
    value = document.get(key)
    if isinstance(value, dict):  # an OpenCV-style matrix: {rows, cols, data}
        value = value.get("data")
    try:
        array = np.array(value, dtype=float).ravel()
    except (TypeError, ValueError):
        array = np.zeros(0)
    if array.size != count or not np.all(np.isfinite(array)):
        raise InputError(f"calibration {path}: '{key}' must hold {count} finite numbers")
    return array


def read_sensor_yaml(path: Path) -> tuple[CameraModel, np.ndarray]:
    """A camera's `sensor.yaml`: its model, and `T_BS` (4x4)."""
    import yaml

    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"calibration {path}: cannot read ({exc})") from None
    if text.startswith("%YAML:"):  # OpenCV's header, which YAML 1.1 parsers refuse
        text = text.split("\n", 1)[1] if "\n" in text else ""
    try:
        document = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        where = getattr(exc, "problem_mark", None)
        line = f" at line {where.line + 1}" if where is not None else ""
        raise InputError(f"calibration {path}: not valid YAML{line}") from None
    if not isinstance(document, dict):
        raise InputError(f"calibration {path}: expected a mapping of sensor settings")
    camera_model = document.get("camera_model", "pinhole")
    if camera_model != "pinhole":
        raise InputError(f"calibration {path}: camera_model {camera_model!r}: only pinhole")
    distortion_name = document.get("distortion_model", "radial-tangential")
    if distortion_name not in DISTORTION_MODELS:
        raise InputError(
            f"calibration {path}: distortion_model {distortion_name!r}: one of "
            f"{', '.join(DISTORTION_MODELS)}"
        )
    fu, fv, cu, cv = _numbers(document, "intrinsics", 4, path)
    width, height = _numbers(document, "resolution", 2, path)
    distortion = _numbers(document, "distortion_coefficients", 4, path)
    body_from_sensor = _numbers(document, "T_BS", 16, path).reshape(4, 4)
    rotation = body_from_sensor[:3, :3]
    if (
        min(fu, fv, width, height) <= 0
        or width != int(width)
        or height != int(height)
        or np.max(np.abs(rotation @ rotation.T - np.eye(3))) > 1e-4
        or np.max(np.abs(body_from_sensor[3] - [0, 0, 0, 1])) > 0
    ):
        raise InputError(
            f"calibration {path}: needs positive focal lengths, a whole resolution and a rigid T_BS"
        )
    K = np.array([[fu, 0.0, cu], [0.0, fv, cv], [0.0, 0.0, 1.0]])
    model = CameraModel(int(width), int(height), K, distortion, DISTORTION_MODELS[distortion_name])
    return model, body_from_sensor


class EurocSequence(StereoSequence):
    """A stereo sequence in the EuRoC / ASL layout (see the module's description).
    `unmatched_left` and `unmatched_right` count the images left without a partner."""

    def __init__(self, root: str | Path, stereo_tolerance_s: float):
        self.root = Path(root)
        mav0 = euroc_root(self.root)
        if mav0 is None:
            raise InputError(f"sequence {self.root}: no mav0/cam0/data.csv")
        stamps, files, models, poses = [], [], [], []
        for camera in CAMERAS:
            folder = mav0 / camera
            for name in ("data.csv", "sensor.yaml"):
                if not (folder / name).exists():
                    raise InputError(f"sequence {self.root}: missing {camera}/{name}")
            camera_stamps, names = read_data_csv(folder / "data.csv")
            model, body_from_camera = read_sensor_yaml(folder / "sensor.yaml")
            stamps.append(camera_stamps)
            files.append([folder / "data" / name for name in names])
            models.append(model)
            poses.append(body_from_camera)
        if (models[0].width, models[0].height) != (models[1].width, models[1].height):
            raise InputError(f"sequence {self.root}: cam0 and cam1 have different resolutions")
        pairing = pair_stamps(stamps[0], stamps[1], round(stereo_tolerance_s * 1e9))
        self.unmatched_left = len(pairing.unmatched_left)
        self.unmatched_right = len(pairing.unmatched_right)
        if pairing.unmatched_left or pairing.unmatched_right:
            log.warning(
                "sequence %s: %d cam0 and %d cam1 images have no partner within %g s (left "
                "out; the first at %d ns)",
                self.root,
                self.unmatched_left,
                self.unmatched_right,
                stereo_tolerance_s,
                min(
                    [stamps[0][i] for i in pairing.unmatched_left]
                    + [stamps[1][j] for j in pairing.unmatched_right]
                ),
            )
        if not pairing.pairs:
            raise InputError(
                f"sequence {self.root}: no cam0 image has a cam1 image within "
                f"{stereo_tolerance_s:g} s"
            )
        self.left_files = [files[0][i] for i, _ in pairing.pairs]
        self.right_files = [files[1][j] for _, j in pairing.pairs]
        for path in (*self.left_files, *self.right_files):
            if not path.exists():
                raise InputError(f"sequence {self.root}: missing image {path.relative_to(mav0)}")
        self.exact_stamps_ns = [stamps[0][i] for i, _ in pairing.pairs]
        self.times = np.array(self.exact_stamps_ns, dtype=np.int64) / 1e9
        right_from_left = np.linalg.inv(poses[1]) @ poses[0]
        self.rectification = stereo_rectification(models[0], models[1], right_from_left)
        self.intrinsics = self.rectification.intrinsics(str(mav0 / "cam0" / "sensor.yaml"))
        first = read_image(self.left_files[0])
        self.colour = first.ndim == 3
        self.gt_poses = None
        log.info(
            "sequence %s: %d stereo pairs, %s",
            self.root,
            len(self),
            "rectified here" if self.rectification.needed else "rectified already",
        )

    def images(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        return self.rectification.apply(*super().images(index))
