"""The messages of the contract-v1 detection log, each declared once: its fields, their types,
units and bounds.

A field's annotation says everything a reader checks of it: msgspec's `Meta` gives a number's
range and unit (checked as msgspec decodes the JSON straight into the dataclass), and the
markers below what spans a field's items (a vector's length, a unit quaternion, a covariance
the back-end can use, a box's corners in order, a rigid transform, a class among the log's).
From these declarations come the JSON Schemas of the MCAP channels (`schemas.py`), the
decoders and encoders (`codec.py`) and the field table of docs/log-format.md
(`python -m pipeline.log.doc`). Adding a field or a bound is one edit here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Annotated, Literal

from msgspec import Meta

from pipeline.log import limits

FORMAT_VERSION = "1"
METADATA_NAME = "mmslam"


# --- what spans a field's items: checked after decoding, by codec.py --------------------------


@dataclass(frozen=True)
class Norm:
    """A vector whose Euclidean length lies in [low, high]."""

    high: float
    low: float = 0.0


@dataclass(frozen=True)
class UnitQuaternion:
    """[x, y, z, w] of norm 1, within `limits.QUATERNION_NORM_TOLERANCE`."""


@dataclass(frozen=True)
class Covariance:
    """`dim` x `dim`, row-major: symmetric, positive definite, variances and condition number
    within `limits`."""

    dim: int


@dataclass(frozen=True)
class Corners:
    """`[u_min, v_min, u_max, v_max]`: the minima no larger than the maxima."""


@dataclass(frozen=True)
class RigidTransform:
    """A 4x4 row-major matrix: a rotation and a translation, last row [0, 0, 0, 1]."""


@dataclass(frozen=True)
class OfTheLogsClasses:
    """A class id below the log's `num_classes` (its metadata)."""


# --- kinds of value ---------------------------------------------------------------------------

Stamp = Annotated[int, Meta(ge=0, le=limits.MAX_STAMP_NS, description="ns")]
PoseIndex = Annotated[int, Meta(ge=0, le=limits.MAX_POSES - 1)]
ClassId = Annotated[int, Meta(ge=0, le=limits.MAX_CLASSES - 1), OfTheLogsClasses()]
LandmarkId = Annotated[int, Meta(ge=0, le=limits.MAX_LANDMARK_ID)]
Number = float  # finite: JSON holds no other
Vec3 = tuple[Number, Number, Number]
Metres = Meta(description="m")
Quat = Annotated[tuple[Number, Number, Number, Number], UnitQuaternion()]  # [x, y, z, w]
Coordinate = Annotated[float, Meta(ge=-limits.MAX_COORDINATE_M, le=limits.MAX_COORDINATE_M)]
Position = Annotated[tuple[Coordinate, Coordinate, Coordinate], Metres]
Pixel = Annotated[float, Meta(ge=-limits.MAX_PIXEL, le=limits.MAX_PIXEL, description="px")]
Focal = Annotated[float, Meta(gt=0.0, le=limits.MAX_PIXEL, description="px")]
ImageSide = Annotated[int, Meta(ge=1, le=limits.MAX_IMAGE_SIDE_PX, description="px")]
Covariance3 = Annotated[
    tuple[Number, ...],
    Meta(min_length=9, max_length=9, description="row-major 3x3"),
    Covariance(3),
]
Covariance6 = Annotated[
    tuple[Number, ...],
    Meta(min_length=36, max_length=36, description="row-major 6x6, (rx, ry, rz, tx, ty, tz)"),
    Covariance(6),
]


@dataclass(frozen=True)
class Odometry:
    """Pose of `to_index` in the frame of `from_index`; covariance in Pose3 tangent order."""

    stamp_ns: Stamp
    from_index: PoseIndex
    to_index: PoseIndex
    translation: Annotated[Vec3, Metres, Norm(limits.MAX_ODOMETRY_STEP_M)]
    rotation: Quat
    covariance: Covariance6


@dataclass(frozen=True)
class RelativePose:
    """6-DoF pose of a tag in the body frame."""

    translation: Annotated[Vec3, Metres, Norm(limits.MAX_RANGE_M)]
    rotation: Quat
    covariance: Covariance6


@dataclass(frozen=True)
class Detection:
    class_id: ClassId  # as the detector reported it
    score: Annotated[float, Meta(ge=0.0, le=1.0)]
    # The contract's definitions: bearing = atan2(y, x), elevation = atan2(z, hypot(x, y)).
    bearing: Annotated[float, Meta(ge=-math.pi, le=math.pi, description="rad")]
    elevation: Annotated[float, Meta(ge=-math.pi / 2, le=math.pi / 2, description="rad")]
    range: Annotated[float, Meta(ge=limits.MIN_RANGE_M, le=limits.MAX_RANGE_M, description="m")]
    covariance: Covariance3  # over (bearing, elevation, range)
    source: Literal["apriltag", "bbox"]
    bbox: Annotated[tuple[Pixel, Pixel, Pixel, Pixel], Corners()] | None = None
    relative_pose: RelativePose | None = None
    # the landmark really seen; -1: a false positive, no real landmark
    truth_landmark_id: Annotated[int, Meta(ge=-1, le=limits.MAX_LANDMARK_ID)] | None = None


@dataclass(frozen=True)
class Detections:
    stamp_ns: Stamp
    pose_index: PoseIndex
    detections: tuple[Detection, ...]  # may be empty


@dataclass(frozen=True)
class GroundTruthPose:
    stamp_ns: Stamp
    pose_index: PoseIndex
    translation: Position
    rotation: Quat


@dataclass(frozen=True)
class GroundTruthLandmark:
    id: LandmarkId
    class_id: ClassId
    position: Position


@dataclass(frozen=True)
class GroundTruthLandmarks:
    stamp_ns: Stamp
    landmarks: tuple[GroundTruthLandmark, ...]


@dataclass(frozen=True)
class StereoCalibration:
    stamp_ns: Stamp
    width: ImageSide
    height: ImageSide
    fx: Focal
    fy: Focal
    cx: Pixel
    cy: Pixel
    baseline: Annotated[float, Meta(gt=0.0, le=limits.MAX_BASELINE_M, description="m")]
    body_from_camera: Annotated[
        tuple[Coordinate, ...],
        Meta(min_length=16, max_length=16, description="row-major 4x4"),
        RigidTransform(),
    ]


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
