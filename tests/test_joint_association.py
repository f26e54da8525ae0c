"""A keyframe's detections associated together, on small linear problems worked by hand:
residual = landmark - pose translation, so H_pose = [0 | -I] and H_landmark = I."""

import math

import numpy as np
import pytest

from pipeline.backend.association import gaussian_log_density
from pipeline.backend.budget import SearchBudget
from pipeline.backend.methods.maxmixture.joint_association import (
    EMPTY,
    NONE,
    DetectionOptions,
    KeyframeProblem,
    _group_problem,
    _Search,
    associate_keyframe,
    detection_groups,
    indistinguishable,
    joint_log_likelihood,
    score,
    stacked_pairs,
)

H_POSE = np.hstack([np.zeros((3, 3)), -np.eye(3)])
GAMMA = np.diag([0.05**2] * 3)
NULL_DENSITY = -10.0  # log of the null's density, the same for every detection here


LOG_PRIOR = math.log(0.9)


def detection(residuals, slots, log_prior=LOG_PRIOR) -> DetectionOptions:
    residuals = np.atleast_2d(np.asarray(residuals, dtype=float)).reshape(-1, 3)
    n = len(residuals)
    return DetectionOptions(
        residuals=residuals,
        pose_jacobians=np.broadcast_to(H_POSE, (n, 3, 6)).copy(),
        landmark_jacobians=np.broadcast_to(np.eye(3), (n, 3, 3)).copy(),
        slots=np.array(slots, dtype=int),
        log_prior=np.full(n, log_prior),
        covariance=GAMMA,
        null_log_density=NULL_DENSITY,
    )


def problem(detections, pose_sigmas, landmarks: int, landmark_sigma=0.05) -> KeyframeProblem:
    n = 6 + 3 * landmarks
    covariance = np.eye(n) * landmark_sigma**2
    covariance[:6, :6] = np.diag(np.asarray(pose_sigmas, dtype=float) ** 2)
    offsets = np.arange(landmarks) * 3 + 6
    return KeyframeProblem(detections, covariance, offsets, np.full(landmarks, 3), 0.95)


def test_score_of_one_pairing_is_its_marginal_likelihood_and_priors():
    det = detection([[0.1, -0.2, 0.0]], [0])
    p = problem([det, detection([], [])], [0.0, 0.0, 0.0, 0.3, 0.3, 0.3], landmarks=1)
    S = np.diag([0.3**2 + 0.05**2 + 0.05**2] * 3)
    expected = gaussian_log_density(det.residuals[0], S) + math.log(0.9) + NULL_DENSITY
    assert score(p, [0, NONE]) == pytest.approx(expected)
    assert score(p, [NONE, NONE]) == pytest.approx(2 * NULL_DENSITY)


def test_detections_that_agree_on_the_pose_outweigh_one_that_fits_the_prediction():
    # The pose slid 3 m sideways (y sigma 3 m). Two detections see their landmarks 3 m off the
    # prediction, in the same direction; a third fits a lookalike exactly where predicted.
    truthful_a = detection([[0.0, 3.0, 0.0]], [0])
    truthful_b = detection([[0.0, 3.02, 0.01]], [1])
    alias = detection([[0.0, 0.0, 0.0]], [2])
    p = problem([truthful_a, truthful_b, alias], [1e-3] * 3 + [0.05, 3.0, 0.05], landmarks=3)
    decision = associate_keyframe(p, ambiguity_log_odds=3.0, max_nodes=1000)
    assert decision.finished
    assert decision.assignment == [0, 0, NONE]
    assert decision.unique[:2] == [True, True]
    # one by one, at the prediction, the lookalike would have been the best fit of all
    assert np.linalg.norm(alias.residuals[0]) < np.linalg.norm(truthful_a.residuals[0])


def test_a_pairing_with_a_close_rival_is_not_made():
    # Two landmarks 7 m apart, the pose known to 5 m along the line between them.
    det = detection([[0.0, -3.4, 0.0], [0.0, 3.6, 0.0]], [0, 1])
    p = problem([det], [1e-3] * 3 + [0.05, 5.0, 0.05], landmarks=2)
    decision = associate_keyframe(p, ambiguity_log_odds=3.0, max_nodes=1000)
    assert decision.assignment == [0]  # the nearer one is best ...
    assert decision.unique == [False]  # ... but the other is almost as likely
    # with the pose known to 0.3 m, the same two landmarks seen from where the pose really is
    known = detection([[0.0, 0.1, 0.0], [0.0, 7.1, 0.0]], [0, 1])
    sure = associate_keyframe(
        problem([known], [1e-3] * 3 + [0.05, 0.3, 0.05], landmarks=2), 3.0, 1000
    )
    assert sure.assignment == [0] and sure.unique == [True]


