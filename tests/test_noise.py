"""Noise scales from innovations and drift windows: by hand, and recovery of misstatements."""

import gtsam
import numpy as np
import pytest

from pipeline.backend.noise import (
    OUTLIER_SCALE,
    OUTLIER_SHARE,
    SETTLING_VARIANCE,
    DriftScaleBelief,
    NoiseScales,
    OdometryDrift,
    ScaleEstimator,
    composed_odometry,
    drift_log_likelihood,
    drift_scale,
    drift_spectrum,
    measurement_corrections,
    odometry_scale_move,
    relative_covariance,
    robust_drift_log_likelihood,
    settled,
    updated,
)

GAMMA = np.diag([0.02**2, 0.01**2, 0.3**2])


def pairings(n, true_a, true_b, prior_scale, rng):
    """n pairings whose prior part is `prior_scale` times Gamma's size, drawn with the true
    scales."""
    out = []
    for _ in range(n):
        G = rng.normal(size=(3, 3)) * np.sqrt(np.diag(GAMMA))[:, None] * prior_scale
        P = G @ G.T
        true = true_a * P + np.diag(np.asarray(true_b) * np.diag(GAMMA))
        out.append((rng.multivariate_normal(np.zeros(3), true, method="cholesky"), P, GAMMA))
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
    rng = np.random.default_rng(7)
    for row in pairings(3000, 1.0, [1 / 36, 1.0, 1.0], 0.05, rng):
        estimator.add(*row)
    b = estimator.corrections()
    assert b[0] == pytest.approx(1 / 36, rel=0.3)
    assert b[1] == pytest.approx(1.0, rel=0.15) and b[2] == pytest.approx(1.0, rel=0.15)


def test_consistent_noise_gives_corrections_near_one():
    estimator = ScaleEstimator(3, window=10000, min_pairings=100, bounds=(1e-2, 1e2))
    rng = np.random.default_rng(8)
    for row in pairings(3000, 1.0, [1, 1, 1], 0.1, rng):
        estimator.add(*row)
    np.testing.assert_allclose(estimator.corrections(), 1.0, rtol=0.12)


def test_too_few_pairings_say_nothing_and_bounds_hold():
    estimator = ScaleEstimator(3, window=10, min_pairings=5, bounds=(0.5, 2.0))
    rng = np.random.default_rng(9)
    for row in pairings(4, 1.0, [1, 1, 1], 0.1, rng):
        estimator.add(*row)
    assert estimator.corrections() is None
    for row in pairings(6, 1.0, [50, 50, 50], 0.1, rng):
        estimator.add(*row)
    assert len(estimator) == 10
    assert np.all(estimator.corrections() <= 2.0)
    estimator.clear()
    assert len(estimator) == 0


def test_updated_scales_take_bounded_steps():
    scales = NoiseScales(2.0, (1.0, 0.5, 1.0))
    new = updated(scales, np.array([0.5, 4.0, 1.0]), (0.1, 10.0), max_step=3.0)
    assert new.odometry == 2.0  # kept as it was
    # products of the scales and their bounded steps: equal to round-off
    assert new.measurement == pytest.approx((0.5, 1.5, 1.0), rel=1e-12)
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


def test_drift_spectrum_by_hand():
    # Q = 2 I, C = diag(1, 1, 0, 0, 0, 0): whitened, C is diag(0.5, 0.5, 0, ...), so the rest of
    # the graph decides half of the first two directions and all of the others; the
    # discrepancy whitened is delta / sqrt(2)
    delta = np.array([2.0, 1.0, 0, 0, 0, 0])
    C = np.diag([1.0, 1.0, 0, 0, 0, 0])
    shares, components = drift_spectrum(delta, 2 * np.eye(6), C)
    np.testing.assert_allclose(shares, [0.5, 0.5, 1, 1, 1, 1])
    assert sorted(components[:2] ** 2) == pytest.approx([0.5, 2.0])
    np.testing.assert_allclose(components[2:], 0, atol=1e-12)


