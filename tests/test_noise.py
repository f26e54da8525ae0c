"""Noise scales from innovations: moments by hand, and recovery of known misstatements."""

import numpy as np
import pytest

from pipeline.backend.noise import (
    NoiseScales,
    ScaleEstimator,
    measurement_corrections,
    odometry_correction,
    updated,
)

RNG = np.random.default_rng(7)
GAMMA = np.diag([0.02**2, 0.01**2, 0.3**2])


def pairings(n, true_a, true_b, prior_scale):
    """n pairings whose prior part is `prior_scale` times Gamma's size, drawn with the true
    scales."""
    out = []
    for _ in range(n):
        G = RNG.normal(size=(3, 3)) * np.sqrt(np.diag(GAMMA))[:, None] * prior_scale
        P = G @ G.T
        true = true_a * P + np.diag(np.asarray(true_b) * np.diag(GAMMA))
        out.append((RNG.multivariate_normal(np.zeros(3), true), P, GAMMA))
    return out


def stacked(rows):
    return (np.stack(part) for part in zip(*rows, strict=True))


def test_measurement_moment_by_hand():
    nu = np.array([[0.2, 0.0, 0.0], [0.0, 0.0, 0.0]])
    P = np.zeros((2, 3, 3))
    G = np.stack([np.eye(3) * 0.01] * 2)
    # bearing: (0.04 + 0) / (0.01 + 0.01) = 2; the others: 0
    np.testing.assert_allclose(measurement_corrections(nu, P, G, 2), [2.0, 0.0, 0.0])
    assert np.all(measurement_corrections(nu, P, G, 3) == 1.0)  # too few: unchanged


def test_odometry_moment_by_hand():
    # one drift pairing: S = P + G = 5 I, nu^T S^-1 nu = 10 / 5 = 2, tr(S^-1 G) = 0.6,
    # tr(S^-1 P) = 2.4: a = (2 - 0.6) / 2.4
    nu = np.array([[np.sqrt(10.0), 0.0, 0.0]])
    P, G = np.eye(3)[None] * 4.0, np.eye(3)[None] * 1.0
    assert odometry_correction(nu, P, G, np.ones(3), 1) == pytest.approx(1.4 / 2.4)


def test_estimator_recovers_understated_odometry_and_overstated_bearing():
    estimator = ScaleEstimator(3, window=10000, min_pairings=100, bounds=(1e-2, 1e2))
    rows = pairings(2000, 20.0, [1 / 36, 1.0, 1.0], 0.1) + pairings(2000, 20.0, [1 / 36, 1, 1], 5)
    for row in rows:
        estimator.add(*row)
    a, *b = estimator.corrections()
    assert a == pytest.approx(20.0, rel=0.15)
    # the bearing's share hides under the drift's even in the tracking pairings: the estimate
    # is rough, but it says the stated bearing variance is some 10 to 100 times too large
    assert 0.01 < b[0] < 0.1
    assert b[1] == pytest.approx(1.0, rel=0.15) and b[2] == pytest.approx(1.0, rel=0.15)


def test_consistent_noise_gives_corrections_near_one():
    estimator = ScaleEstimator(3, window=10000, min_pairings=100, bounds=(1e-2, 1e2))
    for row in pairings(1500, 1.0, [1, 1, 1], 0.1) + pairings(1500, 1.0, [1, 1, 1], 5):
        estimator.add(*row)
    np.testing.assert_allclose(estimator.corrections(), 1.0, rtol=0.12)


def test_without_drift_the_odometry_scale_is_left_alone():
    nu, P, G = stacked(pairings(500, 1.0, [4.0, 1.0, 1.0], 0.1))
    assert odometry_correction(nu, P, G, np.ones(3), 100) == 1.0


def test_too_few_pairings_say_nothing_and_bounds_hold():
    estimator = ScaleEstimator(3, window=10, min_pairings=5, bounds=(0.5, 2.0))
    for row in pairings(4, 1.0, [1, 1, 1], 0.1):
        estimator.add(*row)
    assert estimator.corrections() is None
    for row in pairings(6, 1.0, [50, 50, 50], 0.1):
        estimator.add(*row)
    assert len(estimator) == 10
    assert np.all(estimator.corrections() <= 2.0)
    estimator.clear()
    assert len(estimator) == 0


def test_updated_scales_take_bounded_steps():
    scales = NoiseScales(2.0, (1.0, 0.5, 1.0))
    new = updated(scales, np.array([10.0, 0.5, 4.0, 1.0]), (0.1, 10.0), max_step=3.0)
    assert new == NoiseScales(6.0, (0.5, 1.5, 1.0))
    D = new.measurement_matrix()
    np.testing.assert_allclose(D @ np.eye(3) @ D, np.diag([0.5, 1.5, 1.0]))
