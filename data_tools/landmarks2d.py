"""2-D landmark datasets (GTSAM's text format: `gtsam/Data/victoria_park.txt`, `example.graph`)
lifted to contract logs, their associations kept as truth labels.

    mmslam convert .venv/lib/python3.*/site-packages/gtsam/Data/victoria_park.txt --out vp.mcap

Lines read (others refused, naming the line):
- `ODOMETRY i j dx dy dtheta v1..v6` (or `EDGE2`): pose j in the frame of pose i, and its
  covariance over (x, y, theta): upper triangle `xx xy xtheta yy ytheta thetatheta`; or, told by
  its zeros as GTSAM's `load2D` tells it, TORO's information `ff fs ss rr fr sr`. The steps must
  chain (each starts where the one before ended): they become poses 0, 1, 2, ...
- `LANDMARK i l x y cxx cxy cyy`: landmark l seen from pose i at (x, y) in its frame, with that
  point's covariance; carried to (bearing, range) through the Jacobian at the point.
- `BR i l bearing range sigma_bearing sigma_range`: the same, as bearing and range.
- `VERTEX2`, `VERTEX_SE2`, `VERTEX_XY`: initial guesses, skipped.

The log is planar: odometry with zero height, roll and pitch (stated with `flat_sigma`), every
detection at elevation 0 (`elevation_sigma_rad`); `mmslam replay` states the plane itself
(`[prior] planar`). Each detection's `truth_landmark_id` is the file's landmark id: `--method
known` replays the given associations, and every method's metrics.json scores associations
against them. GTSAM's own loader reads a LANDMARK's covariance as if taken at 10 m (its bearing
sigma sqrt(cxx / 10)); here it is the covariance at the sighting's own range.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import numpy as np

from pipeline import settings
from pipeline.errors import InputError
from pipeline.log import Detection, Detections, LogMetadata, LogWriter, Odometry
from pipeline.settings import positive

STEP_TAGS = ("ODOMETRY", "EDGE2")
SKIPPED_TAGS = ("VERTEX2", "VERTEX_SE2", "VERTEX_XY")


@dataclass(frozen=True)
class Landmarks2dConfig:
    keyframe_period_s: Annotated[float, positive(3600.0)]
    flat_sigma: Annotated[float, positive(1.0)]  # m and rad
    elevation_sigma_rad: Annotated[float, positive(3.2)]


@dataclass(frozen=True)
class _ConfigFile:
    landmarks2d: Landmarks2dConfig


def load_landmarks2d_config(path: str | Path | None = None) -> Landmarks2dConfig:
    """The defaults (configs/landmarks2d.toml), with the keys of `path` (if given) over them."""
    return settings.load(_ConfigFile, settings.config_path("landmarks2d.toml"), path).landmarks2d


@dataclass(frozen=True)
class Step:
    """An odometry step: pose `to_id` in the frame of pose `from_id`."""

    from_id: int
    to_id: int
    motion: tuple[float, float, float]  # x, y, theta
    covariance: np.ndarray  # 3x3 over (x, y, theta)


@dataclass(frozen=True)
class Sighting:
    pose_id: int
    landmark_id: int
    bearing: float
    range: float
    covariance: np.ndarray  # 2x2 over (bearing, range)


@dataclass(frozen=True)
class Dataset2d:
    steps: list[Step]
    sightings: list[Sighting]

    def pose_ids(self) -> list[int]:
        """The file's pose ids in chain order: pose 0 is where the first step starts."""
        return [self.steps[0].from_id] + [s.to_id for s in self.steps]


def step_covariance(values: np.ndarray) -> np.ndarray:
    """A step's 3x3 covariance over (x, y, theta) from its six numbers, read as GTSAM's load2D
    reads them: a covariance's upper triangle (xx xy xt yy yt tt), unless the zeros say TORO's
    information (ff fs ss rr fr sr); with neither pattern, as a covariance."""
    v = np.asarray(values, dtype=float)
    toro = v[0] != 0 and v[1] == 0 and v[2] != 0 and v[3] != 0 and v[4] == 0 and v[5] == 0
    if toro:
        information = np.array([[v[0], v[1], v[4]], [v[1], v[2], v[5]], [v[4], v[5], v[3]]])
        return np.linalg.inv(information)
    return np.array([[v[0], v[1], v[2]], [v[1], v[3], v[4]], [v[2], v[4], v[5]]])