def test_a_landmark_mapped_twice_is_no_rival():
    # Two estimates of one landmark 3 cm apart: choosing either is right.
    det = detection([[0.0, 0.02, 0.0], [0.0, -0.01, 0.0]], [0, 1])
    p = problem([det], [1e-3] * 3 + [0.05, 0.5, 0.05], landmarks=2)
    assert indistinguishable(p, 0, 0, 1)
    decision = associate_keyframe(p, ambiguity_log_odds=3.0, max_nodes=1000)
    assert decision.assignment != [NONE] and decision.unique == [True]


def test_nothing_fits_goes_to_the_null():
    far = detection([[0.0, 2.0, 0.0]], [0])  # 40 sigma off, with the pose known
    p = problem([far], [1e-3] * 3 + [0.05] * 3, landmarks=1)
    assert associate_keyframe(p, 3.0, 1000).assignment == [NONE]


def test_one_landmark_takes_one_detection_a_keyframe():
    a = detection([[0.0, 0.0, 0.0]], [0])
    b = detection([[0.0, 0.01, 0.0]], [0])
    p = problem([a, b], [1e-3] * 3 + [0.05] * 3, landmarks=1)
    assignment = associate_keyframe(p, 3.0, 1000).assignment
    assert sorted(assignment) == [NONE, 0]


def test_an_exhausted_search_decides_nothing():
    dets = [detection([[0.0, 0.0, 0.0], [0.0, 0.1, 0.0]], [0, 1]) for _ in range(3)]
    p = problem(dets, [1e-3] * 3 + [0.5] * 3, landmarks=2)
    decision = associate_keyframe(p, 3.0, max_nodes=2)
    assert not decision.finished and decision.assignment == [NONE] * 3


def test_subset_keeps_the_chosen_options_in_order():
    det = detection([[1.0, 0, 0], [2.0, 0, 0], [3.0, 0, 0]], [4, 5, 6])
    sub = det.subset(np.array([2, 0]))
    np.testing.assert_array_equal(sub.slots, [6, 4])
    np.testing.assert_array_equal(sub.residuals[:, 0], [3.0, 1.0])


def test_of_two_estimates_of_one_landmark_the_established_one_takes_the_detection():
    det = detection([[0.0, 0.02, 0.0], [0.0, -0.01, 0.0]], [0, 1])
    det = DetectionOptions(**{**det.__dict__, "seniority": np.array([30.0, 2.0])})
    p = problem([det], [1e-3] * 3 + [0.05, 0.5, 0.05], landmarks=2)
    # the second fits a little better, but the first holds thirty detections already
    assert score(p, [1]) > score(p, [0])
    assert associate_keyframe(p, 3.0, 1000).assignment == [0]


def test_an_established_lookalike_hidden_by_the_pose_uncertainty_does_not_take_it():
    # 2 m apart, the second landmark known to 5 m only (a drifted map): the joint test cannot
    # tell them apart, but the measurement can: the better fit keeps the detection whatever
    # the other's seniority
    det = detection([[0.0, 0.02, 0.0], [0.0, 2.0, 0.0]], [0, 1])
    det = DetectionOptions(**{**det.__dict__, "seniority": np.array([1.0, 40.0])})
    p = problem([det], [1e-3] * 3 + [0.05, 0.05, 0.05], landmarks=2)
    p.covariance[9:12, 9:12] = np.eye(3) * 25.0
    assert indistinguishable(p, 0, 0, 1)
    assert associate_keyframe(p, 3.0, 1000).assignment == [0]


def crowded(detections: int, rival_m: float = 0.2, pose_sigma: float = 0.05) -> KeyframeProblem:
    """Detection i sees landmark i, and its neighbour i + 1 lies `rival_m` off: within the
    gate, an option for the search to rule out, in a keyframe of as many landmarks."""
    rng = np.random.default_rng(0)
    dets = []
    for i in range(detections):
        own = rng.normal(size=3) * 0.03
        rival = own + np.array([rival_m, 0.0, 0.0])
        dets.append(detection([own, rival], [i, (i + 1) % detections]))
    return problem(dets, [1e-3] * 3 + [pose_sigma] * 3, landmarks=detections)


