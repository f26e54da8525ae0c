"""The candidate scorer's screening before the joint marginals (`candidates.py`): a landmark
whose classes the detector never reports as the detection's is no candidate, and a keyframe is
decided without the joint test only when each detection is sure of its own landmark, seen
lately; and what the scoring then hands on, worked out here: the report's likelihood, the
weights kept, each candidate's fit, the wide gate, the keyframe's joint covariance."""

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import L, X

from pipeline.backend.candidates import CandidateScorer, PosePrediction
from pipeline.config import load_config
from pipeline.geometry import bearing_elevation_range
from tests.backend_cases import (
    CONFUSION,
    add_landmark,
    add_pose,
    detection_of,
    hand_context,
    measurement,
    with_settings,
)

NEVER_CONFUSED = np.eye(2)  # the detector reports each class as itself, always
SIGMAS = np.array([0.01, 0.01, 0.1])
A, B = np.array([10.0, 2.0, 0.0]), np.array([10.0, -2.0, 0.0])


def pinned(landmarks, confusion=NEVER_CONFUSED, keep_joint=False):
    """Pose 0 at the origin known to a micrometre, the new pose predicted there; landmarks
    known to a centimetre, of class 0."""
    context = hand_context(confusion=confusion)
    add_pose(context, 0, gtsam.Pose3(), 1e-6)
    ids = [add_landmark(context, p, 0.01, classes=[1.0, 0.0]) for p in landmarks]
    context.solver.update()
    prediction = PosePrediction(1, X(0), gtsam.Pose3(), np.eye(6), np.zeros((6, 6)))
    a = context.config.association
    scorer = CandidateScorer(context.solver, context.landmarks, confusion, a, keep_joint)
    return scorer, prediction, ids


@pytest.mark.parametrize(("class_id", "kept"), [(0, True), (1, False)])
def test_a_landmark_the_detector_never_reports_so_is_no_candidate(class_id, kept):
    scorer, prediction, (a,) = pinned([A])
    m = measurement(1, detection_of(gtsam.Pose3(), A, class_id=class_id, sigmas=SIGMAS))
    (candidates,), _ = scorer.score(prediction, [m])
    assert candidates.searched == 1  # found near ...
    assert candidates.landmark_ids.tolist() == ([a] if kept else [])  # ... but not if never
    if kept:
        assert candidates.weights == pytest.approx([1.0])


@pytest.mark.parametrize(
    ("seen", "recent", "decided_alone"),
    [
        ((A, B), (True, True), True),  # each sure of its own landmark, both seen lately
        ((A, A), (True, True), False),  # both sure of one landmark: the joint test decides
        ((A, B), (True, False), False),  # one would close a loop: the joint test decides
    ],
)
def test_a_keyframe_is_decided_without_the_joint_only_when_every_pairing_is_sure(
    seen, recent, decided_alone
):
    scorer, prediction, ids = pinned([A, B], keep_joint=True)
    keyframe = [
        measurement(1, detection_of(gtsam.Pose3(), p, class_id=0, sigmas=SIGMAS), k)
        for k, p in enumerate(seen)
    ]
    lately = dict(zip(ids, recent, strict=True))
    candidates, joint = scorer.score(prediction, keyframe, is_recent=lambda j: lately[j])
    expected = [ids[0] if (p == A).all() else ids[1] for p in seen]
    assert [c.landmark_ids.tolist() for c in candidates] == [[j] for j in expected]
    assert (joint is None) == decided_alone


def test_a_detection_s_report_is_weighed_by_the_confusion_matrix_s_column():
    """P(report | landmark) = sum_c P(report | c) P(c): the column of the reported class."""
    confusion = np.array([[0.7, 0.3], [0.1, 0.9]])  # rows: true class; columns: reported
    scorer, prediction, (a,) = pinned([A], confusion=confusion)
    m = measurement(1, detection_of(gtsam.Pose3(), A, class_id=1, sigmas=SIGMAS))
    (candidates,), _ = scorer.score(prediction, [m])
    assert candidates.landmark_ids.tolist() == [a]
    assert candidates.semantic == pytest.approx([0.3])  # the landmark is class 0 for sure


def three_near(min_weight: float):
    """Three landmarks known to 30 cm around the detection's landmark, 5, 15 and 25 cm off in
    bearing at 10 m, all inside the gate, each weighed; `min_weight` drops the least."""
    context = hand_context(with_settings(load_config(), association={"min_weight": min_weight}))
    add_pose(context, 0, gtsam.Pose3(), 1e-6)
    ids = [
        add_landmark(context, [10.0, y, 0.0], 0.3, classes=[1.0, 0.0]) for y in (0.05, 0.15, 0.25)
    ]
    context.solver.update()
    prediction = PosePrediction(1, X(0), gtsam.Pose3(), np.eye(6), np.zeros((6, 6)))
    a = context.config.association
    scorer = CandidateScorer(context.solver, context.landmarks, CONFUSION, a)
    m = measurement(1, detection_of(gtsam.Pose3(), [10.0, 0.0, 0.0], sigmas=SIGMAS))
    (candidates,), _ = scorer.score(prediction, [m])
    return ids, candidates, m


