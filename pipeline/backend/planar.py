"""Planar logs: a 2-D dataset lifted to the contract (Victoria Park, `planar-park`), solved with
its plane stated as a prior instead of left to the odometry.

Such a log moves in x, y and yaw only: its odometry says "no change in height, roll or pitch"
with a small variance, and every detection is at elevation 0. Left at that, height, roll and
pitch of the poses are a random walk the landmarks hardly see: after a thousand keyframes of
Victoria Park the newest pose's height was 4 m uncertain against a step's 1 mm. GTSAM's
Cholesky refuses to eliminate a variable whose information left after conditioning is below
2^-24 of its own (the pivot lost half the digits of a double), which a step of 1 mm against a
marginal of 4 m is (tests/test_solver.py reproduces it on a bare chain). The plane is prior
knowledge of the world, so the back-end says it: every pose gets a prior on its height
(`GPSFactor` weighing z alone) and on its tilt (`AttitudeFactorPose3`: the body's up along the
world's), which keeps those directions bounded and leaves x, y and yaw free.
"""

from __future__ import annotations

import gtsam
import numpy as np

from pipeline.log.messages import DetectionLog

UP = np.array([0.0, 0.0, 1.0])
# What counts as zero in a planar log's odometry and detections: 2-D data lifted to 3-D carries
# exact zeros, float round trips (a quaternion from a yaw-only matrix) may leave 1e-17.
PLANAR_TOLERANCE = 1e-12


def is_planar(log: DetectionLog) -> bool:
    """Whether every odometry step keeps height, roll and pitch (z, and the quaternion's x and
    y) and every detection lies at elevation 0, with at least one odometry step."""
    if not log.odometry:
        return False
    for odometry in log.odometry:
        if abs(odometry.translation[2]) > PLANAR_TOLERANCE:
            return False
        if max(abs(odometry.rotation[0]), abs(odometry.rotation[1])) > PLANAR_TOLERANCE:
            return False
    return all(
        abs(detection.elevation) <= PLANAR_TOLERANCE
        for message in log.detections
        for detection in message.detections
    )


def uses_plane(mode: str, log: DetectionLog) -> bool:
    """Whether a replay of `log` states the plane, under `[prior] planar` = `mode`."""
    return mode == "always" or (mode == "auto" and is_planar(log))


def planar_prior_factors(
    pose_key: int, height_sigma_m: float, tilt_sigma_rad: float
) -> list[gtsam.NonlinearFactor]:
    """The plane z = 0 as two priors on a pose: its height (x and y weigh nothing) and its tilt
    (the angle between its up and the world's, whatever its heading)."""
    height = gtsam.noiseModel.Diagonal.Precisions(np.array([0.0, 0.0, height_sigma_m**-2]))
    tilt = gtsam.noiseModel.Isotropic.Sigma(2, tilt_sigma_rad)
    up = gtsam.Unit3(UP)
    return [
        gtsam.GPSFactor(pose_key, np.zeros(3), height),
        gtsam.AttitudeFactorPose3(pose_key, up, tilt, up),
    ]