def test_drift_log_likelihood_by_hand():
    # shares 0.5, 1, 0 with components 1, 2, 0.1: variances 0.25 + 0.25 c, c and nothing
    # but the settling variance s
    shares = np.array([[0.5, 1.0, 0.0]])
    components = np.array([[1.0, 2.0, 0.1]])
    s = SETTLING_VARIANCE
    for c in (1.0, 4.0):
        v = np.array([0.25 + 0.25 * c + s, c + s, s])
        expected = -0.5 * np.sum(np.log(v) + components[0] ** 2 / v)
        assert drift_log_likelihood(np.array([c]), shares, components)[0] == pytest.approx(expected)


def fused_windows(Q, L, true_scale, n, rng):
    """n windows whose odometry (true covariance true_scale Q) and rest of the graph
    (covariance L) are fused as the back-end would with Q: (shares, components) stacked."""
    C = np.linalg.inv(np.linalg.inv(Q) + np.linalg.inv(L))  # the estimate's covariance
    z_o = rng.multivariate_normal(np.zeros(6), true_scale * Q, size=n, method="cholesky")
    z_l = rng.multivariate_normal(np.zeros(6), L, size=n, method="cholesky")
    fused = (C @ (np.linalg.solve(Q, z_o.T) + np.linalg.solve(L, z_l.T))).T
    windows = [drift_spectrum(d, Q, C) for d in z_o - fused]
    return np.stack([w[0] for w in windows]), np.stack([w[1] for w in windows])


@pytest.mark.parametrize("true_scale", [0.25, 1.0, 6.0])
def test_drift_scale_comes_back_where_landmarks_pin_the_pose_only_partly(true_scale):
    rng = np.random.default_rng(11)
    A, B = rng.normal(size=(6, 6)), rng.normal(size=(6, 6))
    Q, L = A @ A.T + 0.1 * np.eye(6), 3.0 * (B @ B.T) + 0.1 * np.eye(6)
    shares, components = fused_windows(Q, L, true_scale, 2000, rng)
    scale, evidence = drift_scale(shares, components, (0.01, 100.0))
    assert scale == pytest.approx(true_scale, rel=0.1)
    if true_scale == 1.0:
        assert evidence < 3.0
    else:
        assert evidence > 20.0


def test_drift_scale_is_not_moved_by_one_window_a_wrong_association_bent():
    """Nineteen windows of an odometry stated right and one across a wrong loop closure,
    tens of sigmas off along directions the landmarks decide little of (as on kitti05-cars,
    noise x5, seed 5): the scale stays about 1; where the odometry is understated, at about
    the true scale."""
    rng = np.random.default_rng(5)
    A, B = rng.normal(size=(6, 6)), rng.normal(size=(6, 6))
    Q, L = A @ A.T + 0.1 * np.eye(6), 3.0 * (B @ B.T) + 0.1 * np.eye(6)
    shares, components = fused_windows(Q, L, 1.0, 20, rng)
    components[0] = 30.0 * np.sign(components[0] + 1e-12)
    scale, evidence = drift_scale(shares, components, (0.01, 100.0))
    assert scale < 3.0
    assert evidence < 3.0
    # windows of an odometry whose sigmas are understated 5 times, one of them bent too
    shares, components = fused_windows(Q, L, 25.0, 20, rng)
    components[0] = 30.0 * np.sign(components[0] + 1e-12)
    scale, evidence = drift_scale(shares, components, (0.01, 100.0))
    assert 10.0 < scale < 60.0
    assert evidence > 20.0


