"""Typed messages of the contract-v1 detection log (one dataclass per schema)."""

from __future__ import annotations

from dataclasses import dataclass, field

FORMAT_VERSION = "1"
METADATA_NAME = "mmslam"

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]  # [x, y, z, w]


@dataclass(frozen=True)
class Odometry:
    """Pose of `to_index` in the frame of `from_index`; covariance in Pose3 tangent order."""

    stamp_ns: int
    from_index: int
    to_index: int
    translation: Vec3
    rotation: Quat
    covariance: tuple[float, ...]  # 36, row-major, (rx, ry, rz, tx, ty, tz)


@dataclass(frozen=True)
class RelativePose:
    """6-DoF pose of a tag in the body frame."""

    translation: Vec3
    rotation: Quat
    covariance: tuple[float, ...]  # 36


@dataclass(frozen=True)
class Detection:
    class_id: int
    score: float
    bearing: float
    elevation: float
    range: float
    covariance: tuple[float, ...]  # 9, over (bearing, elevation, range)
    source: str  # "apriltag" or "bbox"
    bbox: tuple[float, float, float, float] | None = None
    relative_pose: RelativePose | None = None
    truth_landmark_id: int | None = None  # -1: a false positive, no real landmark


@dataclass(frozen=True)
class Detections:
    stamp_ns: int
    pose_index: int
    detections: tuple[Detection, ...] = ()


@dataclass(frozen=True)
class GroundTruthPose:
    stamp_ns: int
    pose_index: int
    translation: Vec3
    rotation: Quat


@dataclass(frozen=True)
class GroundTruthLandmark:
    id: int
    class_id: int
    position: Vec3


@dataclass(frozen=True)
class GroundTruthLandmarks:
    stamp_ns: int
    landmarks: tuple[GroundTruthLandmark, ...] = ()


@dataclass(frozen=True)
class StereoCalibration:
    stamp_ns: int
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    baseline: float
    body_from_camera: tuple[float, ...]  # 16, row-major 4x4


@dataclass(frozen=True)
class CompressedImage:
    """foxglove.CompressedImage; `data` holds the encoded bytes (base64 on the wire)."""

    stamp_ns: int
    frame_id: str
    format: str
    data: bytes = field(repr=False)


@dataclass(frozen=True)
class LogMetadata:
    num_classes: int
    confusion_matrix: tuple[tuple[float, ...], ...]  # row = true class, column = reported
    class_names: tuple[str, ...]
    source: str = ""
    format_version: str = FORMAT_VERSION


@dataclass
class DetectionLog:
    """Everything a log holds, validated, in log order within each topic."""

    metadata: LogMetadata
    odometry: list[Odometry]
    detections: list[Detections]
    ground_truth_poses: list[GroundTruthPose] = field(default_factory=list)
    ground_truth_landmarks: GroundTruthLandmarks | None = None
    calibration: StereoCalibration | None = None
    image_counts: dict[str, int] = field(default_factory=dict)
    images: dict[str, list[CompressedImage]] = field(default_factory=dict)

    @property
    def num_poses(self) -> int:
        return len(self.odometry) + 1

    @property
    def num_detections(self) -> int:
        return sum(len(m.detections) for m in self.detections)

    @property
    def has_ground_truth(self) -> bool:
        return len(self.ground_truth_poses) > 0

    def pose_stamps_ns(self) -> list[int]:
        """A time for every pose: the odometry that reaches it for poses 1..; pose 0 from its
        ground truth or detections, else from the first odometry."""
        stamps = [0] * self.num_poses
        for odometry in self.odometry:
            stamps[odometry.to_index] = odometry.stamp_ns
        first = [m.stamp_ns for m in self.ground_truth_poses if m.pose_index == 0]
        first += [m.stamp_ns for m in self.detections if m.pose_index == 0]
        if first:
            stamps[0] = first[0]
        elif self.odometry:
            stamps[0] = self.odometry[0].stamp_ns
        return stamps
