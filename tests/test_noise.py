"""Noise scales from innovations: moments by hand, and recovery of known misstatements."""

import gtsam
import numpy as np
import pytest

from pipeline.backend.noise import (
    NoiseScales,
    OdometryDrift,
    ScaleEstimator,
    composed_odometry,
    drift_corrections,
    drift_moments,
    measurement_corrections,
    odometry_scale_move,
    relative_covariance,
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


def test_estimator_recovers_overstated_bearing():
    estimator = ScaleEstimator(3, window=10000, min_pairings=100, bounds=(1e-2, 1e2))
    for row in pairings(3000, 1.0, [1 / 36, 1.0, 1.0], 0.05):
        estimator.add(*row)
    b = estimator.corrections()
    assert b[0] == pytest.approx(1 / 36, rel=0.3)
    assert b[1] == pytest.approx(1.0, rel=0.15) and b[2] == pytest.approx(1.0, rel=0.15)


def test_consistent_noise_gives_corrections_near_one():
    estimator = ScaleEstimator(3, window=10000, min_pairings=100, bounds=(1e-2, 1e2))
    for row in pairings(3000, 1.0, [1, 1, 1], 0.1):
        estimator.add(*row)
    np.testing.assert_allclose(estimator.corrections(), 1.0, rtol=0.12)


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
    new = updated(scales, np.array([0.5, 4.0, 1.0]), (0.1, 10.0), max_step=3.0)
    assert new == NoiseScales(2.0, (0.5, 1.5, 1.0))
    D = new.measurement_matrix()
    np.testing.assert_allclose(D @ np.eye(3) @ D, np.diag([0.5, 1.5, 1.0]))


def random_steps(n, rng):
    return [
        gtsam.Pose3(gtsam.Rot3.RzRyRx(*rng.normal(0, 0.1, 3)), rng.normal([1.0, 0, 0], 0.2))
        for _ in range(n)
    ]


def test_composed_covariance_matches_numerical_jacobians():
    rng = np.random.default_rng(3)
    steps = random_steps(4, rng)
    covariances = []
    for _ in steps:
        A = rng.normal(size=(6, 6)) * 0.01
        covariances.append(A @ A.T + 1e-6 * np.eye(6))
    total, Q = composed_odometry(steps, covariances)
    assert total.equals(steps[0] * steps[1] * steps[2] * steps[3], 1e-12)
    # d Log(U^-1 U(n)) / d n_k, each step perturbed as step Exp(n_k)
    eps, expected = 1e-6, np.zeros((6, 6))
    for k, cov in enumerate(covariances):
        J = np.zeros((6, 6))
        for i in range(6):
            perturbed = list(steps)
            perturbed[k] = steps[k] * gtsam.Pose3.Expmap(eps * np.eye(6)[i])
            U = perturbed[0] * perturbed[1] * perturbed[2] * perturbed[3]
            J[:, i] = gtsam.Pose3.Logmap(total.between(U)) / eps
        expected += J @ cov @ J.T
    np.testing.assert_allclose(Q, expected, rtol=1e-4, atol=1e-12)


def test_relative_covariance_matches_numerical_jacobians():
    rng = np.random.default_rng(4)
    a, b = random_steps(2, rng)
    relative = a.between(b)
    A = rng.normal(size=(12, 12)) * 0.01
    joint = A @ A.T
    eps, J = 1e-6, np.zeros((6, 12))
    for i in range(12):
        e = eps * np.eye(12)[i]
        moved = (a * gtsam.Pose3.Expmap(e[:6])).between(b * gtsam.Pose3.Expmap(e[6:]))
        J[:, i] = gtsam.Pose3.Logmap(relative.between(moved)) / eps
    np.testing.assert_allclose(relative_covariance(relative, joint), J @ joint @ J.T, atol=1e-9)


def test_drift_moments_by_hand():
    # Q = 2 I, C = diag(1, 1, 0, 0, 0, 0): nis = (4 + 1) / 2, decided = 6 - (1 + 1) / 2,
    # G = diag(0.5, 0.5, 1, 1, 1, 1): reach = tr(G G^T) = 0.25 + 0.25 + 4
    delta = np.array([2.0, 1.0, 0, 0, 0, 0])
    C = np.diag([1.0, 1.0, 0, 0, 0, 0])
    assert drift_moments(delta, 2 * np.eye(6), C) == pytest.approx((2.5, 5.0, 4.5))
    # nothing decided: the estimate is the odometry's, and none of its error shows
    assert drift_moments(delta, np.eye(6), np.eye(6))[1:] == pytest.approx((0.0, 0.0))


@pytest.mark.parametrize("true_scale", [1.0, 6.0])
def test_drift_moments_are_unbiased_where_landmarks_pin_the_pose_only_partly(true_scale):
    """The window's odometry z_o (true covariance true_scale Q) and the rest of the graph z_l
    (covariance L) fused as the back-end would with Q: E[nis] - decided = (c - 1) reach."""
    rng = np.random.default_rng(11)
    A, B = rng.normal(size=(6, 6)), rng.normal(size=(6, 6))
    Q, L = A @ A.T + 0.1 * np.eye(6), 3.0 * (B @ B.T) + 0.1 * np.eye(6)
    C = np.linalg.inv(np.linalg.inv(Q) + np.linalg.inv(L))  # the estimate's covariance
    z_o = rng.multivariate_normal(np.zeros(6), true_scale * Q, size=20000)
    z_l = rng.multivariate_normal(np.zeros(6), L, size=20000)
    fused = (C @ (np.linalg.solve(Q, z_o.T) + np.linalg.solve(L, z_l.T))).T
    moments = np.array([drift_moments(d, Q, C) for d in z_o - fused])
    nis, decided, reach = moments.sum(axis=0)
    assert 1.0 + (nis - decided) / reach == pytest.approx(true_scale, rel=0.05)
    # the plain ratio nis / decided reads low where the landmarks see the pose only partly
    if true_scale > 1:
        assert nis / decided < 0.9 * true_scale


@pytest.mark.parametrize("true_scale", [1.0, 9.0])
def test_drift_finds_the_odometry_scale_against_a_known_relative_pose(true_scale):
    """Steps drawn with true_scale times the stated covariance, against an estimate that
    knows the true relative pose (landmarks pin it: C = 0): the scale comes back."""
    rng = np.random.default_rng(5)
    stated = np.diag([1e-4, 1e-4, 4e-4, 1e-3, 1e-3, 1e-4])
    drift = OdometryDrift(length=20, kept=300, min_windows=4)
    for window in range(300):
        truth = random_steps(20, rng)
        for step in truth:
            noise = rng.multivariate_normal(np.zeros(6), true_scale * stated)
            drift.add_step(step * gtsam.Pose3.Expmap(noise), stated)
        assert drift.full
        relative = truth[0]
        for step in truth[1:]:
            relative = relative * step
        drift.observe(relative, np.zeros((12, 12)), 1.0)
        if window < 3:
            assert drift.readings() is None
    median, pooled = drift.readings()
    # the median of chi-square(6) / 6 is 0.89: the windows' median reads a little low
    assert median == pytest.approx(0.89 * true_scale, rel=0.2)
    assert pooled == pytest.approx(true_scale, rel=0.1)


def test_drift_says_nothing_where_the_landmarks_decide_nothing():
    drift = OdometryDrift(length=2, kept=10, min_windows=1)
    step = gtsam.Pose3(gtsam.Rot3(), np.array([1.0, 0, 0]))
    for _ in range(2):
        drift.add_step(step, np.eye(6))
    # the estimate's relative covariance is the odometry's own: no degree of freedom decided
    _, Q = composed_odometry([step, step], [np.eye(6), np.eye(6)])
    joint = np.zeros((12, 12))
    joint[6:, 6:] = Q
    drift.observe(step * step, joint, 1.0)
    assert drift.readings() is None


def test_drift_corrections_by_hand():
    # corrections 1 + (nis - decided) / reach: 1 + 2 / 1 = 3, 1 + 0 / 0.5 = 1, 1 - 3 / 2 = -0.5;
    # the window reaching 0.1 < MIN_REACH is left out
    moments = np.array([[5.0, 3.0, 1.0], [2.0, 2.0, 0.5], [1.0, 4.0, 2.0], [90.0, 0.0, 0.1]])
    median, pooled = drift_corrections(moments, min_windows=3)
    assert median == pytest.approx(1.0)
    assert pooled == pytest.approx(1.0 + (2.0 + 0.0 - 3.0) / 3.5)
    assert drift_corrections(moments, min_windows=4) is None
    # a correction below zero reads as zero
    assert drift_corrections(np.array([[0.0, 6.0, 1.0]]), 1) == (0.0, 0.0)


@pytest.mark.parametrize("true_scale", [0.25, 4.0])
def test_pooled_reading_is_unbiased_where_windows_reach_little(true_scale):
    """Landmarks that pin the window's relative pose only loosely (L = 2.5 Q: a fifth of the
    odometry's error per degree of freedom shows): the pooled moment comes back, the windows'
    median correction reads low, far low where the odometry's noise is overstated."""
    rng = np.random.default_rng(3)
    Q = np.diag([1e-4, 1e-4, 4e-4, 1e-2, 1e-2, 1e-3])
    C = np.linalg.inv(np.linalg.inv(Q) + np.linalg.inv(2.5 * Q))
    G = np.eye(6) - C @ np.linalg.inv(Q)
    z_o = rng.multivariate_normal(np.zeros(6), true_scale * Q, size=20000)
    z_l = rng.multivariate_normal(np.zeros(6), 2.5 * Q, size=20000)
    moments = np.array([drift_moments(G @ d, Q, C) for d in z_o - z_l])
    assert moments[0, 2] == pytest.approx(6 / 3.5**2)  # G = I / 3.5
    median, pooled = drift_corrections(moments, min_windows=1)
    assert pooled == pytest.approx(true_scale, rel=0.05)
    # an overstated odometry: the median of the skewed corrections reads zero
    assert median < (0.5 if true_scale < 1 else 0.9) * true_scale


@pytest.mark.parametrize(
    ("median", "pooled", "expected"),
    [
        (12.0, 12.0, 12.0),  # up, to the median: 12 >= 3 x 4
        (11.0, 30.0, None),  # the median short of the deadband: a bent window alone says up
        (500.0, 500.0, 100.0),  # up, to the ceiling
        (1.2, 1.3, 1.3),  # down, to the pooled moment: 1.3 <= 4 / 3
        (0.1, 1.5, None),  # the median alone says down: it reads low
        (0.1, 0.2, 1.0),  # down, to the floor
    ],
)
def test_odometry_scale_moves_by_clear_steps_within_bounds(median, pooled, expected):
    assert odometry_scale_move(4.0, median, pooled, 3.0, (1.0, 100.0)) == expected


def test_odometry_scale_comes_down_only_when_allowed():
    assert odometry_scale_move(4.0, 1.2, 1.3, 3.0, (1.0, 100.0), down=False) is None
    assert odometry_scale_move(4.0, 12.0, 12.0, 3.0, (1.0, 100.0), down=False) == 12.0


def test_odometry_scale_stays_at_a_bound_it_holds():
    assert odometry_scale_move(1.0, 0.1, 0.1, 3.0, (1.0, 100.0)) is None
    assert odometry_scale_move(100.0, 900.0, 900.0, 3.0, (1.0, 100.0)) is None