def test_robust_drift_log_likelihood_by_hand():
    # one window, shares 1 and 0: variances c + s and s under the model, OUTLIER_SCALE + s and
    # s as an outlier; the two mixed with weights 1 - OUTLIER_SHARE and OUTLIER_SHARE
    shares, components = np.array([[1.0, 0.0]]), np.array([[3.0, 0.0]])
    s = SETTLING_VARIANCE

    def gaussian(v):
        return np.exp(-0.5 * (np.log(v) + 9.0 / v)) * s**-0.5

    for c in (1.0, 9.0):
        expected = np.log(
            (1 - OUTLIER_SHARE) * gaussian(c + s) + OUTLIER_SHARE * gaussian(OUTLIER_SCALE + s)
        )
        got = robust_drift_log_likelihood(np.array([c]), shares, components)[0]
        assert got == pytest.approx(expected)


@pytest.mark.parametrize("true_scale", [0.25, 4.0])
def test_drift_scale_comes_back_where_windows_reach_little(true_scale):
    """Landmarks that pin the window's relative pose only loosely (L = 2.5 Q: the rest of
    the graph decides 2/7 of each direction): few windows, each of which says little, but
    together the scale."""
    rng = np.random.default_rng(3)
    Q = np.diag([1e-4, 1e-4, 4e-4, 1e-2, 1e-2, 1e-3])
    shares, components = fused_windows(Q, 2.5 * Q, true_scale, 400, rng)
    np.testing.assert_allclose(shares, 1 - 1 / 1.4)
    scale, _ = drift_scale(shares, components, (0.01, 100.0))
    assert scale == pytest.approx(true_scale, rel=0.2)
    # the scale is sought within its bounds only, also where they leave out the windows' own
    assert drift_scale(shares, components, (0.5, 2.0))[0] == (0.5 if true_scale < 1 else 2.0)
    outside = (0.1, 0.5) if true_scale > 1 else (2.0, 10.0)
    assert drift_scale(shares, components, outside)[0] == outside[true_scale > 1]


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
            noise = rng.multivariate_normal(np.zeros(6), true_scale * stated, method="cholesky")
            drift.add_step(step * gtsam.Pose3.Expmap(noise), stated)
        assert drift.due(20 * (window + 1), 20) == [20]
        relative = truth[0]
        for step in truth[1:]:
            relative = relative * step
        drift.observe(relative, np.zeros((12, 12)), 1.0)
        if window < 3:
            assert drift.reading((0.01, 100.0)) is None
    scale, _ = drift.reading((0.01, 100.0))
    assert scale == pytest.approx(true_scale, rel=0.1)
    # the windows were taken at scale 1; at another, the reading is the same scale
    assert drift.reading((1.0, 4.0))[0] == pytest.approx(min(true_scale, 4.0), rel=0.1)


def test_long_windows_are_due_every_their_own_length_once_their_steps_are_known():
    drift = OdometryDrift(length=2, kept=10, min_windows=1, long_length=6)
    step = gtsam.Pose3(gtsam.Rot3(), np.array([1.0, 0, 0]))
    for _ in range(4):
        drift.add_step(step, np.eye(6))
    assert drift.due(4, 2) == [2]  # a long window needs six steps
    assert drift.due(5, 2) == []
    for _ in range(2):
        drift.add_step(step, np.eye(6))
    assert drift.due(6, 2) == [2, 6]
    assert drift.due(8, 2) == [2]  # not every 2: long windows never overlap
    assert drift.due(12, 2) == [2, 6]
    alone = OdometryDrift(length=2, kept=10, min_windows=1)
    for _ in range(6):
        alone.add_step(step, np.eye(6))
    assert alone.due(6, 2) == [2]