def bearing_range_covariance(x: float, y: float, covariance: np.ndarray) -> np.ndarray:
    """A point's (x, y) covariance carried to (bearing, range) to first order."""
    r2 = x * x + y * y
    r = math.sqrt(r2)
    J = np.array([[-y / r2, x / r2], [x / r, y / r]])
    C = J @ np.asarray(covariance, dtype=float) @ J.T
    return 0.5 * (C + C.T)


def _numbers(fields: list[str], count: int, where: str) -> list[float]:
    if len(fields) != count:
        raise InputError(f"{where}: {count} numbers expected after the tag, found {len(fields)}")
    try:
        values = [float(f) for f in fields]
    except ValueError:
        raise InputError(f"{where}: not a number among {' '.join(fields)}") from None
    if not all(math.isfinite(v) for v in values):
        raise InputError(f"{where}: a number is not finite")
    return values


def _id(value: float, where: str) -> int:
    if value != int(value) or value < 0:
        raise InputError(f"{where}: ids are integers >= 0, got {value:g}")
    return int(value)


def _positive_definite(covariance: np.ndarray, where: str) -> np.ndarray:
    if not np.all(np.isfinite(covariance)) or np.any(np.linalg.eigvalsh(covariance) <= 0):
        raise InputError(f"{where}: the covariance is not positive definite")
    return covariance


def parse_landmarks2d(path: Path) -> Dataset2d:
    """The steps and sightings of a 2-D landmark file; a line it cannot take is an `InputError`
    naming the file and the line."""
    steps: list[Step] = []
    sightings: list[Sighting] = []
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read {path}: {exc}") from None
    for number, line in enumerate(text.splitlines(), start=1):
        fields = line.split()
        if not fields or fields[0].startswith("#"):
            continue
        tag, where = fields[0], f"{path} line {number}"
        if tag in SKIPPED_TAGS:
            continue
        if tag in STEP_TAGS:
            v = _numbers(fields[1:], 11, where)
            covariance = _positive_definite(step_covariance(np.array(v[5:])), where)
            step = Step(_id(v[0], where), _id(v[1], where), (v[2], v[3], v[4]), covariance)
            if steps and step.from_id != steps[-1].to_id:
                raise InputError(
                    f"{where}: the step {step.from_id} -> {step.to_id} does not continue the "
                    f"pose chain (the last step ended at {steps[-1].to_id}); only odometry "
                    "chains are taken"
                )
            steps.append(step)
        elif tag == "LANDMARK":
            v = _numbers(fields[1:], 7, where)
            x, y = v[2], v[3]
            if x == 0.0 and y == 0.0:
                raise InputError(f"{where}: a landmark seen at range 0")
            point = np.array([[v[4], v[5]], [v[5], v[6]]])
            covariance = _positive_definite(bearing_range_covariance(x, y, point), where)
            bearing, range_m = math.atan2(y, x), math.hypot(x, y)
            sightings.append(
                Sighting(_id(v[0], where), _id(v[1], where), bearing, range_m, covariance)
            )
        elif tag == "BR":
            v = _numbers(fields[1:], 6, where)
            if v[3] <= 0 or v[4] <= 0 or v[5] <= 0:
                raise InputError(f"{where}: range and sigmas must be positive")
            covariance = np.diag([v[4] ** 2, v[5] ** 2])
            bearing = math.remainder(v[2], math.tau)  # the contract's bearings lie in [-pi, pi]
            pose, landmark = _id(v[0], where), _id(v[1], where)
            sightings.append(Sighting(pose, landmark, bearing, v[3], covariance))
        else:
            raise InputError(
                f"{where}: unknown tag {tag!r}; a 2-D landmark file holds "
                f"{', '.join(STEP_TAGS)}, LANDMARK and BR lines"
            )
    if not steps:
        raise InputError(f"{path}: no ODOMETRY or EDGE2 line: not a 2-D landmark dataset")
    poses = set(Dataset2d(steps, []).pose_ids())
    for s in sightings:
        if s.pose_id not in poses:
            raise InputError(f"{path}: landmark {s.landmark_id} seen from {s.pose_id}, no pose")
    return Dataset2d(steps, sightings)


