"""Noise scales from innovations: equations by hand, and recovery of known misstatements."""

import numpy as np
import pytest

from pipeline.backend.noise import NoiseScales, ScaleEstimator, scale_equations, updated

RNG = np.random.default_rng(7)


def test_equations_of_a_consistent_innovation_in_its_own_whitened_frame():
    # S = P + Gamma = I: W = I, and the equations read nu nu^T = a P + sum_k b_k Gamma_kk e_k e_k^T
    P = np.diag([0.5, 0.25, 0.0])
    gamma = np.diag([0.5, 0.75, 1.0])
    nu = np.array([1.0, 2.0, 0.0])
    A, y = scale_equations(nu, P, gamma)
    # upper triangle order: (0,0) (0,1) (0,2) (1,1) (1,2) (2,2)
    np.testing.assert_allclose(y, [1.0, 2.0, 0.0, 4.0, 0.0, 0.0])
    np.testing.assert_allclose(A[:, 0], [0.5, 0.0, 0.0, 0.25, 0.0, 0.0])
    np.testing.assert_allclose(A[:, 1], [0.5, 0, 0, 0, 0, 0])
    np.testing.assert_allclose(A[:, 2], [0, 0, 0, 0.75, 0, 0])
    np.testing.assert_allclose(A[:, 3], [0, 0, 0, 0, 0, 1.0])


def simulate(estimator, true_a, true_b, n=3000):
    """Pairings whose prior part ranges from none (tracking) to dominant (after a drift)."""
    gamma = np.diag([0.02**2, 0.01**2, 0.3**2])
    for _ in range(n):
        G = RNG.normal(size=(3, 3)) * np.exp(RNG.uniform(np.log(1e-4), np.log(0.05)))
        P = G @ G.T
        true = true_a * P + np.diag(np.asarray(true_b) * np.diag(gamma))
        nu = RNG.multivariate_normal(np.zeros(3), true)
        estimator.add(nu, P, gamma)


def test_estimator_recovers_understated_odometry_and_overstated_bearing():
    estimator = ScaleEstimator(3, window=5000, min_pairings=100, bounds=(1e-2, 1e2))
    simulate(estimator, true_a=20.0, true_b=[1 / 36, 1.0, 1.0])
    a, *b = estimator.corrections()
    assert a == pytest.approx(20.0, rel=0.15)
    assert b[0] == pytest.approx(1 / 36, rel=0.25)
    assert b[1] == pytest.approx(1.0, rel=0.15) and b[2] == pytest.approx(1.0, rel=0.15)


def test_consistent_noise_gives_corrections_near_one():
    estimator = ScaleEstimator(3, window=5000, min_pairings=100, bounds=(1e-2, 1e2))
    simulate(estimator, 1.0, [1.0, 1.0, 1.0])
    np.testing.assert_allclose(estimator.corrections(), 1.0, rtol=0.12)


def test_too_few_pairings_say_nothing_and_bounds_hold():
    estimator = ScaleEstimator(3, window=10, min_pairings=5, bounds=(0.5, 2.0))
    simulate(estimator, 1.0, [1.0, 1.0, 1.0], n=4)
    assert estimator.corrections() is None
    simulate(estimator, 50.0, [1.0, 1.0, 1.0], n=6)
    assert len(estimator) == 10
    assert np.all(estimator.corrections() <= 2.0)
    estimator.clear()
    assert len(estimator) == 0


def test_updated_scales_multiply_and_stay_bounded():
    scales = NoiseScales(2.0, (1.0, 0.5, 1.0))
    new = updated(scales, np.array([10.0, 0.5, 4.0, 1.0]), (0.1, 10.0))
    assert new == NoiseScales(10.0, (0.5, 2.0, 1.0))
    D = new.measurement_matrix()
    np.testing.assert_allclose(D @ np.eye(3) @ D, np.diag([0.5, 2.0, 1.0]))