def test_long_windows_read_the_larger_scale_of_a_biased_odometry():
    """A yaw bias that changes slowly (first-order autoregressive) drifts more over 40 steps
    than its variance per step says: windows of 40 read a larger scale than windows of 5, and
    both lengths read together fall in between, each window of a length composed of that many
    of the latest steps."""
    rng = np.random.default_rng(11)
    stated = np.diag([1e-8, 1e-8, 1e-6, 1e-6, 1e-6, 1e-8])
    short = OdometryDrift(length=5, kept=1000, min_windows=4)
    long = OdometryDrift(length=40, kept=1000, min_windows=4)
    both = OdometryDrift(length=5, kept=1000, min_windows=4, long_length=40)
    step = gtsam.Pose3(gtsam.Rot3(), np.array([0.5, 0, 0]))
    truth, bias = [], 0.0
    for k in range(1, 4001):
        bias = 0.98 * bias + np.sqrt(1 - 0.98**2) * rng.normal(0.0, 1e-3)
        noisy = step * gtsam.Pose3(gtsam.Rot3.Rz(bias), np.zeros(3))
        truth.append(step)
        for drift, every in ((short, 5), (long, 40), (both, 5)):
            drift.add_step(noisy, stated)
            for n in drift.due(k, every):
                relative = gtsam.Pose3()
                for s in truth[-n:]:
                    relative = relative * s
                drift.observe(relative, np.zeros((12, 12)), 1.0, n)
    bounds = (0.01, 1e4)
    low, high = short.reading(bounds)[0], long.reading(bounds)[0]
    assert high > 4.0 * low
    assert low < both.reading(bounds)[0] < high


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
    assert drift.reading((0.01, 100.0))[1] == pytest.approx(0.0, abs=1e-9)


def test_a_window_is_settled_unless_the_odometry_alone_is_off():
    shares = np.array([0.0, 0.01, 0.04, 0.3, 0.9, 1.0])
    # large where the landmarks decide: the scale's business
    assert settled(shares, np.array([0.4, -0.45, 0.3, 5.0, -8.0, 3.0]))
    # off by more than half a sigma where only the odometry decides: not the model's
    assert not settled(shares, np.array([0.0, 0.0, -0.6, 0.0, 0.0, 0.0]))


def test_drift_leaves_out_a_window_bent_where_the_odometry_alone_decides():
    drift = OdometryDrift(length=1, kept=10, min_windows=1)
    step = gtsam.Pose3(gtsam.Rot3(), np.array([1.0, 0, 0]))
    drift.add_step(step, np.eye(6))
    # the landmarks decide nothing (C = Q), yet the estimate is a sigma away from the odometry
    joint = np.zeros((12, 12))
    joint[6:, 6:] = np.eye(6)
    bent = step * gtsam.Pose3(gtsam.Rot3(), np.array([0, 1.0, 0]))
    drift.observe(bent, joint, 1.0)
    assert drift.reading((0.01, 100.0)) is None
    drift.observe(step, joint, 1.0)
    assert drift.reading((0.01, 100.0)) is not None


@pytest.mark.parametrize(
    ("reading", "evidence", "expected"),
    [
        (12.0, 5.0, 12.0),  # up: 12 >= 3 x 4
        (12.0, 2.0, None),  # the windows are not sure enough
        (11.0, 50.0, None),  # short of the deadband
        (1.3, 5.0, 1.3),  # down: 1.3 <= 4 / 3
        (1.5, 50.0, None),
        (4.0, 50.0, None),  # the scale it has
    ],
)
def test_odometry_scale_moves_by_clear_steps_on_evidence(reading, evidence, expected):
    assert odometry_scale_move(4.0, reading, evidence, 3.0, 3.0) == expected


def test_odometry_scale_comes_down_only_when_allowed():
    assert odometry_scale_move(4.0, 1.2, 9.0, 3.0, 3.0, down=False) is None
    assert odometry_scale_move(4.0, 12.0, 9.0, 3.0, 3.0, down=False) == 12.0


def test_drift_scale_belief_starts_as_its_prior():
    belief = DriftScaleBelief(0.5, 100.0, 2)
    scales, log_weights = belief.relative(1.0)
    np.testing.assert_allclose(scales, [1.0, 10.0, 100.0])
    np.testing.assert_allclose(np.exp(log_weights), [0.5, 0.25, 0.25])
    for none in (DriftScaleBelief(0.0, 100.0, 4), DriftScaleBelief(0.5, 1.0, 4)):
        np.testing.assert_array_equal(none.relative(1.0)[0], [1.0])
        np.testing.assert_array_equal(none.relative(1.0)[1], [0.0])


