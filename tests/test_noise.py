"""The noise scales learnt per direction: the likelihood and its pieces against independent
computations, and recovery of misstatements, one direction at a time, both ways."""

from dataclasses import replace

import gtsam
import numpy as np
import pytest
from scipy.stats import multivariate_normal

from pipeline.backend.geometry import predict_point_batch, predict_point_jacobians_batch
from pipeline.backend.noise import DriftScaleBelief, NoiseScales, scaled_covariance
from pipeline.backend.noise.components import (
    OUTLIER_SCALE,
    OUTLIER_SHARE,
    PRIOR_LOG_SIGMA,
    ScaleLikelihood,
    ScaleObservation,
    gaussian_log_densities,
    nonzero_pairs,
    pair_basis,
    pair_coefficients,
)
from pipeline.backend.noise.contrasts import contrast_observation
from pipeline.backend.noise.drift import (
    SETTLING_VARIANCE,
    DriftWindows,
    composed_basis,
    drift_observation,
    relative_covariance,
    transports,
    window_discrepancy,
)
from pipeline.backend.noise.learner import NoiseLearner
from pipeline.backend.noise.scales import ODOMETRY_AXES
from pipeline.config import load_config

YAW = ODOMETRY_AXES.index("yaw")
LATERAL = ODOMETRY_AXES.index("lateral")


def random_covariance(n, rng, scale=0.01):
    A = rng.normal(size=(n, n)) * scale
    return A @ A.T + 1e-3 * scale**2 * np.eye(n)


def random_steps(n, rng):
    return [
        gtsam.Pose3(gtsam.Rot3.RzRyRx(*rng.normal(0, 0.1, 3)), rng.normal([1.0, 0, 0], 0.2))
        for _ in range(n)
    ]


# --- scales -------------------------------------------------------------------------------


def test_scaled_covariance_by_hand():
    S = np.array([[4.0, 1.0], [1.0, 9.0]])
    # variances times 4 and 1, the covariance times sqrt(4 x 1)
    np.testing.assert_allclose(scaled_covariance(S, [4.0, 1.0]), [[16.0, 2.0], [2.0, 9.0]])


def test_noise_scales_apply_and_report_per_direction():
    scales = NoiseScales((1.0, 1.0, 100.0, 4.0, 1.0, 1.0), (0.25, 1.0, 9.0))
    stated = np.diag([1e-6] * 3 + [1e-4] * 3)
    np.testing.assert_allclose(
        np.diag(scales.odometry_covariance(stated)), [1e-6, 1e-6, 1e-4, 4e-4, 1e-4, 1e-4]
    )
    np.testing.assert_allclose(np.diag(scales.measurement_matrix()), [0.5, 1.0, 3.0])
    report = scales.report()
    assert report["odometry"]["yaw"] == 100.0 and report["odometry"]["forward"] == 4.0
    assert report["measurement"] == {"bearing": 0.25, "elevation": 1.0, "range": 9.0}


# --- the likelihood's pieces -------------------------------------------------------------


def test_pair_basis_gives_the_scaled_covariance():
    rng = np.random.default_rng(1)
    S = random_covariance(4, rng)
    S[0, 3] = S[3, 0] = 0.0  # a zero pair is left out
    pairs = nonzero_pairs(S[None])
    assert (0, 3) not in {tuple(p) for p in pairs} and len(pairs) == 9
    scales = rng.uniform(0.1, 10.0, 4)
    got = np.einsum("p,pab->ab", pair_coefficients(scales, pairs), pair_basis(S, pairs))
    np.testing.assert_allclose(got, scaled_covariance(S, scales), rtol=1e-12)
    # several scale vectors at once
    many = rng.uniform(0.1, 10.0, (3, 4))
    np.testing.assert_allclose(pair_coefficients(many, pairs)[2], pair_coefficients(many[2], pairs))


def test_gaussian_log_densities_match_scipy():
    rng = np.random.default_rng(2)
    V = np.stack([random_covariance(3, rng, 1.0) for _ in range(4)])
    y = rng.normal(size=(4, 3))
    expected = [multivariate_normal(np.zeros(3), v).logpdf(x) for x, v in zip(y, V, strict=True)]
    np.testing.assert_allclose(gaussian_log_densities(y, V), expected, rtol=1e-10)