def test_a_spent_keyframe_budget_leaves_every_detection_to_the_null():
    p = crowded(6)
    decision = associate_keyframe(p, 3.0, 1000, budget=SearchBudget(3))
    assert not decision.finished and decision.assignment == [NONE] * 6
    # spent by a search before: the next decides nothing either, and spends nothing
    spent = SearchBudget(100, spent=100)
    assert associate_keyframe(p, 3.0, 1000, budget=spent).assignment == [NONE] * 6
    assert spent.spent == 100


def test_rivals_left_unfinished_leave_their_pairings_unmade():
    p = crowded(6, rival_m=0.3, pose_sigma=0.1)  # each neighbour a rival to search
    counted = SearchBudget(10**6)
    whole = associate_keyframe(p, 3.0, 1000, budget=counted)
    assert whole.finished and all(whole.unique)
    best_only = _Search(p, 1000, None)
    best_only.run()
    # enough for the best assignment, not for its rivals: found, but nothing unique
    decision = associate_keyframe(p, 3.0, 1000, budget=SearchBudget(best_only.nodes))
    assert decision.assignment == whole.assignment and not any(decision.unique)


def test_a_search_within_its_budget_decides_as_without_one():
    p = crowded(8)
    unbounded = associate_keyframe(p, 3.0, 1000)
    budget = SearchBudget(10**6)
    bounded = associate_keyframe(p, 3.0, 1000, budget=budget)
    assert bounded == unbounded and 0 < budget.spent < 10**6


def test_groups_decide_as_the_whole_keyframe_where_it_fits():
    p = crowded(8)
    whole = associate_keyframe(p, 3.0, 10**5)
    assert whole.assignment == [0] * 8 and all(whole.unique)
    assert associate_keyframe(p, 3.0, 10**5, max_detections=3) == whole


def test_detection_groups_keep_linked_detections_together_as_far_as_a_group_holds_them():
    # detections 0-2 share landmark 0, 3-4 landmark 5, 5 has its own, 6 none
    dets = [detection([[0.0, 0, 0]], [0]) for _ in range(3)]
    dets += [detection([[0.0, 0, 0]], [5]) for _ in range(2)]
    dets += [detection([[0.0, 0, 0]], [7]), detection([], [])]
    p = problem(dets, [1e-3] * 6, landmarks=8)
    assert detection_groups(p, 10) == [[0, 1, 2, 3, 4, 5]]
    assert detection_groups(p, 3) == [[0, 1, 2], [3, 4, 5]]
    assert detection_groups(p, 2) == [[0, 1], [2], [3, 4], [5]]


def test_a_group_is_given_the_pairings_before_it():
    # The pose slid 0.3 m in x (sigma 0.5 m): given detection 0's pairing, which says so,
    # detection 1's residual is the same 0.3 m explained, its covariance the pose's pinned.
    dets = [detection([[0.3, 0, 0]], [0]), detection([[0.3, 0, 0]], [1])]
    p = problem(dets, [1e-3] * 3 + [0.5] * 3, landmarks=2)
    given = stacked_pairs(p, [(0, 0)])
    alone, _ = _group_problem(p, [1], set(), [], EMPTY)
    cut, kept = _group_problem(p, [1], {0}, [(0, 0)], given)
    assert list(kept[0]) == [0] and cut.covariance.shape == (9, 9) == alone.covariance.shape
    assert abs(cut.detections[0].residuals[0, 0]) < 0.05 < alone.detections[0].residuals[0, 0]
    assert cut.covariance[3, 3] < 0.01 < alone.covariance[3, 3]
    # the chain rule: the group's likelihood given the first is the pair's over the first's
    both, _ = joint_log_likelihood(p, [(0, 0), (1, 0)])
    first, _ = joint_log_likelihood(p, [(0, 0)])
    second, _ = joint_log_likelihood(cut, [(0, 0)])
    assert second == pytest.approx(both - first)


def test_a_crowded_keyframe_is_searched_in_bounded_work():
    """300 detections each with a rival in its gate: searched whole, no search finishes and
    nothing is paired; in groups of 12, every search is one of 12 detections, the nodes grow
    with the detections, and every pairing is made."""
    p = crowded(300)
    counted = SearchBudget(10**9)
    whole = associate_keyframe(p, 3.0, 500, budget=counted)
    assert not whole.finished and whole.assignment == [NONE] * 300
    counted = SearchBudget(10**9)
    depths = []
    run = _Search.run

    def recording(search):
        depths.append(len(search.order))
        return run(search)

    _Search.run = recording
    try:
        grouped = associate_keyframe(p, 3.0, 500, max_detections=12, budget=counted)
    finally:
        _Search.run = run
    assert grouped.finished and grouped.assignment == [0] * 300 and all(grouped.unique)
    assert max(depths) <= 12
    assert counted.spent <= 10 * 300
