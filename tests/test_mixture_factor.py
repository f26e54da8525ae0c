"""The CustomFactor max-mixture: its cost is the winner's negative log-likelihood, its
Jacobians are right, and it switches component as the estimate moves."""

import math

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import L, X

from pipeline.backend.methods.maxmixture.mixture_factor import MaxMixtureFactor, component
from pipeline.backend.mixture import gaussian_log_normaliser, null_component_nll
from tests.numerics import numerical_jacobian

COVARIANCE = np.diag([1e-4, 1e-4, 1e-2])


def bearing_range(landmark: int) -> gtsam.BearingRangeFactor3D:
    noise = gtsam.noiseModel.Gaussian.Covariance(COVARIANCE)
    return gtsam.BearingRangeFactor3D(
        X(0), L(landmark), gtsam.Unit3(np.array([1.0, 0, 0])), 5.0, noise
    )


def values(first: np.ndarray, second: np.ndarray, pose: gtsam.Pose3 | None = None):
    v = gtsam.Values()
    v.insert(X(0), pose or gtsam.Pose3())
    v.insert(L(0), first)
    v.insert(L(1), second)
    return v


@pytest.fixture
def mixture() -> MaxMixtureFactor:
    parts = [component(bearing_range(0), 0.6), component(bearing_range(1), 0.3)]
    return MaxMixtureFactor(X(0), parts, dim=3, null_nll=null_component_nll(0.1, 1e5, 3))


def test_half_squared_error_is_the_winners_nll_less_the_smallest_constant(mixture):
    v = values(np.array([5.0, 0.05, 0.0]), np.array([5.2, -0.3, 0.0]))
    costs = mixture.nll(v)
    factor = mixture.factor()
    assert mixture.winner == -1  # not evaluated yet
    constants = [-math.log(0.6) + gaussian_log_normaliser(COVARIANCE),
                 -math.log(0.3) + gaussian_log_normaliser(COVARIANCE),
                 null_component_nll(0.1, 1e5, 3)]  # fmt: skip
    np.testing.assert_allclose(costs[2], constants[2])
    assert factor.error(v) == pytest.approx(costs.min() - min(constants))
    assert mixture.winner == int(np.argmin(costs))


def test_switches_component_as_the_landmark_estimates_move(mixture):
    factor = mixture.factor()
    factor.error(values(np.array([5.0, 0.0, 0.0]), np.array([5.0, 2.0, 0.0])))
    assert mixture.winner == 0
    factor.error(values(np.array([5.0, 2.0, 0.0]), np.array([5.0, 0.0, 0.0])))
    assert mixture.winner == 1
    factor.error(values(np.array([5.0, 3.0, 0.0]), np.array([5.0, -3.0, 0.0])))
    assert mixture.winner == -1  # both far: the null hypothesis


def test_jacobians_match_numerical_differentiation(mixture):
    pose = gtsam.Pose3(gtsam.Rot3.Rz(0.02), np.array([0.1, -0.05, 0.0]))
    v = values(np.array([5.0, 0.1, 0.05]), np.array([5.5, 1.0, 0.0]), pose)
    factor = mixture.factor()
    A, _ = factor.linearize(v).jacobian()

    def retract(estimate: gtsam.Values, d: np.ndarray) -> gtsam.Values:
        delta = gtsam.VectorValues()
        for key, block in ((X(0), d[:6]), (L(0), d[6:9]), (L(1), d[9:])):
            delta.insert(key, block)
        return estimate.retract(delta)

    numerical = numerical_jacobian(factor.unwhitenedError, v, retract, dim=12)
    # GTSAM's bearing Jacobian leaves out how its Unit3 error basis turns with the prediction:
    # agreement to 1e-4 of the largest entry
    np.testing.assert_allclose(A, numerical, atol=1e-4 * np.abs(A).max())
    assert mixture.winner == 0