def test_composed_basis_matches_the_step_by_step_composition_and_its_jacobians():
    rng = np.random.default_rng(3)
    steps = random_steps(5, rng)
    stated = np.stack([random_covariance(6, rng) for _ in steps])
    scales = rng.uniform(0.2, 20.0, 6)
    # the composition as a prediction carries a pose's covariance: Q <- A Q A^T + D S D
    Q = np.zeros((6, 6))
    for step, S in zip(steps, stated, strict=True):
        A = step.inverse().AdjointMap()
        Q = A @ Q @ A.T + scaled_covariance(S, scales)
    pairs = nonzero_pairs(stated)
    T = transports(np.array([s.inverse().AdjointMap() for s in steps]))
    basis = composed_basis(T, stated, pairs)
    np.testing.assert_allclose(np.einsum("p,pab->ab", pair_coefficients(scales, pairs), basis), Q)
    # and each step's noise reaches the end as its numerical Jacobian says
    total = steps[0] * steps[1] * steps[2] * steps[3] * steps[4]
    eps, expected = 1e-6, np.zeros((6, 6))
    for k, S in enumerate(stated):
        J = np.zeros((6, 6))
        for i in range(6):
            moved = list(steps)
            moved[k] = steps[k] * gtsam.Pose3.Expmap(eps * np.eye(6)[i])
            U = moved[0] * moved[1] * moved[2] * moved[3] * moved[4]
            J[:, i] = gtsam.Pose3.Logmap(total.between(U)) / eps
        expected += J @ scaled_covariance(S, scales) @ J.T
    np.testing.assert_allclose(Q, expected, rtol=1e-4, atol=1e-12)


def test_relative_covariance_matches_numerical_jacobians():
    rng = np.random.default_rng(4)
    a, b = random_steps(2, rng)
    relative = a.between(b)
    joint = random_covariance(12, rng)
    eps, J = 1e-6, np.zeros((6, 12))
    for i in range(12):
        e = eps * np.eye(12)[i]
        moved = (a * gtsam.Pose3.Expmap(e[:6])).between(b * gtsam.Pose3.Expmap(e[6:]))
        J[:, i] = gtsam.Pose3.Logmap(relative.between(moved)) / eps
    np.testing.assert_allclose(relative_covariance(relative, joint), J @ joint @ J.T, atol=1e-9)


def test_a_window_observation_by_hand():
    # one step, stated Q = 2 I, the estimate's relative covariance C = diag(1, 1, 0, 0, 0, 0):
    # whitened, C is diag(0.5, 0.5, 0, ...): the rest of the graph decides half of the first
    # two directions and all of the others. Under scales s (the rest erring as the odometry
    # does) the discrepancy's variance is (1 - l)^2 s + (l - l^2) s (+ settling) along each:
    # 0.5 s, and s along the others.
    step = gtsam.Pose3(gtsam.Rot3(), np.array([1.0, 0.0, 0.0]))
    joint = np.zeros((12, 12))
    joint[6:, 6:] = np.diag([1.0, 1.0, 0, 0, 0, 0])
    delta = np.array([0.2, 0.0, 0.0, 0.0, 0.3, 0.0])
    relative = step * gtsam.Pose3.Expmap(delta)
    T = transports(np.array([step.inverse().AdjointMap()]))
    stated = 2.0 * np.eye(6)[None]
    o = drift_observation(
        gtsam.Pose3.Logmap(step.between(relative)), T, stated, relative, joint, np.ones(6)
    )
    np.testing.assert_allclose(o.y, delta / np.sqrt(2.0), atol=1e-12)
    s = np.array([3.0, 1.0, 1.0, 1.0, 5.0, 1.0])
    V = o.rest + np.einsum("p,pab->ab", pair_coefficients(s, o.pairs), o.basis)
    share = np.array([0.5, 0.5, 0, 0, 0, 0])  # whitened C's eigenvalues
    expected = (1 - share) * s + SETTLING_VARIANCE
    np.testing.assert_allclose(np.diag(V), expected)


def test_a_window_the_estimate_knows_less_of_than_the_odometry_says_nothing():
    """Numerically the estimate's relative covariance can exceed the odometry's (C > Q, where a
    fused estimate has C <= Q): such a direction is the odometry's alone, and tells nothing."""
    step = gtsam.Pose3(gtsam.Rot3(), np.array([1.0, 0.0, 0.0]))
    joint = np.zeros((12, 12))
    joint[6:, 6:] = 8.0 * np.eye(6)  # whitened by Q = 2 I: 4, above 1
    T = transports(np.array([step.inverse().AdjointMap()]))
    o = drift_observation(np.zeros(6), T, 2.0 * np.eye(6)[None], step, joint, np.ones(6))
    np.testing.assert_allclose(o.basis, 0.0, atol=1e-12)
    np.testing.assert_allclose(o.rest, SETTLING_VARIANCE * np.eye(6), atol=1e-12)


def rest_erring_like_the_odometry(Qu, R, Qt):
    """The true covariance of the rest of the graph's measurement of a window (stated R) where
    it is the rest of a loop's odometry, erring as the window's does (stated Qu, true Qt):
    whitened by Qu, R_w^1/2 Qt_w R_w^1/2."""
    W = np.linalg.inv(np.linalg.cholesky(Qu))
    lam, U = np.linalg.eigh(W @ R @ W.T)
    root = (U * np.sqrt(lam)) @ U.T
    Winv = np.linalg.inv(W)
    return Winv @ root @ (W @ Qt @ W.T) @ root @ Winv.T


