"""The max-mixture method (`maxmixture/method.py`) one detection at a time and its switches, on
small states built by hand: the first component by the weights or at the prediction, the null
hypothesis's share, a detection nothing fits starting a landmark, a switch to the null taking
the factor out, and a keyframe's joint pairing's factor on the landmark chosen."""

import math

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import L, X

from pipeline.backend.candidates import Candidates, KeyframeCovariance, PosePrediction
from pipeline.backend.hypotheses import NULL
from pipeline.backend.landmarks import LandmarkKind
from pipeline.backend.methods.base import Keyframe
from pipeline.backend.methods.maxmixture import MaxMixture
from pipeline.config import load_config
from tests.backend_cases import (
    add_landmark,
    add_pose,
    detection_at,
    detection_of,
    factor_keys,
    hand_context,
    keyframe_at,
    measurement,
    past_record,
    with_settings,
)

POSE = gtsam.Pose3()
A, B = np.array([10.0, 1.0, 0.0]), np.array([10.0, -1.0, 0.0])


def method(first_choice: str, null_hypothesis: bool = True, null_weight: float = 0.1):
    config = with_settings(
        load_config(),
        mixture={"first_choice": first_choice},
        association={"null_weight": null_weight},
    )
    context = hand_context(config)
    add_pose(context, 1, POSE, 1e-3)
    a = add_landmark(context, A, 0.05, classes=[1.0, 0.0])
    b = add_landmark(context, B, 0.05, classes=[1.0, 0.0])
    context.solver.update()
    return context, MaxMixture(context, null_hypothesis=null_hypothesis), a, b


def candidates(ids, weights, fit_sq) -> Candidates:
    k = len(ids)
    return Candidates(
        np.array(ids), np.array(weights, float), np.full(k, 0.9), np.zeros(k), k,
        np.array(fit_sq, float),
    )  # fmt: skip


@pytest.mark.parametrize(
    ("null_weight", "active"), [(0.5, NULL), (0.2, 0)]
)  # 0.6 (1 - w) against w: 0.3 < 0.5, 0.48 > 0.2
def test_by_the_weights_the_null_wins_where_it_outweighs_the_best(null_weight, active):
    context, mm, a, b = method("weights", null_weight=null_weight)
    assert mm.null_weight == pytest.approx(null_weight)
    m = measurement(1, detection_of(POSE, A, class_id=0))
    record = mm.associate(m, candidates([a, b], [0.6, 0.4], [0.0, 1.0]), keyframe_at(1, POSE))
    assert record.null_weight == pytest.approx(null_weight)
    np.testing.assert_allclose(record.weights, np.array([0.6, 0.4]) * (1 - null_weight))
    assert record.active == active
    context.solver.update()
    assert ((X(1), L(a)) in factor_keys(context.solver)) == (active == 0)


def test_without_the_null_hypothesis_the_best_weight_is_taken():
    _, mm, a, b = method("weights", null_hypothesis=False, null_weight=0.5)
    assert mm.null_weight == pytest.approx(0.0, abs=1e-12) and mm.name == "mm"
    m = measurement(1, detection_of(POSE, A, class_id=0))
    record = mm.associate(m, candidates([a, b], [0.4, 0.6], [1.0, 0.0]), keyframe_at(1, POSE))
    np.testing.assert_allclose(record.weights, [0.4, 0.6])
    assert record.active == 1 and record.landmark_id == b


def test_at_the_prediction_a_detection_nothing_fits_starts_a_landmark_of_its_own():
    """Both candidates 20 sigma off at the predicted pose: the null's cost (the relative model
    at d^2 60) is lower, and with merges a landmark of its own is started there."""
    context, mm, a, b = method("prediction")
    point = np.array([10.0, 0.0, 0.0])
    m = measurement(1, detection_of(POSE, point, class_id=0))
    record = mm.associate(m, candidates([a, b], [0.5, 0.5], [400.0, 400.0]), keyframe_at(1, POSE))
    (new,) = set(context.landmarks.landmarks) - {a, b}
    assert record.landmark_ids == [new] and record.active == 0
    np.testing.assert_allclose(context.landmarks.position(new), point, atol=1e-6)
    # where one fits, it is the first choice
    m = measurement(1, detection_of(POSE, A, class_id=0), 1)
    record = mm.associate(m, candidates([a, b], [0.5, 0.5], [0.5, 400.0]), keyframe_at(1, POSE))
    assert record.landmark_ids == [a, b] and record.active == 0