def _floats(values) -> tuple[float, ...]:
    return tuple(float(v) for v in np.ravel(values))


def odometry_covariance(step: Step, flat_sigma: float) -> np.ndarray:
    """The step's 6x6 covariance in Pose3's tangent order (rx, ry, rz, tx, ty, tz): its
    (x, y, theta) block at (tx, ty, rz), height, roll and pitch at `flat_sigma`."""
    covariance = np.diag(np.full(6, flat_sigma**2))
    where = [3, 4, 2]  # x, y, theta
    covariance[np.ix_(where, where)] = step.covariance
    return covariance


def detection(sighting: Sighting, elevation_sigma: float) -> Detection:
    c = sighting.covariance
    covariance = np.array(
        [[c[0, 0], 0.0, c[0, 1]], [0.0, elevation_sigma**2, 0.0], [c[1, 0], 0.0, c[1, 1]]]
    )
    return Detection(
        class_id=0,
        score=1.0,
        bearing=float(sighting.bearing),
        elevation=0.0,
        range=float(sighting.range),
        covariance=_floats(covariance),
        source="bbox",  # the contract knows tags and detector boxes; a sighting is the latter
        truth_landmark_id=sighting.landmark_id,
    )


@dataclass(frozen=True)
class ConversionSummary:
    out: Path
    num_poses: int
    num_detections: int
    num_landmarks: int

    def summary_line(self) -> str:
        return (
            f"wrote {self.out}: {self.num_poses} poses, {self.num_detections} detections of "
            f"{self.num_landmarks} landmarks (their ids kept as truth_landmark_id)"
        )


def convert_landmarks2d(
    source: Path, out: Path, config: Landmarks2dConfig | None = None
) -> ConversionSummary:
    """Write `source`, a 2-D landmark file, as a contract log at `out` (all or nothing)."""
    config = config or load_landmarks2d_config()
    data = parse_landmarks2d(source)
    index = {pose_id: k for k, pose_id in enumerate(data.pose_ids())}
    seen: dict[int, list[Sighting]] = {}
    for s in data.sightings:
        seen.setdefault(index[s.pose_id], []).append(s)
    metadata = LogMetadata(
        num_classes=1,
        confusion_matrix=((1.0,),),
        class_names=("landmark",),
        source=f"mmslam convert {Path(source).name} (a 2-D landmark dataset, lifted)",
    )
    period_ns = round(config.keyframe_period_s * 1e9)
    with LogWriter(out, metadata) as writer:
        for k in range(len(index)):
            stamp = k * period_ns
            if k > 0:
                step = data.steps[k - 1]
                x, y, theta = step.motion
                writer.write(
                    Odometry(
                        stamp_ns=stamp,
                        from_index=k - 1,
                        to_index=k,
                        translation=(x, y, 0.0),
                        rotation=(0.0, 0.0, math.sin(theta / 2), math.cos(theta / 2)),
                        covariance=_floats(odometry_covariance(step, config.flat_sigma)),
                    )
                )
            detections = tuple(detection(s, config.elevation_sigma_rad) for s in seen.get(k, []))
            writer.write(Detections(stamp_ns=stamp, pose_index=k, detections=detections))
    return ConversionSummary(
        out=Path(out),
        num_poses=len(index),
        num_detections=len(data.sightings),
        num_landmarks=len({s.landmark_id for s in data.sightings}),
    )