def test_a_window_observation_is_the_fused_estimate_s_discrepancy():
    """An odometry (true covariance Q(s)) and the rest of the graph (R, the rest of a loop,
    erring as the odometry does) fused as the back-end would with the odometry stated at
    `used`: the discrepancies' covariance is the model's."""
    rng = np.random.default_rng(5)
    Q0, R = random_covariance(6, rng), 0.5 * random_covariance(6, rng)
    used, true = np.array([1, 1, 4.0, 1, 1, 1]), np.array([1, 1, 30.0, 1, 0.3, 1])
    Qu, Qt = scaled_covariance(Q0, used), scaled_covariance(Q0, true)
    C = np.linalg.inv(np.linalg.inv(Qu) + np.linalg.inv(R))
    n = 20000
    z_o = rng.multivariate_normal(np.zeros(6), Qt, size=n, method="cholesky")
    R_true = rest_erring_like_the_odometry(Qu, R, Qt)
    z_r = rng.multivariate_normal(np.zeros(6), R_true, size=n, method="cholesky")
    fused = (C @ (np.linalg.solve(Qu, z_o.T) + np.linalg.solve(R, z_r.T))).T
    joint = np.zeros((12, 12))
    joint[6:, 6:] = C
    o = drift_observation(
        np.zeros(6), np.eye(6)[None], Q0[None], gtsam.Pose3(), joint, used
    )  # the basis and rest only; the discrepancies are drawn here
    W = np.linalg.inv(np.linalg.cholesky(Qu))
    empirical = np.cov(W @ (z_o - fused).T)
    model = o.rest + np.einsum("p,pab->ab", pair_coefficients(true, o.pairs), o.basis)
    np.testing.assert_allclose(
        empirical, model - SETTLING_VARIANCE * np.eye(6), atol=0.05 * np.max(model)
    )


def test_a_window_s_discrepancy_is_its_steps_carried_to_its_end():
    """To first order the composed discrepancy Log(U^-1 T_est); linear in the steps' own
    (so that a heading error does not bend it: the composed one grows beyond first order)."""
    rng = np.random.default_rng(6)
    steps = random_steps(30, rng)
    T = transports(np.array([step.inverse().AdjointMap() for step in steps]))

    def both(size):
        errors = rng.normal(0, size, (len(steps), 6))
        estimated = [u * gtsam.Pose3.Expmap(e) for u, e in zip(steps, errors, strict=True)]
        U, E = gtsam.Pose3(), gtsam.Pose3()
        for u, e in zip(steps, estimated, strict=True):
            U, E = U * u, E * e
        return window_discrepancy(T, steps, estimated), gtsam.Pose3.Logmap(U.between(E)), errors

    summed, composed, errors = both(1e-5)
    np.testing.assert_allclose(summed, composed, atol=1e-7)  # second order, lever arms ~30 m
    np.testing.assert_allclose(summed, np.einsum("kab,kb->a", T, errors), atol=1e-12)
    summed, composed, _ = both(0.02)  # a heading known to a degree a step
    assert np.abs(summed - composed).max() > 1e-3


def test_a_window_whose_estimate_follows_the_odometry_shows_no_discrepancy():
    rng = np.random.default_rng(8)
    windows = DriftWindows(4)
    steps = random_steps(4, rng)
    for step in steps:
        windows.add_step(step, 1e-4 * np.eye(6))
    poses = [gtsam.Pose3()]
    for step in steps:
        poses.append(poses[-1] * step)
    windows.open(4, [4])
    o = windows.observe(0, poses, random_covariance(12, rng, 0.005), np.ones(6))
    np.testing.assert_allclose(o.y, 0.0, atol=1e-9)


# --- the likelihood, its fit and its evidence --------------------------------------------


def fused_windows(Q0, R, used, true, n, rng, loop=True):
    """n window observations of an odometry Q0 at `true` scales, fused at `used` with the rest
    of the graph (stated R): the rest of a loop erring as the odometry does, or (`loop`
    False) landmarks that err as stated."""
    Qu, Qt = scaled_covariance(Q0, used), scaled_covariance(Q0, true)
    C = np.linalg.inv(np.linalg.inv(Qu) + np.linalg.inv(R))
    R_true = rest_erring_like_the_odometry(Qu, R, Qt) if loop else R
    joint = np.zeros((12, 12))
    joint[6:, 6:] = C
    out = []
    for _ in range(n):
        z_o = rng.multivariate_normal(np.zeros(6), Qt, method="cholesky")
        z_r = rng.multivariate_normal(np.zeros(6), R_true, method="cholesky")
        fused = C @ (np.linalg.solve(Qu, z_o) + np.linalg.solve(R, z_r))
        relative = gtsam.Pose3.Expmap(-(z_o - fused))  # U^-1 T, with U the identity
        out.append(
            drift_observation(
                gtsam.Pose3.Logmap(relative), np.eye(6)[None], Q0[None], relative, joint, used
            )
        )
    return out


