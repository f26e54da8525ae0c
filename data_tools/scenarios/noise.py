"""Noise models shared by the scenarios: odometry, measurements, and the detector's classes.

Odometry, as in the paper (section V-A): the robot's odometry follows a *calibrated* model
(`base_*` sigmas, all six degrees of freedom), and the experiments add body-frame Gaussian
noise on x, y and yaw beyond it (sigma_x 1.5 mm, sigma_y 0.75 mm, sigma_yaw 0.00225 rad a
keyframe), multiplied by a scale factor. Both are drawn as one right perturbation in GTSAM's
Pose3 tangent coordinates, `measured = true @ Exp(xi)`, the frame the log's covariance refers
to. The log carries the calibrated covariance (what a real system would believe) unless the
true one is asked for.

Random draws are standard normals scaled by sigmas, so under one seed a larger noise scale
makes the very same errors larger: runs at different scales are paired, as in a sweep.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

import numpy as np

from data_tools.scenarios.config import MAX_NOISE_SCALE, Sigma, Spread
from data_tools.scenarios.geometry import se3_exp
from pipeline.settings import within

# Named random streams: each kind of draw has its own, so changing one option (say the
# misclassification rate) leaves every other draw of the run as it was.
STREAMS = ("odometry", "visibility", "measurement", "classes", "false_positives")


@dataclass(frozen=True)
class OdometryNoiseConfig:
    """Sigmas per keyframe: the calibrated model (base) and the paper's added noise."""

    base_rotation_sigma_rad: tuple[Sigma, Sigma, Sigma]  # roll, pitch, yaw
    base_translation_sigma_m: tuple[Sigma, Sigma, Sigma]  # x, y, z (body frame)
    added_sigma_x_m: Spread
    added_sigma_y_m: Spread
    added_sigma_yaw_rad: Spread
    # --odom-noise-scale when none is given
    default_noise_scale: Annotated[float, within(0.0, MAX_NOISE_SCALE)]


def random_streams(seed: int) -> dict[str, np.random.Generator]:
    """One independent generator per name in `STREAMS`, all from `seed`."""
    children = np.random.SeedSequence(seed).spawn(len(STREAMS))
    return {
        name: np.random.default_rng(child) for name, child in zip(STREAMS, children, strict=True)
    }


def base_odometry_sigmas(config: OdometryNoiseConfig) -> np.ndarray:
    """The calibrated model's sigmas in Pose3 tangent order (rx, ry, rz, tx, ty, tz)."""
    return np.array([*config.base_rotation_sigma_rad, *config.base_translation_sigma_m])


def added_odometry_sigmas(config: OdometryNoiseConfig, scale: float) -> np.ndarray:
    """The paper's added noise (x, y, yaw) times `scale`, in Pose3 tangent order."""
    sigmas = np.zeros(6)
    sigmas[2] = config.added_sigma_yaw_rad
    sigmas[3] = config.added_sigma_x_m
    sigmas[4] = config.added_sigma_y_m
    return scale * sigmas


def odometry_covariances(
    config: OdometryNoiseConfig, scale: float
) -> tuple[np.ndarray, np.ndarray]:
    """(calibrated, true) 6x6 covariances per keyframe; both diagonal."""
    base = base_odometry_sigmas(config) ** 2
    added = added_odometry_sigmas(config, scale) ** 2
    return np.diag(base), np.diag(base + added)


def corrupt_odometry(
    rng: np.random.Generator, true_motion: np.ndarray, covariance: np.ndarray
) -> np.ndarray:
    """Noisy (N, 4, 4) motions: `true @ Exp(xi)`, xi ~ N(0, covariance) in the motion's frame."""
    xi = sample_gaussian(rng, np.broadcast_to(covariance, (len(true_motion), 6, 6)))
    return true_motion @ se3_exp(xi)


def sample_gaussian(rng: np.random.Generator, covariances: np.ndarray) -> np.ndarray:
    """One zero-mean draw per (N, d, d) positive-definite covariance, (N, d).

    Cholesky factors keep a diagonal covariance's draws on their own axes, so the pairing of
    runs across noise scales holds component by component.
    """
    covariances = np.asarray(covariances, dtype=float)
    normals = rng.standard_normal(covariances.shape[:2])
    return np.einsum("nij,nj->ni", np.linalg.cholesky(covariances), normals)


def confusion_matrix(num_classes: int, alpha: float) -> np.ndarray:
    """P(reported | true): 1 - alpha on the diagonal, alpha spread evenly over the rest of a row."""
    if num_classes == 1:
        return np.ones((1, 1))
    off = alpha / (num_classes - 1)
    matrix = np.full((num_classes, num_classes), off)
    np.fill_diagonal(matrix, 1.0 - alpha)
    return matrix


def sample_reported_classes(
    rng: np.random.Generator, true_classes: np.ndarray, confusion: np.ndarray
) -> np.ndarray:
    """The class a detector reports for each true class, drawn from the confusion matrix rows."""
    true_classes = np.asarray(true_classes, dtype=int)
    cumulative = np.cumsum(confusion, axis=1)
    cumulative[:, -1] = 1.0  # guard against rows summing to 1 - 1e-16
    u = rng.random(len(true_classes))
    reported = (u[:, None] >= cumulative[true_classes]).sum(axis=1)
    return np.minimum(reported, confusion.shape[0] - 1)


def logistic(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-x))
