"""Which reader a sequence needs, chosen by what the path holds: the one place that knows every
layout (the front-end and `mmslam frontend --help` ask it)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from pipeline.datasets.euroc import EurocSequence, euroc_root
from pipeline.datasets.kitti import KittiSequence
from pipeline.datasets.plain import CALIBRATION_FILE, PlainSequence
from pipeline.datasets.rosbag import BAG_SUFFIXES, RosbagSequence, is_bag
from pipeline.datasets.stereo import StereoSequence
from pipeline.errors import InputError


@dataclass(frozen=True)
class SequenceOptions:
    """What a bag may need beside its path: the stereo topics (found when None), a
    calibration file instead of its CameraInfo, and the pairing tolerance (s)."""

    stereo_stamp_tolerance: float = 0.005
    left_topic: str | None = None
    right_topic: str | None = None
    calibration: Path | None = None


def open_sequence(
    path: str | Path, prefer_colour: bool = False, options: SequenceOptions | None = None
) -> StereoSequence:
    """The reader for `path`: a ROS bag, the KITTI layout (`image_0/` or `image_2/`), the
    EuRoC layout (`mav0/cam0/data.csv`) or the plain one (`calibration.toml`).
    `prefer_colour`: KITTI's colour pair where it has both."""
    options = options or SequenceOptions()
    root = Path(path)
    bag_only = options.left_topic or options.right_topic
    if not root.exists():
        raise InputError(f"sequence {root}: no such file or directory")
    if is_bag(root):
        return RosbagSequence(
            root,
            options.stereo_stamp_tolerance,
            options.left_topic,
            options.right_topic,
            options.calibration,
        )
    if bag_only:
        raise InputError(f"sequence {root}: --left-topic and --right-topic are for ROS bags")
    if options.calibration is not None:
        raise InputError(f"sequence {root}: --calibration is for ROS bags")
    if not root.is_dir():
        raise InputError(
            f"sequence {root}: a file, but not a bag ({', '.join(BAG_SUFFIXES)}); a sequence "
            "is a folder"
        )
    if (root / "image_0").is_dir() or (root / "image_2").is_dir():
        return KittiSequence(root, prefer_colour)
    if euroc_root(root) is not None:
        return EurocSequence(root, options.stereo_stamp_tolerance)
    if (root / CALIBRATION_FILE).exists():
        return PlainSequence(root)
    raise InputError(
        f"sequence {root}: none of the layouts: KITTI (image_0/, image_1/, calib.txt, "
        f"times.txt), EuRoC (mav0/cam0/data.csv), plain ({CALIBRATION_FILE}, left/, right/), "
        "or a ROS 2 bag (metadata.yaml)"
    )
