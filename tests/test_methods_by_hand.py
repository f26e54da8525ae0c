"""Maximum likelihood (`methods/ml.py`), known association (`methods/known.py`) and GPDA's
first association (`methods/gpda.py`) on small states built by hand: which landmark a detection
goes to, the factor that goes into the graph, the record's weight, what the report does to the
landmarks' class posteriors (Bayes' rule for a sure association, worked out here), and GPDA's
class evidence weighed by the association weights, no factor for a component below
`min_weight`."""

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import L, X

from pipeline.backend.candidates import Candidates
from pipeline.backend.hypotheses import NULL
from pipeline.backend.methods.gpda import GaussianPDA
from pipeline.backend.methods.known import KnownAssociation
from pipeline.backend.methods.ml import MaximumLikelihood
from pipeline.config import load_config
from pipeline.errors import InputError
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

POSE = gtsam.Pose3(gtsam.Rot3(), np.array([1.0, 0.0, 0.0]))
A, B = [10.0, 1.0, 0.0], [10.0, -1.0, 0.0]


def bayes(prior, class_id: int) -> np.ndarray:
    """A landmark's class posterior after one sure report of `class_id`."""
    posterior = np.asarray(prior, float) * CONFUSION[:, class_id]
    return posterior / posterior.sum()


def two_landmarks():
    """Pose 1 at POSE and landmarks A and B, each held by a prior; A's classes [0.7, 0.3],
    B's [0.4, 0.6]."""
    context = hand_context()
    add_pose(context, 1, POSE, 1e-3)
    a = add_landmark(context, A, 0.1, classes=[0.7, 0.3])
    b = add_landmark(context, B, 0.1, classes=[0.4, 0.6])
    return context, a, b


def candidates(ids, weights) -> Candidates:
    k = len(ids)
    return Candidates(np.array(ids), np.array(weights, float), np.full(k, 0.5), np.zeros(k), k)


@pytest.mark.parametrize("weights", [(0.3, 0.7), (0.8, 0.2)])
def test_ml_commits_to_the_most_likely_candidate_with_its_weight(weights):
    context, a, b = two_landmarks()
    method = MaximumLikelihood(context)
    best, other = (b, a) if weights[1] > weights[0] else (a, b)
    prior_other = context.landmarks.landmarks[other].class_probabilities.copy()
    prior_best = context.landmarks.landmarks[best].class_probabilities.copy()
    m = measurement(1, detection_of(POSE, B, class_id=1))
    record = method.associate(m, candidates([a, b], weights), keyframe_at(1, POSE))
    assert record.landmark_ids == [best] and record.landmark_id == best
    assert record.weight == pytest.approx(max(weights))
    context.solver.update()
    assert (X(1), L(best)) in factor_keys(context.solver)
    assert (X(1), L(other)) not in factor_keys(context.solver)
    # the report counted once, on the landmark taken, as a sure association
    lms = context.landmarks.landmarks
    np.testing.assert_allclose(lms[best].class_probabilities, bayes(prior_best, 1), atol=1e-12)
    np.testing.assert_allclose(lms[other].class_probabilities, prior_other, atol=1e-12)


@pytest.mark.parametrize("method_class", [MaximumLikelihood, KnownAssociation])
def test_a_detection_with_nothing_to_go_to_starts_a_landmark_where_it_puts_it(method_class):
    context, a, b = two_landmarks()
    method = method_class(context)
    point = np.array([20.0, 5.0, 1.0])
    m = measurement(1, detection_of(POSE, point, class_id=0, truth=3))
    record = method.associate(m, Candidates.none(), keyframe_at(1, POSE))
    (new,) = set(context.landmarks.landmarks) - {a, b}
    assert record.landmark_ids == [new] and record.landmark_id == new
    np.testing.assert_allclose(context.landmarks.position(new), point, atol=1e-6)
    context.solver.update()
    assert (X(1), L(new)) in factor_keys(context.solver)


def test_known_maps_each_true_landmark_once_and_counts_every_report():
    context, a, b = two_landmarks()
    method = KnownAssociation(context)
    point = [12.0, 3.0, 0.0]
    first = method.associate(
        measurement(1, detection_of(POSE, point, class_id=0, truth=7)),
        Candidates.none(),
        keyframe_at(1, POSE),
    )
    landmark = first.landmark_id
    assert landmark not in (a, b)
    after_first = context.landmarks.landmarks[landmark].class_probabilities.copy()
    count = len(context.landmarks)
    second = method.associate(
        measurement(1, detection_of(POSE, point, class_id=1, truth=7), 1),
        candidates([a, b], [0.5, 0.5]),  # known reads the truth, not the candidates
        keyframe_at(1, POSE),
    )
    assert second.landmark_ids == [landmark] and second.landmark_id == landmark
    assert len(context.landmarks) == count
    np.testing.assert_allclose(
        context.landmarks.landmarks[landmark].class_probabilities,
        bayes(after_first, 1),
        atol=1e-12,
    )
    context.solver.update()
    assert factor_keys(context.solver).count((X(1), L(landmark))) == 2


def test_known_leaves_a_false_positive_out_and_refuses_a_detection_without_truth():
    context, a, _ = two_landmarks()
    method = KnownAssociation(context)
    count = len(context.landmarks)
    record = method.associate(
        measurement(1, detection_of(POSE, A, truth=NULL)), candidates([a], [1.0]), keyframe_at(1)
    )
    assert record.landmark_ids == [] and record.landmark_id == NULL and record.handles == []
    assert len(context.landmarks) == count
    context.solver.update()
    assert not any(X(1) in keys and len(keys) == 2 for keys in factor_keys(context.solver))
    with pytest.raises(InputError, match="truth_landmark_id"):
        method.associate(measurement(1, detection_of(POSE, A)), Candidates.none(), keyframe_at(1))


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
