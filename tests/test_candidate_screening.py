"""The candidate scorer's screening before the joint marginals (`candidates.py`): a landmark
whose classes the detector never reports as the detection's is no candidate, and a keyframe is
decided without the joint test only when each detection is sure of its own landmark, seen
lately."""

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import X

from pipeline.backend.candidates import CandidateScorer, PosePrediction
from tests.backend_cases import add_landmark, add_pose, detection_of, hand_context, measurement

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
