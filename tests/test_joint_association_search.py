"""The keyframe's joint association (`maxmixture/joint_association.py`) against references
written out plainly here, on random small keyframes (several seeds): the branch and bound's
best assignment and score against every assignment enumerated, each pairing's uniqueness
against the rivals enumerated the same way; and, worked by hand, which options a detection
cannot tell apart and where an established landmark may take a pairing over."""

import itertools

import numpy as np
import pytest

from pipeline.backend.association import chi2_gate
from pipeline.backend.methods.maxmixture.joint_association import (
    NONE,
    DetectionOptions,
    KeyframeProblem,
    associate_keyframe,
    indistinguishable,
    joint_log_likelihood,
    score,
)

H_POSE = np.hstack([np.zeros((3, 3)), -np.eye(3)])
GAMMA = np.eye(3) * 0.05**2
CONFIDENCE = 0.95
AMBIGUITY = 3.0


def random_problem(seed: int, detections: int = 3, landmarks: int = 4) -> KeyframeProblem:
    """Detections with one to three candidate landmarks each (shared between detections), the
    residuals of some a few centimetres, of others a few decimetres; a random joint covariance
    of the pose and the landmarks; priors and null densities of their own."""
    rng = np.random.default_rng(seed)
    n = 6 + 3 * landmarks
    A = rng.normal(size=(n, n)) * 0.04
    covariance = A @ A.T + np.eye(n) * 0.02**2
    dets = []
    for _ in range(detections):
        slots = rng.choice(landmarks, size=int(rng.integers(1, 4)), replace=False)
        k = len(slots)
        residuals = rng.normal(size=(k, 3)) * np.where(rng.random(k) < 0.6, 0.05, 0.3)[:, None]
        dets.append(
            DetectionOptions(
                residuals=residuals,
                pose_jacobians=np.broadcast_to(H_POSE, (k, 3, 6)).copy(),
                landmark_jacobians=np.broadcast_to(np.eye(3), (k, 3, 3)).copy(),
                slots=slots.astype(int),
                log_prior=np.log(rng.uniform(0.2, 0.9, k)),
                covariance=GAMMA,
                null_log_density=float(rng.uniform(-12.0, -2.0)),
            )
        )
    offsets = 6 + 3 * np.arange(landmarks)
    return KeyframeProblem(dets, covariance, offsets, np.full(landmarks, 3), CONFIDENCE)


def search_order(problem: KeyframeProblem, first: int | None = None) -> list[int]:
    """The detections with candidates, fewest first (the required one before all)."""
    order = sorted(
        (i for i, d in enumerate(problem.detections) if len(d.slots)),
        key=lambda i: len(problem.detections[i].slots),
    )
    if first is not None:
        order.remove(first)
        order.insert(0, first)
    return order


def admissible(problem: KeyframeProblem, assignment, order) -> bool:
    """No landmark twice, and every pairing added in `order` keeps the pairs so far inside the
    joint gate of their dimension."""
    pairs = [(i, assignment[i]) for i in order if assignment[i] != NONE]
    slots = [problem.detections[i].slots[k] for i, k in pairs]
    if len(slots) != len(set(slots)):
        return False
    for m in range(1, len(pairs) + 1):
        _, d2 = joint_log_likelihood(problem, pairs[:m])
        if d2 > chi2_gate(3 * m, CONFIDENCE):
            return False
    return True


def enumerated_best(problem: KeyframeProblem, required=None) -> tuple[list[int] | None, float]:
    """The best admissible assignment and its score; with a `required` (detection, option),
    among those that make it (None and -inf where none is admissible)."""
    choices = [[NONE, *range(len(d.slots))] for d in problem.detections]
    if required is not None:
        choices[required[0]] = [required[1]]
    order = search_order(problem, None if required is None else required[0])
    best, best_score = None, -np.inf
    for assignment in itertools.product(*choices):
        if admissible(problem, assignment, order):
            s = score(problem, list(assignment))
            if s > best_score:
                best, best_score = list(assignment), s
    assert best is not None or required is not None  # all to the null is admissible
    return best, best_score


@pytest.mark.parametrize("seed", range(8))
def test_the_best_assignment_is_the_best_of_every_assignment(seed):
    problem = random_problem(seed)
    decision = associate_keyframe(problem, AMBIGUITY, 100_000)
    _, expected_score = enumerated_best(problem)
    assert decision.finished
    assert score(problem, decision.assignment) == pytest.approx(expected_score, rel=1e-9)
    assert admissible(problem, decision.assignment, search_order(problem))


def test_some_random_keyframes_pair_several_detections():
    """The cases above are no trivial ones: most pair two or more detections."""
    paired = [sum(k != NONE for k in enumerated_best(random_problem(seed))[0]) for seed in range(8)]
    assert sum(p >= 2 for p in paired) >= 4


@pytest.mark.parametrize("seed", range(8))
def test_a_pairing_is_unique_where_no_rival_comes_within_the_ambiguity(seed):
    problem = random_problem(seed)
    decision = associate_keyframe(problem, AMBIGUITY, 100_000)
    _, best_score = enumerated_best(problem)
    for i, k in enumerate(decision.assignment):
        if k == NONE:
            assert not decision.unique[i]
            continue
        rivals = [
            enumerated_best(problem, (i, other))[1]
            for other in range(len(problem.detections[i].slots))
            if other != k and not indistinguishable(problem, i, k, other)
        ]
        assert decision.unique[i] == all(r < best_score - AMBIGUITY for r in rivals)