def test_the_weights_kept_sum_to_one_in_the_same_ratios():
    ids, every, _ = three_near(0.0)
    assert every.landmark_ids.tolist() == ids and every.weights.sum() == pytest.approx(1.0)
    dropped = float(every.weights[2])
    kept_ids, kept, _ = three_near(dropped * 1.01)
    assert kept.landmark_ids.tolist() == kept_ids[:2]
    assert kept.weights.sum() == pytest.approx(1.0)
    assert kept.weights[0] / kept.weights[1] == pytest.approx(every.weights[0] / every.weights[1])


def test_a_candidate_s_fit_is_its_residual_in_the_detection_s_own_metric():
    """|h(x, l) - z|^2 in Gamma's metric at the predicted pose, worked out here."""
    _, candidates, m = three_near(0.0)
    z = np.array([m.detection.bearing, m.detection.elevation, m.detection.range])
    for k, y in enumerate((0.05, 0.15, 0.25)):
        residual = bearing_elevation_range(np.array([10.0, y, 0.0])) - z
        assert candidates.fit_sq[k] == pytest.approx(np.sum((residual / SIGMAS) ** 2), rel=1e-6)
    assert candidates.fit_sq[2] > 5.0  # 2.5 sigma in bearing: the metric is Gamma's


@pytest.mark.parametrize(("wide_gate", "kept"), [(False, False), (True, True)])
def test_a_wide_gate_takes_a_landmark_the_usual_gate_leaves_out(wide_gate, kept):
    """A landmark known to 0.5 m at 10 m, off by d^2 = 10 in bearing: outside the gate at 0.9
    (6.25), inside the joint candidates' at 0.999 (16.27)."""
    context = hand_context()
    add_pose(context, 0, gtsam.Pose3(), 1e-6)
    r_bearing = 0.5**2 / 10.0**2 + SIGMAS[0] ** 2
    angle = np.sqrt(10.0 * r_bearing)
    j = add_landmark(context, [10.0 * np.cos(angle), 10.0 * np.sin(angle), 0.0], 0.5)
    context.solver.update()
    prediction = PosePrediction(1, X(0), gtsam.Pose3(), np.eye(6), np.zeros((6, 6)))
    a = context.config.association
    scorer = CandidateScorer(
        context.solver, context.landmarks, CONFUSION, a, keep_joint=False, wide_gate=wide_gate
    )
    m = measurement(1, detection_of(gtsam.Pose3(), [10.0, 0.0, 0.0], sigmas=SIGMAS))
    (candidates,), joint = scorer.score(prediction, [m])
    assert joint is None  # only keep_joint returns the keyframe's joint
    assert candidates.landmark_ids.tolist() == ([j] if kept else [])
    if kept:
        assert candidates.mahalanobis_sq[0] == pytest.approx(10.0, rel=1e-3)


def test_the_keyframe_s_joint_is_the_anchor_s_carried_to_the_new_pose():
    """With keep_joint: the new pose's block A P A^T + Q, its cross-covariance with a
    landmark A P_xl, the landmark's own block as it is (P from iSAM2's joint marginal)."""
    context = hand_context()
    add_pose(context, 0, gtsam.Pose3(), [0.02, 0.02, 0.05, 0.3, 0.3, 0.1])
    position = np.array([8.0, 2.0, 0.0])
    j = add_landmark(context, position, 1000.0)
    context.add_factor(measurement(0, detection_of(gtsam.Pose3(), position)), j)
    context.solver.update()
    step = gtsam.Pose3(gtsam.Rot3.Yaw(0.2), np.array([1.0, 0.2, 0.0]))
    process = np.diag([1e-5, 1e-5, 1e-4, 1e-2, 1e-2, 1e-3])
    prediction = PosePrediction(1, X(0), step, step.inverse().AdjointMap(), process)
    a = context.config.association
    scorer = CandidateScorer(context.solver, context.landmarks, CONFUSION, a, keep_joint=True)
    m = measurement(1, detection_of(step, position, sigmas=SIGMAS))
    _, joint = scorer.score(prediction, [m], full=True)
    P = context.solver.joint_covariance([X(0), L(j)])
    A = prediction.transport
    assert joint.offsets == {j: 6}
    np.testing.assert_allclose(joint.matrix[:6, :6], A @ P[:6, :6] @ A.T + process, rtol=1e-9)
    np.testing.assert_allclose(joint.matrix[:6, 6:], A @ P[:6, 6:], rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(joint.matrix[6:, :6], (A @ P[:6, 6:]).T, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(joint.matrix[6:, 6:], P[6:, 6:], rtol=1e-9)
