"""The first choice of a detection's component, the null's density, and the measurement space:
pure functions against hand-computed values."""

import math

import numpy as np
import pytest

from pipeline.backend.association import LOG_2PI
from pipeline.backend.decisions import (
    NULL,
    MeasurementSpace,
    clutter_log_density,
    first_component,
    in_view,
    loop_pairs_needed,
    null_cost,
    relative_null_nll,
)
from pipeline.backend.mixture import gaussian_log_normaliser, null_component_nll


def test_relative_null_crosses_a_full_weight_component_at_the_crossover():
    gamma = np.diag([0.01**2, 0.02**2, 0.5**2])
    lognorm = gaussian_log_normaliser(gamma)
    null = relative_null_nll(0.1, lognorm, 60.0)
    # a component holding all the candidates' weight (0.9) at d^2 = 60 costs exactly the null
    assert null == pytest.approx(-math.log(0.9) + lognorm + 30.0)
    # the same in other units: the crossover does not move with the covariance's scale
    scaled = gaussian_log_normaliser(gamma * 1e4)
    assert relative_null_nll(0.1, scaled, 60.0) - scaled == pytest.approx(null - lognorm)


def test_null_cost_models():
    lognorm = gaussian_log_normaliser(np.eye(3) * 1e-4)
    assert null_cost("literal", 0.1, 1e5, 60.0, 3, lognorm) == null_component_nll(0.1, 1e5, 3)
    assert null_cost("relative", 0.1, 1e5, 60.0, 3, lognorm) == relative_null_nll(
        0.1, lognorm, 60.0
    )


def test_first_component_picks_the_cheapest_or_the_null():
    lognorm = 0.0
    weights = np.array([0.6, 0.3])
    # costs: -log 0.6 + 0.5 * 4 = 2.51; -log 0.3 + 0.5 * 1 = 1.70: the second wins
    assert first_component(weights, np.array([4.0, 1.0]), lognorm, math.inf) == 1
    # a null cheaper than both wins
    assert first_component(weights, np.array([4.0, 1.0]), lognorm, 1.6) == NULL
    assert first_component(weights, np.array([4.0, 1.0]), lognorm, 1.8) == 1


def test_measurement_space_box_volume_and_floors():
    space = MeasurementSpace()
    cov = np.diag([0.01**2, 0.01**2, 0.1**2])
    for v in ([0.5, 0.0, 5.0], [-0.5, 0.0, 15.0], [0.1, 0.0, 10.0]):
        space.observe(np.array(v), cov)
    low, high = space.box()
    floor = math.sqrt(12.0) * 0.01  # every elevation was 0: a side of sqrt(12) sigma
    np.testing.assert_allclose(high - low, [1.0, floor, 10.0])
    assert space.log_volume() == pytest.approx(math.log(1.0 * floor * 10.0))
    # the volume swept: (15^3 - 5^3) / 3 * 1 rad * (sin(f/2) - sin(-f/2))
    swept = (15**3 - 5**3) / 3 * 1.0 * 2 * math.sin(floor / 2)
    assert space.log_world_volume() == pytest.approx(math.log(swept))


def test_landmarks_in_view_are_those_measured_inside_the_box():
    space = MeasurementSpace()
    cov = np.diag([0.01**2, 0.01**2, 0.1**2])
    for v in ([0.5, 0.2, 5.0], [-0.5, -0.2, 15.0]):  # bearing +-0.5, elevation +-0.2, 5..15 m
        space.observe(np.array(v), cov)
    inside = space.contains(np.array([[0.0, 0.0, 10.0], [0.6, 0.0, 10.0], [0.0, 0.0, 16.0]]))
    assert inside.tolist() == [True, False, False]
    # a sensor at (1, 0, 0) looking along +y (yaw 90 degrees)
    rotation = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    points = np.array(
        [
            [1.0, 10.0, 0.0],  # straight ahead, 10 m
            [11.0, 1.0, 0.0],  # to its right, bearing -1.47
            [1.0, -10.0, 0.0],  # behind it
            [1.0, 10.0, 5.0],  # ahead but 26.6 degrees up
            [-2.0, 8.0, 0.0],  # ahead, bearing atan(3 / 8) = 0.36
        ]
    )
    assert in_view(rotation, np.array([1.0, 0.0, 0.0]), points, space) == 2
    assert in_view(rotation, np.zeros(3), np.zeros((0, 3)), space) == 0


def test_clutter_density_is_the_null_prior_spread_over_the_space():
    assert clutter_log_density(0.1, 0.5, math.log(20.0)) == pytest.approx(math.log(0.1 * 0.5 / 20))


def test_measurement_space_needs_a_detection():
    with pytest.raises(ValueError):
        MeasurementSpace().box()


def test_gaussian_peak_over_clutter_hand_computed():
    # sanity of the units the joint association compares: N(0; Gamma) against 1 / volume
    gamma = np.diag([0.02**2, 0.02**2, 0.2**2])
    peak = -gaussian_log_normaliser(gamma)
    assert peak == pytest.approx(-0.5 * (3 * LOG_2PI + math.log(np.linalg.det(gamma))))


def test_a_loop_resting_on_the_pattern_needs_more_pairs():
    assert loop_pairs_needed([0.96, 0.8], alone=2, crowded=3) == 2
    assert loop_pairs_needed([0.96, 0.1], alone=2, crowded=3) == 3
    # the favourite of three, yet outweighed by the other two together
    assert loop_pairs_needed([0.96, 0.45], alone=2, crowded=3) == 3
    assert loop_pairs_needed([0.5, 0.5], alone=2, crowded=3) == 2
    assert loop_pairs_needed([], alone=2, crowded=3) == 2