def options(residuals, null_log_density, slots=None, seniority=None, pose_jacobian=H_POSE):
    """One detection's candidates: their residuals (m), landmark Jacobian I, prior 0.9 each."""
    residuals = np.asarray(residuals, dtype=float)
    k = len(residuals)
    return DetectionOptions(
        residuals=residuals,
        pose_jacobians=np.broadcast_to(pose_jacobian, (k, 3, 6)).copy(),
        landmark_jacobians=np.broadcast_to(np.eye(3), (k, 3, 3)).copy(),
        slots=np.arange(k) if slots is None else np.asarray(slots),
        log_prior=np.full(k, np.log(0.9)),
        covariance=GAMMA,
        null_log_density=null_log_density,
        seniority=None if seniority is None else np.asarray(seniority, dtype=float),
    )


def two_estimates(rho: float, difference: float) -> KeyframeProblem:
    """One detection, two candidate landmarks each known to 1 m, correlated by `rho` (one
    landmark mapped twice shares the drift: rho near 1), their predictions `difference` apart;
    the pose known exactly."""
    covariance = np.zeros((12, 12))
    covariance[6:9, 6:9] = covariance[9:12, 9:12] = np.eye(3)
    covariance[6:9, 9:12] = covariance[9:12, 6:9] = rho * np.eye(3)
    det = options([[0.0, 0.0, 0.0], [difference, 0.0, 0.0]], -5.0, pose_jacobian=np.zeros((3, 6)))
    return KeyframeProblem([det], covariance, np.array([6, 9]), np.array([3, 3]), CONFIDENCE)


@pytest.mark.parametrize(("rho", "difference"), [(0.95, 1.0), (0.95, 0.5), (-0.95, 3.0)])
def test_two_options_are_told_apart_by_their_difference_s_covariance(rho, difference):
    """The difference of the two predictions has covariance 2 (1 - rho) I + Gamma."""
    d2 = difference**2 / (2.0 * (1.0 - rho) + GAMMA[0, 0])
    expected = d2 <= chi2_gate(3, CONFIDENCE)
    assert indistinguishable(two_estimates(rho, difference), 0, 0, 1) == expected
    assert indistinguishable(two_estimates(rho, difference), 0, 1, 0) == expected


def test_an_established_landmark_another_detection_holds_does_not_take_a_pairing():
    """Detection 0 fits landmark 0 (new, seniority 1) and, as well within its noise, landmark
    1 (seniority 30); detection 1 fits only landmark 1 and holds it. Detection 0 keeps
    landmark 0: one landmark takes one detection a keyframe."""
    covariance = np.eye(12) * 0.01**2
    covariance[:6, :6] = np.eye(6) * 1e-6
    det0 = options([[0.0, 0.01, 0.0], [0.0, 0.0, 0.0]], -10.0, seniority=[1.0, 30.0])
    det1 = options([[0.0, 0.0, 0.01]], -10.0, slots=[1], seniority=[30.0])
    problem = KeyframeProblem(
        [det0, det1], covariance, np.array([6, 9]), np.array([3, 3]), CONFIDENCE
    )
    decision = associate_keyframe(problem, AMBIGUITY, 10_000)
    assert decision.assignment == [0, 0]


@pytest.mark.parametrize("max_nodes", [6, 8, 12])
def test_a_search_stopped_by_its_budget_decides_nothing_even_with_a_best_so_far(max_nodes):
    """Depth first, the search reaches a full assignment within a handful of nodes (one a
    detection and the leaf): stopped after it, it has a best so far, and still decides
    nothing."""
    problem = random_problem(0)
    assert any(k != NONE for k in associate_keyframe(problem, AMBIGUITY, 100_000).assignment)
    decision = associate_keyframe(problem, AMBIGUITY, max_nodes)
    assert not decision.finished
    assert decision.assignment == [NONE] * 3 and decision.unique == [False] * 3


def test_a_rival_keeps_its_required_pairing_and_is_not_its_detection_s_null():
    """One detection: landmark 0 fits exactly (density 5.19 nats, prior 0.9), landmark 1 is
    a metre off (outside the gate: no rival assignment at all), the null 4.0. Pairing with 0
    adds only 1.1 nats over the null, yet no rival pairs the detection otherwise: unique."""
    covariance = np.eye(12) * 0.05**2
    covariance[:6, :6] = np.eye(6) * 1e-12
    det = options([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], 4.0)
    problem = KeyframeProblem([det], covariance, np.array([6, 9]), np.array([3, 3]), CONFIDENCE)
    paired = -1.5 * np.log(2 * np.pi * 2 * 0.05**2) + np.log(0.9)
    assert score(problem, [0]) == pytest.approx(paired, rel=1e-6)
    assert 0.0 < paired - 4.0 < AMBIGUITY
    rival, rival_score = enumerated_best(problem, (0, 1))
    assert rival is None and np.isneginf(rival_score)  # no assignment pairs it with 1
    decision = associate_keyframe(problem, AMBIGUITY, 10_000)
    assert decision.assignment == [0] and decision.unique == [True]