def likelihood_of(observations, names=ODOMETRY_AXES):
    out = ScaleLikelihood(names, kept=10_000)
    for o in observations:
        out.add(o)
    return out


def window_case(seed, decided=1.0):
    """An odometry's stated covariance and the rest of the graph's: the landmarks decide part
    of each direction, more of it the smaller `decided`."""
    rng = np.random.default_rng(seed)
    Q0 = np.diag([1e-6, 1e-6, 1e-6, 1e-4, 1e-4, 1e-5])
    R = decided * np.diag([4e-6, 4e-6, 2e-5, 1e-4, 2e-4, 4e-5])
    return rng, Q0, R


# An overstated direction shows only where the landmarks decide more of it than the
# odometry's statement does: there the discrepancy is smaller than the statement allows.
@pytest.mark.parametrize(
    ("direction", "true", "decided"),
    [(YAW, 40.0, 1.0), (YAW, 0.1, 0.02), (LATERAL, 10.0, 1.0), (LATERAL, 0.25, 0.1)],
)
def test_one_direction_misstated_is_found_and_moved_alone(direction, true, decided):
    rng, Q0, R = window_case(7, decided)
    scales = np.ones(6)
    scales[direction] = true
    likelihood = likelihood_of(fused_windows(Q0, R, np.ones(6), scales, 300, rng))
    reading = likelihood.reading(np.ones(6), (0.01, 1e4), 3.0, 2.0, drop=2)
    assert reading.scales is not None
    moved = np.flatnonzero(reading.scales != 1.0)
    assert moved.tolist() == [direction]
    assert reading.scales[direction] == pytest.approx(true, rel=0.35)
    assert reading.evidence[direction] >= 3.0


def test_two_directions_misstated_move_one_a_reading_the_clearest_first():
    """Yaw 40 and lateral 10 times the statement: the first reading moves the direction with
    the most evidence beyond what it needs, the next one (the same windows, read at the first
    move's scales) the other."""
    rng, Q0, R = window_case(9)
    true = np.array([1, 1, 40.0, 1, 10.0, 1])
    likelihood = likelihood_of(fused_windows(Q0, R, np.ones(6), true, 300, rng))
    first = likelihood.reading(np.ones(6), (0.01, 1e4), 3.0, 2.0, drop=2)
    assert first.evidence[YAW] >= 3.0 and first.evidence[LATERAL] >= 3.0  # both could move
    clearest = int(np.argmax(first.evidence))
    other = LATERAL if clearest == YAW else YAW
    assert np.flatnonzero(first.scales != 1.0).tolist() == [clearest]
    second = likelihood.reading(first.scales, (0.01, 1e4), 3.0, 2.0, drop=2)
    assert np.flatnonzero(second.scales != first.scales).tolist() == [other]
    np.testing.assert_allclose(second.scales[[YAW, LATERAL]], [40.0, 10.0], rtol=0.35)


@pytest.mark.parametrize("true", [40.0, 0.1])
def test_where_landmarks_decide_the_rest_the_scale_read_lies_toward_the_statement(true):
    """The model takes the rest of a window's graph to err as the odometry does (a loop's other
    windows). Where it is landmarks that err as stated, the scale read lies between the
    statement and the truth (a move never overshoots), at the truth where the landmarks
    decide nearly all of the window."""
    scales = np.ones(6)
    scales[YAW] = true
    read = {}
    for decided in (1.0, 0.001):
        rng, Q0, R = window_case(11, decided)
        windows = fused_windows(Q0, R, np.ones(6), scales, 300, rng, loop=False)
        read[decided] = likelihood_of(windows).reading(np.ones(6), (0.01, 1e4), 3.0, 2.0, 2).fit
    low, high = sorted([1.0, true])
    assert low / 1.2 <= read[1.0][YAW] <= high * 1.2
    assert abs(np.log(read[1.0][YAW] / true)) > 0.5  # half decided: well short of the truth
    assert read[0.001][YAW] == pytest.approx(true, rel=0.35)


