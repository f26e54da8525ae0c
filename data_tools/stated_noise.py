"""A log's noise stated wrong on purpose: its covariances scaled per direction.

A robust back-end must not need the noise stated right. To measure how much it does, a log
states each direction's variance times a factor: the odometry's per body-frame direction
(roll, pitch, yaw, forward, lateral, vertical: GTSAM's Pose3 tangent order), a detection's per
component (bearing, elevation, range), and a tag's relative pose as a whole. Factors are on
variances (4: sigmas twice the truth); a covariance D S D, D = diag(sqrt(factors)), keeps its
correlations.

    mmslam simulate kitti05-cars --true-covariance --stated-odometry yaw=0.1 --out k.mcap
    mmslam restate vp.mcap --stated-detections bearing=4,range=4 --out vp-loose.mcap
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from pipeline.backend.noise import ODOMETRY_AXES, scaled_covariance
from pipeline.errors import InputError
from pipeline.foxglove.log_topics import foxglove_mirror
from pipeline.log import LogWriter
from pipeline.log.mcap_stream import McapFile
from pipeline.log.messages import Detection, Detections, Odometry
from pipeline.log.reader import log_metadata
from pipeline.log.validate import LogValidator

DETECTION_COMPONENTS = ("bearing", "elevation", "range")
ALL = "all"
# The directions a sweep's axis states wrong: each alone, or all of the odometry's or of the
# detections' (`stated_noise_of`).
STATED_DIRECTIONS = (*ODOMETRY_AXES, "odometry", *DETECTION_COMPONENTS, "detections")
# Factors further from 1 than this are no misstatement but a unit error.
MAX_FACTOR = 1e4


@dataclass(frozen=True)
class StatedNoise:
    """Variance factors: what a log states over what it would state otherwise."""

    odometry: tuple[float, ...] = (1.0,) * 6  # ODOMETRY_AXES
    detections: tuple[float, ...] = (1.0,) * 3  # DETECTION_COMPONENTS
    relative_pose: float = 1.0  # a tag's 6-DoF pose, every direction

    @property
    def is_identity(self) -> bool:
        return all(f == 1.0 for f in (*self.odometry, *self.detections, self.relative_pose))

    def describe(self) -> str:
        """As the command line takes it ('' when nothing is restated)."""
        parts = []
        for flag, names, factors in (
            ("--stated-odometry", ODOMETRY_AXES, self.odometry),
            ("--stated-detections", DETECTION_COMPONENTS, self.detections),
        ):
            changed = [f"{n}={f:g}" for n, f in zip(names, factors, strict=True) if f != 1.0]
            if changed:
                parts.append(f"{flag} {','.join(changed)}")
        if self.relative_pose != 1.0:
            parts.append(f"--stated-tag-pose {self.relative_pose:g}")
        return " ".join(parts)


def parse_factors(text: str, names: tuple[str, ...], option: str) -> tuple[float, ...]:
    """'yaw=4,forward=0.25' (or 'all=10', or both: later keys win) as one factor per name."""
    factors = dict.fromkeys(names, 1.0)
    for item in filter(None, (part.strip() for part in text.split(","))):
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or (key not in names and key != ALL):
            raise InputError(
                f"{option}: expected NAME=FACTOR with NAME one of {', '.join((*names, ALL))}, "
                f"got {item[:40]!r}"
            )
        factor = parse_factor(value, option)
        for name in names if key == ALL else (key,):
            factors[name] = factor
    return tuple(factors[n] for n in names)


def stated_noise_of(spec: str) -> StatedNoise:
    """A sweep cell's "DIRECTION=FACTOR" (one of STATED_DIRECTIONS; "" states nothing wrong)."""
    if not spec:
        return StatedNoise()
    direction, _, value = spec.partition("=")
    if direction in ("odometry", *ODOMETRY_AXES):
        key = ALL if direction == "odometry" else direction
        return StatedNoise(odometry=parse_factors(f"{key}={value}", ODOMETRY_AXES, spec))
    if direction in ("detections", *DETECTION_COMPONENTS):
        key = ALL if direction == "detections" else direction
        return StatedNoise(detections=parse_factors(f"{key}={value}", DETECTION_COMPONENTS, spec))
    raise InputError(f"not a stated direction: {spec!r}; use one of {', '.join(STATED_DIRECTIONS)}")


def parse_factor(value: str, option: str) -> float:
    try:
        factor = float(value)
    except ValueError:
        raise InputError(f"{option}: a factor must be a number, got {value[:40]!r}") from None
    if not (math.isfinite(factor) and 1.0 / MAX_FACTOR <= factor <= MAX_FACTOR):
        raise InputError(
            f"{option}: a factor must lie within {1 / MAX_FACTOR:g}..{MAX_FACTOR:g}, got {factor:g}"
        )
    return factor


def restated_covariance(covariance: tuple[float, ...], factors: tuple[float, ...]) -> tuple:
    """A row-major covariance with each direction's variance times its factor."""
    n = len(factors)
    matrix = np.reshape(np.asarray(covariance, dtype=float), (n, n))
    return tuple(float(v) for v in scaled_covariance(matrix, factors).ravel())


def restate_odometry(odometry: Odometry, stated: StatedNoise) -> Odometry:
    if all(f == 1.0 for f in stated.odometry):
        return odometry
    return replace(odometry, covariance=restated_covariance(odometry.covariance, stated.odometry))


def restate_detection(detection: Detection, stated: StatedNoise) -> Detection:
    changes = {}
    if any(f != 1.0 for f in stated.detections):
        changes["covariance"] = restated_covariance(detection.covariance, stated.detections)
    pose = detection.relative_pose
    if pose is not None and stated.relative_pose != 1.0:
        factors = (stated.relative_pose,) * 6
        changes["relative_pose"] = replace(
            pose, covariance=restated_covariance(pose.covariance, factors)
        )
    return replace(detection, **changes) if changes else detection


def restate_log(source: Path, out: Path, stated: StatedNoise) -> tuple[int, int]:
    """Copy the log `source` to `out` (atomically) with its noise stated as `stated` says;
    every other message as it was. Returns (odometry steps, detections) restated."""
    steps = detections = 0
    with McapFile(source) as mcap:
        metadata = log_metadata(mcap)
        validator = LogValidator(mcap.path, metadata)
        with LogWriter(out, metadata, foxglove_mirror) as writer:
            for channel, index, log_time, data in mcap.messages():
                msg = validator.message(channel, index, log_time, data)
                if msg is None:
                    continue
                if isinstance(msg, Odometry):
                    msg = restate_odometry(msg, stated)
                    steps += 1
                elif isinstance(msg, Detections):
                    msg = replace(
                        msg, detections=tuple(restate_detection(d, stated) for d in msg.detections)
                    )
                    detections += len(msg.detections)
                writer.write(msg, channel.topic)
            validator.finish(mcap.channels.values())
    return steps, detections