def test_a_switch_to_the_null_takes_the_factor_out():
    """A record on landmark A whose detection, seen from the pose as it is, lies 2 m from A
    (the detection's 1 cm noise: d^2 in the tens of thousands): the null wins at the next
    revision, and its factor leaves the graph."""
    context, mm, a, _ = method("prediction")
    m = measurement(1, detection_of(POSE, A + np.array([0.0, 2.0, 0.0]), class_id=0))
    record = mm.track(past_record(context, m, [a], [0.9], 0, null_weight=0.1))
    context.solver.update()
    assert (X(1), L(a)) in factor_keys(context.solver)
    changed = mm.refine({X(1)})
    assert changed == [record] and record.active == NULL and record.handles == []
    assert record.switches == 1
    context.solver.update()
    assert (X(1), L(a)) not in factor_keys(context.solver)


def test_a_keyframe_s_joint_pairing_puts_its_factor_on_the_landmark_chosen():
    """A keyframe of one detection whose candidates are landmark A (listed first, 2 m off)
    and B (exact), both seen lately: the joint choice is B, and so is the factor."""
    context, mm, a, b = method("joint")
    for j in (a, b):
        context.last_seen[j] = 0
    space = context.space[LandmarkKind.POINT]
    for corner in ([-1.0, -0.3, 1.0], [1.0, 0.3, 20.0]):
        space.observe(np.array(corner), np.eye(3) * 1e-4)
    sigma = 0.05
    residuals = np.array([[0.0, 2.0, 0.0], [0.0, 0.0, 0.0]])
    c = Candidates(
        landmark_ids=np.array([a, b]),
        weights=np.array([0.5, 0.5]),
        semantic=np.full(2, 0.9),
        mahalanobis_sq=np.zeros(2),
        searched=2,
        fit_sq=np.zeros(2),
        residuals=residuals,
        pose_jacobians=np.broadcast_to(np.hstack([np.zeros((3, 3)), -np.eye(3)]), (2, 3, 6)).copy(),
        landmark_jacobians=np.broadcast_to(np.eye(3), (2, 3, 3)).copy(),
    )
    m = measurement(1, detection_at([0.0, 0.0, 10.0], sigmas=[sigma] * 3))
    joint = KeyframeCovariance(np.eye(12) * sigma**2, {a: 6, b: 9})
    prediction = PosePrediction(1, X(0), POSE, np.eye(6), np.eye(6))
    (record,) = mm.associate_keyframe(Keyframe(prediction, [m], [c], joint))
    assert record.landmark_id == b and record.landmark_ids == [a, b]
    context.solver.update()
    keys = factor_keys(context.solver)
    assert (X(1), L(b)) in keys and (X(1), L(a)) not in keys


def test_a_point_detection_s_null_is_a_new_landmark_or_clutter_anywhere_in_view():
    """The null's density: null_weight times the report's mean likelihood over the true
    classes, uniform over the measurement box (log volume)."""
    context, mm, _, _ = method("joint")
    space = context.space[LandmarkKind.POINT]
    for corner in ([-1.0, -0.3, 1.0], [1.0, 0.3, 20.0]):
        space.observe(np.array(corner), np.eye(3) * 1e-4)
    for class_id in (0, 1):
        m = measurement(1, detection_of(POSE, A, class_id=class_id))
        report = float(np.mean(context.confusion[:, class_id]))
        volume = 2.0 * 0.6 * 19.0
        expected = math.log(0.1) + math.log(report) - math.log(volume)
        assert mm._null_log_density(m) == pytest.approx(expected, rel=1e-9)


def joint_keyframe(mm, residuals, weights=None):
    """One keyframe whose detection k has candidates `residuals[k]` (landmark id -> offset of
    the prediction from the measurement, m), each pairing's innovation 3 sigma^2 per axis
    (pose, landmark, detection, sigma 5 cm)."""
    context = mm.context
    space = context.space[LandmarkKind.POINT]
    for corner in ([-1.0, -0.3, 1.0], [1.0, 0.3, 20.0]):
        space.observe(np.array(corner), np.eye(3) * 1e-4)
    sigma = 0.05
    ids = sorted({j for options in residuals for j in options})
    slot = {j: 6 + 3 * s for s, j in enumerate(ids)}
    measurements, keyframe_candidates = [], []
    for k, options in enumerate(residuals):
        n = len(options)
        offsets = np.zeros((n, 3))
        offsets[:, 1] = list(options.values())
        keyframe_candidates.append(
            Candidates(
                landmark_ids=np.array(list(options)),
                weights=np.full(n, 1.0 / n) if weights is None else np.array(weights[k]),
                semantic=np.full(n, 0.9),
                mahalanobis_sq=np.zeros(n),
                searched=n,
                fit_sq=np.zeros(n),
                residuals=offsets,
                pose_jacobians=np.broadcast_to(
                    np.hstack([np.zeros((3, 3)), -np.eye(3)]), (n, 3, 6)
                ).copy(),
                landmark_jacobians=np.broadcast_to(np.eye(3), (n, 3, 3)).copy(),
            )
        )
        measurements.append(
            measurement(1, detection_at([0.1 * k, 0.0, 10.0], sigmas=[sigma] * 3), k)
        )
    joint = KeyframeCovariance(np.eye(6 + 3 * len(ids)) * sigma**2, slot)
    prediction = PosePrediction(1, X(0), POSE, np.eye(6), np.eye(6))
    return mm.associate_keyframe(Keyframe(prediction, measurements, keyframe_candidates, joint))