def test_a_move_down_takes_twice_the_evidence_of_a_move_up():
    """A noise learnt too small turns true pairings away: down needs DOWN_EVIDENCE times the
    evidence up does."""
    rng, Q0, R = window_case(31, decided=0.02)
    true = np.ones(6)
    true[YAW] = 0.1
    likelihood = likelihood_of(fused_windows(Q0, R, np.ones(6), true, 40, rng))
    evidence = likelihood.reading(np.ones(6), (0.01, 1e4), 0.0, 1.5, drop=2).evidence[YAW]
    assert evidence > 1.0
    held = likelihood.reading(np.ones(6), (0.01, 1e4), evidence / 1.5, 1.5, drop=2)
    assert held.scales is None or held.scales[YAW] == 1.0
    moved = likelihood.reading(np.ones(6), (0.01, 1e4), evidence / 2.5, 1.5, drop=2)
    assert moved.scales[YAW] < 0.5


def test_windows_of_an_odometry_stated_right_move_nothing():
    rng, Q0, R = window_case(8)
    likelihood = likelihood_of(fused_windows(Q0, R, np.ones(6), np.ones(6), 300, rng))
    reading = likelihood.reading(np.ones(6), (0.01, 1e4), 3.0, 2.0, drop=2)
    assert reading.scales is None
    assert np.all(reading.evidence < 3.0)


def test_windows_taken_under_different_scales_are_read_together():
    """Half the windows taken with the odometry stated as it is, half after a move to 10 in
    yaw: all say the truth, 40."""
    rng, Q0, R = window_case(9)
    true = np.array([1, 1, 40.0, 1, 1, 1])
    moved = np.array([1, 1, 10.0, 1, 1, 1])
    windows = fused_windows(Q0, R, np.ones(6), true, 150, rng)
    windows += fused_windows(Q0, R, moved, true, 150, rng)
    reading = likelihood_of(windows).reading(moved, (0.01, 1e4), 3.0, 2.0, drop=2)
    assert reading.scales[YAW] == pytest.approx(40.0, rel=0.35)


@pytest.mark.parametrize(("drop", "moves"), [(0, True), (2, False)])
def test_no_two_windows_alone_move_a_scale(drop, moves):
    """Windows of an odometry stated right, and two bent in yaw far beyond it (a wrong
    association each): without `drop` they move the yaw's scale, with it nothing."""
    rng, Q0, R = window_case(10)
    right = fused_windows(Q0, R, np.ones(6), np.ones(6), 30, rng)
    bent = fused_windows(Q0, R, np.ones(6), np.array([1, 1, 500.0, 1, 1, 1]), 2, rng)
    reading = likelihood_of(right + bent).reading(np.ones(6), (0.01, 1e4), 3.0, 2.0, drop=drop)
    assert (reading.scales is not None) == moves


def test_the_fit_reaches_a_scale_the_outliers_hid_from_the_current_one():
    """Windows whose landmarks decide little, but some a lot (loop closures): at the stated
    scale those are outliers to the model, so the likelihood is flat near it; the scan still
    finds the true scale far above."""
    rng, Q0, _ = window_case(11)
    true = np.array([1, 1, 300.0, 1, 1, 1])
    weak = fused_windows(Q0, 100.0 * Q0, np.ones(6), true, 40, rng)
    loops = fused_windows(Q0, 0.01 * Q0, np.ones(6), true, 6, rng)
    reading = likelihood_of(weak + loops).reading(np.ones(6), (0.01, 1e4), 3.0, 2.0, drop=2)
    assert reading.scales is not None
    assert reading.scales[YAW] == pytest.approx(300.0, rel=0.5)


def test_the_mixture_and_prior_by_hand():
    """One observation y = 3 of variance rest 1 + s b (b = 2): its mixture density and the
    prior on log s, as the likelihood gives them."""
    o = ScaleObservation.made(
        np.array([3.0]), np.eye(1), 2.0 * np.ones((1, 1, 1)), np.array([[0, 0]]), np.ones(1)
    )
    likelihood = likelihood_of([o], names=("only",))

    def density(v):
        return np.exp(-0.5 * 9.0 / v) / np.sqrt(2 * np.pi * v)

    for s in (1.0, 4.0):
        mixed = (1 - OUTLIER_SHARE) * density(1 + 2 * s) + OUTLIER_SHARE * density(
            1 + 2 * OUTLIER_SCALE
        )
        theta = np.log([s])
        expected = np.log(mixed) - 0.5 * (theta[0] / PRIOR_LOG_SIGMA) ** 2
        assert likelihood.log_posterior(theta[None])[0] == pytest.approx(expected)


def test_nuisance_directions_are_fitted_but_never_moved():
    rng, Q0, R = window_case(12)
    true = np.array([1, 1, 40.0, 1, 1, 1])
    likelihood = likelihood_of(fused_windows(Q0, R, np.ones(6), true, 300, rng))
    tested = np.zeros(6, bool)
    tested[LATERAL] = True
    reading = likelihood.reading(np.ones(6), (0.01, 1e4), 3.0, 2.0, drop=2, tested=tested)
    assert reading.scales is None  # lateral is right; yaw, a nuisance here, reported as fit
    assert reading.fit[YAW] == pytest.approx(40.0, rel=0.35)