def test_drift_scale_belief_is_relative_to_the_odometry_scale():
    # at an odometry scale of 10, scales 1 and 10 are the current one; 100 is 10 times it
    scales, log_weights = DriftScaleBelief(0.5, 100.0, 2).relative(10.0)
    np.testing.assert_allclose(scales, [1.0, 10.0])
    np.testing.assert_allclose(np.exp(log_weights), [0.75, 0.25])
    scales, log_weights = DriftScaleBelief(0.5, 100.0, 2).relative(0.5)  # all above it
    np.testing.assert_allclose(scales, [1.0, 2.0, 20.0, 200.0])
    np.testing.assert_allclose(np.exp(log_weights), [0.0, 0.5, 0.25, 0.25])


def test_drift_scale_belief_is_the_posterior_of_the_loops_closed():
    belief = DriftScaleBelief(0.5, 100.0, 2)
    belief.observe(1.0, np.log([0.1, 0.2, 0.6]))  # a loop that a large drift explains best
    posterior = np.array([0.5 * 0.1, 0.25 * 0.2, 0.25 * 0.6])
    np.testing.assert_allclose(np.exp(belief.relative(1.0)[1]), posterior / posterior.sum())
    # seen from an odometry scale of 10, the same loop again: 1 and 10 are one entry
    belief.observe(10.0, np.log([0.2, 0.6]))
    posterior *= [0.2, 0.2, 0.6]
    np.testing.assert_allclose(np.exp(belief.relative(1.0)[1]), posterior / posterior.sum())
    report = belief.report()
    assert report["loops"] == 2
    np.testing.assert_allclose(report["scales"], [1.0, 10.0, 100.0], rtol=1e-12)  # powers of 10
    np.testing.assert_allclose(report["probabilities"], posterior / posterior.sum(), atol=1e-4)


def test_drift_scale_belief_reads_its_likeliest_scale_against_the_current_one():
    belief = DriftScaleBelief(0.5, 100.0, 2)  # scales 1, 10, 100; prior 0.5, 0.25, 0.25
    assert belief.reading(1.0) is None  # no loop yet
    belief.observe(1.0, np.log([0.1, 0.2, 0.6]))
    # each loop an outlier with probability 0.05, likely as its best then: 0.95 p + 0.05 * 0.6
    posterior = np.array([0.5, 0.25, 0.25]) * (0.95 * np.array([0.1, 0.2, 0.6]) + 0.03)
    scale, evidence = belief.reading(1.0)
    assert scale == pytest.approx(100.0)
    assert evidence == pytest.approx(np.log(posterior[2] / posterior[0]))
    # at 10, scales 1 and 10 both stand for the current one
    assert belief.reading(10.0)[1] == pytest.approx(np.log(posterior[2] / posterior[:2].sum()))
    # at 100 the likeliest is the current one: no evidence for a move
    assert belief.reading(100.0)[1] == pytest.approx(np.log(posterior[2] / posterior.sum()))


def test_one_loop_however_sure_moves_the_scale_by_three_nats_at_most_and_two_can_more():
    belief = DriftScaleBelief(0.5, 100.0, 2)
    sure = np.array([-1000.0, 0.0, 0.0])  # scale 1 ruled out by a thousand nats
    belief.observe(1.0, sure)
    _, evidence = belief.reading(1.0)
    # prior odds 0.25 / 0.5, the loop at most 1 / 0.05
    assert evidence == pytest.approx(np.log(0.25 / (0.5 * 0.05)), abs=1e-9)
    assert odometry_scale_move(1.0, 10.0, evidence, 3.0, 3.0) is None
    belief.observe(1.0, sure)
    _, evidence = belief.reading(1.0)
    assert evidence == pytest.approx(np.log(0.25 / (0.5 * 0.05**2)), abs=1e-9)
    assert odometry_scale_move(1.0, 10.0, evidence, 3.0, 3.0) == 10.0
