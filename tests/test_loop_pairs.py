"""The loop-pair retry of mm-nh's joint first choice (`MaxMixture.associate_keyframe`): a
keyframe whose best assignment closes a loop with too few pairings (`loop_pairs_needed`) has
those pairings taken out, and is decided again without them.

The keyframes are small linear problems, as in test_joint_association.py: residual = landmark
- pose translation, so H_pose = [0 | -I] and H_landmark = I, every variance SIGMA^2."""

import gtsam
import numpy as np
from gtsam.symbol_shorthand import X

from pipeline.backend.candidates import Candidates, KeyframeCovariance, PosePrediction
from pipeline.backend.hypotheses import NULL
from pipeline.backend.landmarks import LandmarkKind
from pipeline.backend.methods.base import Keyframe
from pipeline.backend.methods.maxmixture import MaxMixture
from tests.backend_cases import detection_at, hand_context, measurement

NOW = 100  # the keyframe's pose; recent_keyframes (30) back from it is "lately"
LATELY, LONG_AGO = NOW - 1, NOW - 60
SIGMA = 0.05
H_POSE = np.hstack([np.zeros((3, 3)), -np.eye(3)])
GAMMA = np.eye(3) * SIGMA**2
R_ALONE = 3 * SIGMA**2  # a lone pairing's innovation variance per axis: pose, landmark, Gamma


def keyframe(landmarks: dict[int, int]):
    """A mm-nh method over landmarks 0..n-1, each last seen at `landmarks[j]`; the keyframe's
    pose predicted at the origin. The space detections fall in spans a realistic box, so the
    null's density is that of a new landmark anywhere in view."""
    context = hand_context()
    method = MaxMixture(context, null_hypothesis=True)
    for j, last in landmarks.items():
        landmark = context.landmarks.create(LandmarkKind.POINT, np.array([10.0, 2.0 * j, 0.0]))
        landmark.class_probabilities = np.array([1.0, 0.0])
        assert landmark.id == j
        context.last_seen[j] = last
    for corner in ([-1.0, -0.3, 1.0], [1.0, 0.3, 20.0]):  # bearing, elevation, range
        context.space[LandmarkKind.POINT].observe(np.array(corner), GAMMA)
    return context, method


def options(ids, offsets, weights) -> Candidates:
    """A detection's candidates: landmark ids, each residual's offset in y (m), and the weights
    each had when weighed alone."""
    k = len(ids)
    residuals = np.zeros((k, 3))
    residuals[:, 1] = offsets
    return Candidates(
        landmark_ids=np.array(ids),
        weights=np.array(weights, dtype=float),
        semantic=np.full(k, 0.9),
        mahalanobis_sq=np.sum(residuals**2, axis=1) / R_ALONE,
        searched=k,
        fit_sq=np.sum(residuals**2, axis=1) / SIGMA**2,
        residuals=residuals,
        pose_jacobians=np.broadcast_to(H_POSE, (k, 3, 6)).copy(),
        landmark_jacobians=np.broadcast_to(np.eye(3), (k, 3, 3)).copy(),
    )


def decide(method, candidates: list[Candidates]):
    """The keyframe's records: the landmark each detection went to, and which are new."""
    measurements = [
        measurement(NOW, detection_at([0.1 * k, 0.0, 10.0], sigmas=[SIGMA] * 3), k)
        for k in range(len(candidates))
    ]
    before = method.context.landmarks.next_id
    n = len(method.context.landmarks)
    joint = KeyframeCovariance(np.eye(6 + 3 * n) * SIGMA**2, {j: 6 + 3 * j for j in range(n)})
    prediction = PosePrediction(NOW, X(NOW - 1), gtsam.Pose3(), np.eye(6), np.eye(6))
    records = method.associate_keyframe(Keyframe(prediction, measurements, candidates, joint))
    assert all(r.active != NULL for r in records)  # a first choice is a landmark, old or new
    return ["new" if r.landmark_id >= before else r.landmark_id for r in records]


def test_one_loop_pairing_alone_is_taken_out_and_its_detection_starts_a_landmark():
    # detection 0 fits landmark 0, seen long ago (a loop); detection 1 fits landmark 1, seen
    # lately. min_loop_pairs is 2: one loop pairing is too few.
    context, method = keyframe({0: LONG_AGO, 1: LATELY})
    assert context.config.association.min_loop_pairs == 2
    keyframe_options = [options([0], [0.0], [1.0]), options([1], [0.0], [1.0])]
    assert decide(method, keyframe_options) == ["new", 1]
    # the same keyframe with landmark 0 seen lately: nothing to retry, both paired
    _, method = keyframe({0: LATELY, 1: LATELY})
    assert decide(method, keyframe_options) == [0, 1]


def test_two_loop_pairings_agreeing_close_the_loop():
    _, method = keyframe({0: LONG_AGO, 1: LONG_AGO})
    assert decide(method, [options([0], [0.0], [1.0]), options([1], [0.0], [1.0])]) == [0, 1]


def test_a_loop_pairing_its_detection_s_other_candidate_outweighs_needs_a_third():
    # as above, but weighed alone detection 1 favoured landmark 2 (0.7), which the keyframe
    # together rules out (8 sigma off): crowded_loop_pairs (3) are needed, there are 2, both
    # are taken out and the detections start landmarks of their own
    context, method = keyframe({0: LONG_AGO, 1: LONG_AGO, 2: LATELY})
    assert context.config.association.crowded_loop_pairs == 3
    far = 8 * np.sqrt(R_ALONE)
    crowded = [options([0], [0.0], [1.0]), options([1, 2], [0.0, far], [0.3, 0.7])]
    assert decide(method, crowded) == ["new", "new"]
    # at 0.5 or more, the pairing is its detection's favourite alone too: two suffice
    _, method = keyframe({0: LONG_AGO, 1: LONG_AGO, 2: LATELY})
    favoured = [options([0], [0.0], [1.0]), options([1, 2], [0.0, far], [0.5, 0.5])]
    assert decide(method, favoured) == [0, 1]


def test_the_keyframe_is_decided_again_without_the_loop_pairing():
    # detection 0's best is landmark 0, seen long ago; landmark 2, seen lately, fits it worse
    # (d^2 6.5 alone: 3.25 nats less likely, so the first decision is sure of landmark 0) yet
    # well enough. Decided again without landmark 0, detection 0 takes landmark 2.
    second_best = np.sqrt(6.5 * R_ALONE)
    _, method = keyframe({0: LONG_AGO, 1: LATELY, 2: LATELY})
    retried = [options([0, 2], [0.0, second_best], [0.96, 0.04]), options([1], [0.0], [1.0])]
    assert decide(method, retried) == [2, 1]
    # were landmark 0 seen lately, it would have kept the detection
    _, method = keyframe({0: LATELY, 1: LATELY, 2: LATELY})
    assert decide(method, retried) == [0, 1]