# --- drift windows ------------------------------------------------------------------------


def test_windows_are_due_every_their_own_length_once_their_steps_are_known():
    drift = DriftWindows(length=2, long_length=6)
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
    alone = DriftWindows(length=2)
    for _ in range(6):
        alone.add_step(step, np.eye(6))
    assert alone.due(6, 2) == [2]


def test_only_the_latest_windows_are_kept_and_the_steps_they_read():
    rng = np.random.default_rng(21)
    steps = random_steps(10, rng)
    drift = DriftWindows(length=2, kept=3)
    for step in steps:
        drift.add_step(step, 1e-4 * np.eye(6))
    for end in (2, 4, 6, 8, 10):
        drift.open(end, [2])
    assert list(drift.windows) == [(4, 6), (6, 8), (8, 10)]
    # the window from keyframe 4 reads steps 4 and 5 (the earlier ones let go)
    poses = [gtsam.Pose3(), steps[4], steps[4] * steps[5]]
    np.testing.assert_allclose(
        drift.observe(4, poses, np.zeros((12, 12)), np.ones(6)).y, 0.0, atol=1e-9
    )
    shifted = [gtsam.Pose3(), steps[3], steps[3] * steps[4]]
    assert np.abs(drift.observe(4, shifted, np.zeros((12, 12)), np.ones(6)).y).max() > 1.0


class LoopClosingEstimate:
    """An estimate that follows the odometry (and knows nothing more of it) until `closed`,
    then knows the true path exactly: a loop closed after the windows ended."""

    def __init__(self, odometry, truth, stated):
        self.odometry, self.truth, self.stated = odometry, truth, stated
        self.closed = False

    def pose(self, key):
        return (self.truth if self.closed else self.odometry)[gtsam.Symbol(key).index()]

    def joint_covariance(self, keys):
        """Closed: nothing left to know. Else the odometry's chain from the first key (known):
        each pose's error carried along the steps, e_b = Ad(T_ab^-1) e_a + the steps' noise
        carried to b, so that any two keys' relative pose has the odometry's own covariance."""
        indices = [gtsam.Symbol(k).index() for k in keys]
        n = len(indices)
        joint = np.zeros((6 * n, 6 * n))
        if self.closed:
            return joint
        joint[:6, :6] = 1e-12 * np.eye(6)
        for j in range(1, n):
            a, b = indices[j - 1], indices[j]
            steps = [self.odometry[k].between(self.odometry[k + 1]) for k in range(a, b)]
            T = transports(np.array([step.inverse().AdjointMap() for step in steps]))
            carried = np.einsum("kab,bc,kdc->ad", T, self.stated, T)
            A = self.odometry[a].between(self.odometry[b]).inverse().AdjointMap()
            before = slice(0, 6 * j)
            joint[before, 6 * j : 6 * j + 6] = joint[before, 6 * (j - 1) : 6 * j] @ A.T
            joint[6 * j : 6 * j + 6, before] = joint[before, 6 * j : 6 * j + 6].T
            previous = joint[6 * (j - 1) : 6 * j, 6 * (j - 1) : 6 * j]
            joint[6 * j : 6 * j + 6, 6 * j : 6 * j + 6] = A @ previous @ A.T + carried
        return joint


def test_windows_are_read_again_when_a_loop_closes_after_they_ended():
    """Eight windows end while the estimate follows the odometry: nothing to learn. A loop then
    closes (the estimate knows the true path): the same windows, read again, teach the yaw.
    After the move they are read again, at the new scales: the yaw stays where the loop put
    it (a window read at the truth says the same under any scales in use)."""
    rng = np.random.default_rng(22)
    stated = np.diag([1e-6, 1e-6, 1e-6, 1e-4, 1e-4, 1e-4])
    truth_steps = [
        gtsam.Pose3(gtsam.Rot3.Yaw(rng.normal(0, 0.1)), rng.normal([1.0, 0, 0], [0.2, 0.2, 0.01]))
        for _ in range(100)
    ]
    noisy = [
        step
        * gtsam.Pose3.Expmap(
            rng.multivariate_normal(np.zeros(6), scaled_covariance(stated, [1, 1, 100, 1, 1, 1]))
        )
        for step in truth_steps
    ]

    def path(steps):
        poses = [gtsam.Pose3()]
        for step in steps:
            poses.append(poses[-1] * step)
        return poses

    estimate = LoopClosingEstimate(path(noisy), path(truth_steps), stated)
    config = replace(
        load_config().noise,
        update_every=10,
        drift_window=10,
        long_drift_window=0,
        min_drift_windows=3,
    )
    learner = NoiseLearner(config, enabled=True)
    for k, step in enumerate(noisy, start=1):
        learner.add_step(step, stated)
        estimate.closed = k >= 80
        change = learner.learn(k, estimate, lambda poses: [])
        assert bool(change.odometry) == (k == 80), k
        if k == 80:
            as_read = [o.y for o in learner.windows.observations]
            assert np.abs(as_read[0]).max() > 1.0  # the first window, read again
    # ten windows, the eight of the move read again under the new scales: whitened by them,
    # the same discrepancies read smaller in the yaw
    kept = learner.windows.observations
    assert len(learner.drift.windows) == len(kept) == 10
    again = np.array([o.y for o in kept[:8]])
    assert np.abs(again[:, YAW]).sum() < 0.2 * np.abs(np.array(as_read)[:, YAW]).sum()
    assert learner.moves[0].after[YAW] == pytest.approx(100.0, rel=0.6)
    assert [s for i, s in enumerate(learner.moves[0].after) if i != YAW] == [1.0] * 5


