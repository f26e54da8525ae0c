"""Variance scales of a log's stated noise, per direction: what the back-end uses in place of
the stated covariances."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

# The odometry's directions, GTSAM's Pose3 tangent order in the body frame (REP-103: x
# forward, y left, z up): rotations about x, y, z, then translations along them.
ODOMETRY_AXES = ("roll", "pitch", "yaw", "forward", "lateral", "vertical")
# A point detection's components (../shared/CONTRACT.md).
MEASUREMENT_COMPONENTS = ("bearing", "elevation", "range")


def scaled_covariance(stated: np.ndarray, scales: Sequence[float]) -> np.ndarray:
    """D stated D, D = diag(sqrt(scales)): each direction's variance times its scale, the
    correlations kept."""
    root = np.sqrt(np.asarray(scales, dtype=float))
    return np.asarray(stated, dtype=float) * np.outer(root, root)


@dataclass(frozen=True)
class NoiseScales:
    """Variance scales of the odometry's covariance per direction (`ODOMETRY_AXES`) and of a
    point detection's per component (`MEASUREMENT_COMPONENTS`)."""

    odometry: tuple[float, ...]
    measurement: tuple[float, ...]

    def odometry_covariance(self, stated: np.ndarray) -> np.ndarray:
        """A step's stated covariance at the odometry's scales."""
        return scaled_covariance(stated, self.odometry)

    def measurement_matrix(self) -> np.ndarray:
        """D such that D Gamma D scales component k's variance by measurement[k]."""
        return np.diag(np.sqrt(self.measurement))

    def report(self) -> dict[str, dict[str, float]]:
        """For metrics.json: each direction's scale by name."""
        return {
            "odometry": {n: float(s) for n, s in zip(ODOMETRY_AXES, self.odometry, strict=True)},
            "measurement": {
                n: float(s) for n, s in zip(MEASUREMENT_COMPONENTS, self.measurement, strict=True)
            },
        }
