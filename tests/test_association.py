"""Association weights, gate and class posterior against hand-computed values."""

import math

import numpy as np
import pytest

from pipeline.backend import association as assoc
from pipeline.backend import mixture


def test_chi_square_gate_matches_tables():
    # chi-square quantiles at 0.9: 3 dof 6.2514, 6 dof 10.6446 (standard tables)
    assert assoc.chi2_gate(3, 0.9) == pytest.approx(6.2514, abs=1e-4)
    assert assoc.chi2_gate(6, 0.9) == pytest.approx(10.6446, abs=1e-4)
    assert assoc.chi2_gate(3, 0.99) == pytest.approx(11.3449, abs=1e-4)


def test_innovation_covariance_is_h_sigma_ht_plus_gamma():
    H = np.array([[1.0, 2.0], [0.0, 1.0]])
    Sigma = np.array([[1.0, 0.5], [0.5, 2.0]])
    Gamma = np.eye(2) * 0.1
    # H Sigma H^T = [[1+2+2+8, 0.5+4], [4.5, 2]] = [[11, 4.5], [4.5, 2]]
    np.testing.assert_allclose(
        assoc.innovation_covariance(H, Sigma, Gamma), [[11.1, 4.5], [4.5, 2.1]]
    )


def test_mahalanobis_and_log_density_hand_computed():
    R = np.diag([0.01, 0.04, 1.0])
    r = np.array([0.1, 0.4, 1.0])
    assert assoc.mahalanobis_squared(r, R) == pytest.approx(1.0 + 4.0 + 1.0)
    expected = -0.5 * (6.0 + math.log(0.01 * 0.04 * 1.0) + 3 * math.log(2 * math.pi))
    assert assoc.gaussian_log_density(r, R) == pytest.approx(expected)


def test_semantic_likelihood_sums_over_the_landmark_class_posterior():
    confusion = np.array([[0.8, 0.2], [0.3, 0.7]])  # row true, column reported
    # reported 1 from a landmark that is class 0 with 0.25, class 1 with 0.75
    assert assoc.semantic_likelihood(confusion, 1, np.array([0.25, 0.75])) == pytest.approx(
        0.25 * 0.2 + 0.75 * 0.7
    )


def test_weights_of_two_landmarks_hand_computed():
    # Same R for both: the normalisers cancel. Mahalanobis 1 and 4, semantic 0.9 and 0.1:
    # w1 = 0.9 e^-0.5 / (0.9 e^-0.5 + 0.1 e^-2) = 0.545877 / 0.559411 = 0.975807
    R = np.eye(3) * 0.01
    log_geo = [
        assoc.gaussian_log_density(np.array([0.1, 0.0, 0.0]), R),
        assoc.gaussian_log_density(np.array([0.2, 0.0, 0.0]), R),
    ]
    w = assoc.association_weights(np.array(log_geo), np.array([0.9, 0.1]))
    np.testing.assert_allclose(w, [0.975807, 0.024193], atol=1e-6)


def test_weights_survive_far_candidates_without_underflow():
    w = assoc.association_weights(np.array([-2000.0, -2001.0]), np.array([0.5, 0.5]))
    np.testing.assert_allclose(w, [1 / (1 + math.exp(-1)), 1 - 1 / (1 + math.exp(-1))])


def test_a_class_the_detector_never_reports_gets_zero_weight():
    w = assoc.association_weights(np.array([-1.0, -1.0]), np.array([1.0, 0.0]))
    np.testing.assert_allclose(w, [1.0, 0.0])
    assert not np.any(assoc.association_weights(np.array([-1.0]), np.array([0.0])))


def test_null_hypothesis_takes_its_weight_from_the_others():
    weights, null = assoc.with_null_hypothesis(np.array([0.75, 0.25]), 0.1)
    np.testing.assert_allclose(weights, [0.675, 0.225])
    assert null == pytest.approx(0.1, rel=1e-15)  # 1 - 0.9, or as given: round-off at most
    assert weights.sum() + null == pytest.approx(1.0)


def test_class_posterior_sure_association_is_bayes_rule():
    confusion = np.array([[0.9, 0.1], [0.2, 0.8]])
    prior = np.array([0.5, 0.5])
    post = assoc.class_posterior_update(prior, confusion[:, 0], weight=1.0, other_mass=0.0)
    # P(c=0 | reported 0) = 0.9 / (0.9 + 0.2)
    np.testing.assert_allclose(post, [0.9 / 1.1, 0.2 / 1.1])
    post2 = assoc.class_posterior_update(post, confusion[:, 0], 1.0, 0.0)
    np.testing.assert_allclose(post2, [0.81 / 0.85, 0.04 / 0.85])


def test_class_posterior_uncertain_association_moves_less():
    confusion = np.array([[0.9, 0.1], [0.2, 0.8]])
    prior = np.array([0.5, 0.5])
    # weight 0.5, the other hypotheses explain the report with likelihood mass 0.25:
    # evidence = 0.5 * [0.9, 0.2] + 0.25 = [0.7, 0.35] -> [2/3, 1/3]
    post = assoc.class_posterior_update(prior, confusion[:, 0], 0.5, 0.25)
    np.testing.assert_allclose(post, [2 / 3, 1 / 3])
    sure = assoc.class_posterior_update(prior, confusion[:, 0], 1.0, 0.0)
    assert 0.5 < post[0] < sure[0]


def test_component_nll_includes_the_normaliser():
    cov = np.diag([0.01, 0.01, 0.25])
    norm = mixture.gaussian_log_normaliser(cov)
    assert norm == pytest.approx(0.5 * (math.log(0.01 * 0.01 * 0.25) + 3 * math.log(2 * math.pi)))
    assert mixture.component_nll(math.log(0.5), 4.0, norm) == pytest.approx(
        -math.log(0.5) + norm + 2.0
    )


def test_null_component_nll_hand_computed():
    # -log 0.1 + 1.5 * (log 2 pi + 2 log 1e5) = 2.302585 + 1.5 * (1.837877 + 23.025851)
    assert mixture.null_component_nll(0.1, 1e5, 3) == pytest.approx(39.598177, abs=1e-5)


def test_null_beats_a_component_only_far_out():
    cov = np.diag([0.01**2, 0.01**2, 0.1**2])
    norm = mixture.gaussian_log_normaliser(cov)
    null = mixture.null_component_nll(0.1, 1e5, 3)
    near = mixture.component_nll(math.log(0.9), 3.0**2, norm)  # 3 sigma
    far = mixture.component_nll(math.log(0.9), 12.0**2, norm)  # 12 sigma
    assert near < null < far


def test_em_weights_on_padded_rows():
    w = mixture.em_weights(np.log([[0.5, 0.5, 1e-300]]), np.array([[0.0, math.log(3.0), -np.inf]]))
    np.testing.assert_allclose(w, [[0.25, 0.75, 0.0]])


def test_batched_mahalanobis_and_density_match_one_by_one():
    rng = np.random.default_rng(2)
    residuals = rng.normal(size=(5, 3))
    factors = rng.normal(size=(5, 3, 3))
    covariances = factors @ np.swapaxes(factors, 1, 2) + 0.1 * np.eye(3)
    for k in range(5):
        assert assoc.mahalanobis_squared_batch(residuals, covariances)[k] == pytest.approx(
            assoc.mahalanobis_squared(residuals[k], covariances[k])
        )
        assert assoc.gaussian_log_density_batch(residuals, covariances)[k] == pytest.approx(
            assoc.gaussian_log_density(residuals[k], covariances[k])
        )