@pytest.mark.parametrize("true_yaw", [1.0, 50.0])
def test_windows_of_noisy_steps_against_the_true_path_find_the_yaw_scale(true_yaw):
    """Steps drawn with yaw true_yaw times the stated variance, the estimate knowing the
    true relative pose (the landmarks pin it: C = 0): the yaw's scale comes back, the others
    stay."""
    rng = np.random.default_rng(13)
    stated = np.diag([1e-6, 1e-6, 4e-6, 1e-4, 1e-4, 1e-5])
    true = np.array([1, 1, true_yaw, 1, 1, 1])
    drift = DriftWindows(length=20)
    likelihood = ScaleLikelihood(ODOMETRY_AXES, kept=1000)
    for window in range(200):
        truth = random_steps(20, rng)
        for step in truth:
            noise = rng.multivariate_normal(np.zeros(6), scaled_covariance(stated, true))
            drift.add_step(step * gtsam.Pose3.Expmap(noise), stated)
        poses = [gtsam.Pose3()]
        for step in truth:
            poses.append(poses[-1] * step)
        drift.open(20 * (window + 1), [20])
        likelihood.add(drift.observe(20 * window, poses, np.zeros((12, 12)), np.ones(6)))
    reading = likelihood.reading(np.ones(6), (0.01, 1e4), 3.0, 2.0, drop=2)
    if true_yaw == 1.0:
        assert reading.scales is None
    else:
        assert np.flatnonzero(reading.scales != 1.0).tolist() == [YAW]
        assert reading.scales[YAW] == pytest.approx(true_yaw, rel=0.3)


# --- contrasts ----------------------------------------------------------------------------


def keyframe_scene(K, rng):
    """A pose and K landmarks 5-30 m ahead of it, each detection's stated covariance."""
    rotation = gtsam.Rot3.RzRyRx(*rng.normal(0, 0.2, 3)).matrix()
    translation = rng.normal(0, 1.0, 3)
    body = np.column_stack([rng.uniform(5, 30, K), rng.uniform(-10, 10, K), rng.uniform(-2, 2, K)])
    landmarks = body @ rotation.T + translation
    stated = np.stack([np.diag([1e-4, 4e-4, 1e-2]) for _ in range(K)])
    return rotation, translation, landmarks, stated


def test_a_contrast_does_not_see_the_pose_s_error_along_its_free_directions():
    """Detections exactly where the landmarks are: moving the pose along a free direction
    changes the observation to second order only; along a pinned one (a planar log's height)
    to first order. (N is defined up to a rotation: its length is what is compared.)"""
    rng = np.random.default_rng(21)
    rotation, translation, landmarks, stated = keyframe_scene(4, rng)
    measured = predict_point_batch(rotation, translation, landmarks)
    planar = np.array([False, False, True, True, True, False])  # yaw, x, y free

    def length(axis, eps, free):
        delta = np.zeros(6)
        delta[axis] = eps
        moved = gtsam.Pose3(gtsam.Rot3(rotation), translation).retract(delta)
        o = contrast_observation(
            moved.rotation().matrix(),
            moved.translation(),
            landmarks,
            measured,
            stated,
            np.full(4, 5),
            np.array([2.0, 1.0, 0.5]),
            free,
        )
        return np.linalg.norm(o.y)

    for axis in range(6):  # ten times smaller a move, a hundred times smaller a change
        big, small = length(axis, 1e-3, None), length(axis, 1e-4, None)
        assert big < 1e-12 or big / small == pytest.approx(100, rel=0.1)  # yaw: none at all
    assert length(5, 1e-3, planar) / length(5, 1e-4, planar) == pytest.approx(10, rel=0.1)
    assert (
        contrast_observation(
            rotation,
            translation,
            landmarks[:2],
            measured[:2],
            stated[:2],
            np.full(2, 5),
            np.ones(3),
        )
        is None
    )  # two detections: nothing is left once six pose directions are out


