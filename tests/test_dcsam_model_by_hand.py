"""DC-SAM's mode costs and class posterior (`methods/dcsam/model.py`) worked out by hand: a
candidate's cost takes its share 1 - w_new of the non-null mass, and a landmark whose every
class the reports rule out has a uniform posterior."""

import math

import numpy as np
import pytest

from pipeline.backend.methods.dcsam.model import class_posterior, mode_constants


@pytest.mark.parametrize(("null_weight", "new_weight"), [(0.1, 0.2), (0.3, 0.05)])
def test_each_mode_s_cost_by_hand(null_weight, new_weight):
    geometric = np.array([0.7, 0.3])
    costs = mode_constants(geometric, null_weight, new_weight, 1.5, 4.0, 9.0)
    share = 1.0 - null_weight
    expected = [
        -math.log(share * (1.0 - new_weight) * 0.7) + 1.5,
        -math.log(share * (1.0 - new_weight) * 0.3) + 1.5,
        -math.log(share * new_weight) + 4.0,
        9.0,
    ]
    np.testing.assert_allclose(costs, expected, rtol=1e-12)


@pytest.mark.parametrize("classes", [2, 3, 5])
def test_a_landmark_every_class_is_ruled_out_for_is_uniform(classes):
    posterior = class_posterior(np.full(classes, -np.inf))
    np.testing.assert_allclose(posterior, np.full(classes, 1.0 / classes), rtol=1e-12)
    np.testing.assert_allclose(class_posterior(np.log([0.2, 0.6, 0.2])), [0.2, 0.6, 0.2])