def test_a_pairing_a_rival_comes_close_to_starts_a_landmark_instead():
    """Landmarks A and B 15 cm either side of the detection's prediction: each fits (d^2 3),
    they are told apart (their difference's d^2 is 12), and they score alike: ambiguous."""
    context, mm, a, b = method("joint")
    for j in (a, b):
        context.last_seen[j] = 0
    (record,) = joint_keyframe(mm, [{a: 0.15, b: -0.15}])
    assert record.landmark_id not in (a, b) and len(context.landmarks) == 3
    # with B 30 cm further off, A is unique
    context, mm, a, b = method("joint")
    for j in (a, b):
        context.last_seen[j] = 0
    (record,) = joint_keyframe(mm, [{a: 0.15, b: -0.45}])
    assert record.landmark_id == a


def test_seniority_moves_a_pairing_only_to_a_landmark_seen_lately():
    """Two detections, each exact on a landmark started lately (one detection so far) and a
    centimetre from a landmark of twenty detections seen long ago (a loop): the loop landmarks
    are no more established for that, and both detections stay on the recent ones."""
    context, mm, a, b = method("joint")
    c = add_landmark(context, [10.0, 3.0, 0.0], 0.05, classes=[1.0, 0.0])
    d = add_landmark(context, [10.0, -3.0, 0.0], 0.05, classes=[1.0, 0.0])
    context.solver.update()
    for j in (a, b):  # started lately: one detection each
        context.last_seen[j] = 0
        context.records_of[j] = [None]  # stands for a record: seniority counts them
    for j in (c, d):  # twenty detections, long ago
        context.last_seen[j] = -100
        context.records_of[j] = [None] * 20
    records = joint_keyframe(mm, [{a: 0.0, c: 0.01}, {b: 0.0, d: 0.01}])
    assert [r.landmark_id for r in records] == [a, b]


def test_each_option_s_prior_holds_the_candidates_share_beside_the_null():
    context, mm, a, b = method("joint", null_weight=0.3)
    for j in (a, b):
        context.last_seen[j] = 0
    space = context.space[LandmarkKind.POINT]
    for corner in ([-1.0, -0.3, 1.0], [1.0, 0.3, 20.0]):
        space.observe(np.array(corner), np.eye(3) * 1e-4)
    c = candidates([a, b], [0.5, 0.5], [0.0, 0.0])
    c = Candidates(**{**c.__dict__, "semantic": np.array([0.9, 0.2])})
    joint = KeyframeCovariance(np.eye(12), {a: 6, b: 9})
    options = mm._options(measurement(1, detection_of(POSE, A)), c, joint)
    np.testing.assert_allclose(options.log_prior, np.log(0.7 * np.array([0.9, 0.2])))
    np.testing.assert_array_equal(options.slots, [0, 1])


def test_a_merged_record_stays_on_its_landmark_whatever_its_place_among_the_components():
    """A record whose components are the duplicate B, another landmark C and the survivor A,
    A active: merged, its components are A (B's weight added) and C, and A is still active."""
    context, mm, a, b = method("joint")
    c = add_landmark(context, [10.0, 3.0, 0.0], 0.05, classes=[1.0, 0.0])
    m = measurement(1, detection_of(POSE, A, class_id=0))
    record = mm.track(past_record(context, m, [b, c, a], [0.3, 0.2, 0.4], 2, null_weight=0.1))
    context.solver.update()
    mm.merge(a, b)
    assert record.landmark_ids == [a, c]
    np.testing.assert_allclose(record.weights, [0.7, 0.2])
    assert record.landmark_id == a
    context.solver.update()
    assert (X(1), L(a)) in factor_keys(context.solver)