def test_a_contrast_s_covariance_is_the_residuals_with_the_landmarks_share_taken_out():
    """The observation's covariance at scales s, by hand: N^T W (blockdiag of (1 - 1/n_k)
    Gamma_k(s)) W^T N with N the complement of the whitened pose Jacobian."""
    rng = np.random.default_rng(22)
    K = 4
    rotation, translation, landmarks, stated = keyframe_scene(K, rng)
    measured = predict_point_batch(rotation, translation, landmarks)
    used = np.array([2.0, 1.0, 0.5])
    sightings = np.array([2, 3, 10, 1])
    o = contrast_observation(rotation, translation, landmarks, measured, stated, sightings, used)
    _, H_x, _ = predict_point_jacobians_batch(rotation, translation, landmarks)
    root = np.sqrt(used)
    W = np.zeros((3 * K, 3 * K))
    H = np.zeros((3 * K, 6))
    for k in range(K):
        w = np.linalg.inv(np.linalg.cholesky(stated[k] * np.outer(root, root)))
        W[3 * k : 3 * k + 3, 3 * k : 3 * k + 3] = w
        H[3 * k : 3 * k + 3] = w @ H_x[k]
    U, _, _ = np.linalg.svd(H)
    N = U[:, 6:]
    s = np.array([3.0, 0.5, 7.0])
    G = np.zeros((3 * K, 3 * K))
    for k in range(K):
        G[3 * k : 3 * k + 3, 3 * k : 3 * k + 3] = (1 - 1 / sightings[k]) * scaled_covariance(
            stated[k], s
        )
    expected = N.T @ W @ G @ W.T @ N  # N is defined up to a rotation: compare invariants
    got = o.rest + np.einsum("p,pab->ab", pair_coefficients(s, o.pairs), o.basis)
    np.testing.assert_allclose(np.linalg.eigvalsh(got), np.linalg.eigvalsh(expected), atol=1e-8)
    assert o.y.shape == (3 * K - 6,)


@pytest.mark.parametrize(("true", "moved"), [((6.0, 1, 1), 0), ((1, 1, 0.1), 2), ((1, 1, 1), None)])
def test_contrasts_find_a_misstated_component_whatever_the_pose_s_error(true, moved):
    """Keyframes of five detections with noise `true` times the stated variances, seen from a
    pose whose error (twice the detections' in angle) the contrasts must not take for their noise;
    landmarks known from many sightings: the misstated component comes back, the others stay."""
    rng = np.random.default_rng(23)
    true = np.array(true, dtype=float)
    likelihood = ScaleLikelihood(("bearing", "elevation", "range"), kept=300)
    for _ in range(300):
        rotation, translation, landmarks, stated = keyframe_scene(5, rng)
        z = predict_point_batch(rotation, translation, landmarks)
        noise = np.stack(
            [rng.multivariate_normal(np.zeros(3), scaled_covariance(g, true)) for g in stated]
        )
        wrong = gtsam.Pose3(gtsam.Rot3(rotation), translation).retract(
            rng.normal(0, 1.0, 6) * [0.02, 0.02, 0.02, 0.1, 0.1, 0.1]
        )
        o = contrast_observation(
            wrong.rotation().matrix(),
            wrong.translation(),
            landmarks,
            z + noise,
            stated,
            np.full(5, 1000),
            np.ones(3),
        )
        likelihood.add(o)
    reading = likelihood.reading(np.ones(3), (0.01, 1e4), 3.0, 1.5, drop=2)
    if moved is None:
        assert reading.scales is None or np.allclose(reading.scales, 1.0)
        return
    assert true[moved] / 1.5 < reading.scales[moved] < true[moved] * 1.5
    others = np.arange(3) != moved
    np.testing.assert_allclose(reading.scales[others], 1.0)


# --- loops ---------------------------------------------------------------------------------


def test_drift_belief_takes_each_loop_s_likelihood_and_restarts_from_its_prior():
    belief = DriftScaleBelief(weight=0.5, max_scale=100.0, steps=2)
    np.testing.assert_allclose(belief.scales, [1.0, 10.0, 100.0])
    np.testing.assert_allclose(np.exp(belief.log_weights), [0.5, 0.25, 0.25])
    belief.observe(np.log([1.0, 4.0, 1.0]))  # a loop four times likelier at 10
    np.testing.assert_allclose(np.exp(belief.log_weights), np.array([0.5, 1.0, 0.25]) / 1.75)
    assert belief.loops == 1 and belief.report()["loops"] == 1
    belief.restart()
    np.testing.assert_allclose(np.exp(belief.log_weights), [0.5, 0.25, 0.25])
    assert belief.loops == 0
    assert DriftScaleBelief(weight=0.0, max_scale=100.0, steps=2).scales.tolist() == [1.0]
