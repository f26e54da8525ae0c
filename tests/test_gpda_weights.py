"""GPDA's first association of a detection (`methods/gpda.py`), by hand: the class evidence
weighed by the association weights, and no factor for a component below `min_weight`."""

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import L, X

from pipeline.backend.candidates import Candidates
from pipeline.backend.methods.gpda import GaussianPDA
from pipeline.config import load_config
from tests.backend_cases import (
    CONFUSION,
    add_landmark,
    add_pose,
    detection_of,
    factor_keys,
    hand_context,
    keyframe_at,
    measurement,
    with_settings,
)

A, B = [10.0, 1.0, 0.0], [10.0, -1.0, 0.0]


def gpda(min_weight: float = 1e-6):
    context = hand_context(with_settings(load_config(), association={"min_weight": min_weight}))
    add_pose(context, 1, gtsam.Pose3(), 1e-3)
    a = add_landmark(context, A, 0.05, classes=[0.7, 0.3])
    b = add_landmark(context, B, 0.05, classes=[0.4, 0.6])
    context.solver.update()
    return context, GaussianPDA(context), a, b


def test_each_candidate_s_classes_take_the_report_at_its_association_weight():
    """evidence(c) = (w_k / s_k) P(report | c) + (1 - w_k), s_k = P(report | landmark k): the
    report counted once, summed over the associations."""
    context, method, a, b = gpda()
    priors = {j: context.landmarks.landmarks[j].class_probabilities.copy() for j in (a, b)}
    column = CONFUSION[:, 1]
    semantic = np.array([column @ priors[a], column @ priors[b]])
    weights = np.array([0.3, 0.7])
    c = Candidates(np.array([a, b]), weights, semantic, np.zeros(2), 2)
    m = measurement(1, detection_of(gtsam.Pose3(), A, class_id=1))
    method.associate(m, c, keyframe_at(1))
    for j, w, s in zip((a, b), weights, semantic, strict=True):
        posterior = priors[j] * ((w / s) * column + (1.0 - w))
        np.testing.assert_allclose(
            context.landmarks.landmarks[j].class_probabilities,
            posterior / posterior.sum(),
            rtol=1e-12,
        )


@pytest.mark.parametrize(("weights", "factors"), [((0.9, 0.1), 1), ((0.6, 0.4), 2)])
def test_a_component_below_min_weight_gets_no_factor(weights, factors):
    context, method, a, b = gpda(min_weight=0.2)
    c = Candidates(np.array([a, b]), np.array(weights), np.full(2, 0.5), np.zeros(2), 2)
    record = method.associate(measurement(1, detection_of(gtsam.Pose3(), A)), c, keyframe_at(1))
    assert len(record.handles) == factors
    np.testing.assert_allclose(record.graph_weights, weights)
    context.solver.update()
    keys = factor_keys(context.solver)
    assert (X(1), L(a)) in keys and ((X(1), L(b)) in keys) == (factors == 2)
