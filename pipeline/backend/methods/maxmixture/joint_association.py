"""The detections of one keyframe associated together: joint compatibility, scored as one
max-mixture over the keyframe with its pose integrated out.

All of a keyframe's detections share its new pose, whose error after a long drive is the
largest error in every innovation. Chosen one by one at the predicted pose, the one landmark
that happens to fit the drifted prediction wins, while the truthful ones look like outliers;
chosen one by one by their marginal weights, a lookalike can still win. Chosen together, an
assignment of detections to landmarks (or to the null: no landmark seen before) explains the
stacked innovations nu_H with covariance S_H = J Sigma J^T + Gamma, Sigma the joint marginal
covariance of the pose and every landmark involved; its score is the log of

    N(nu_H; 0, S_H) * prod_paired (1 - null_weight) P(report | landmark)
                    * prod_unpaired (null density)

the max-mixture's components with the pose marginalised (Neira and Tardos's joint
compatibility, with a likelihood instead of a count). Branch and bound finds the best
assignment; each pairing in it is kept only if no assignment that pairs its detection with
another landmark scores within `ambiguity_log_odds` of it, so that in an aliased world, where
a shifted assignment explains the keyframe almost as well, nothing is associated on a guess.

Pure numpy: the caller gathers residuals, Jacobians and the joint covariance.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.linalg import solve_triangular

from pipeline.backend.association import LOG_2PI, chi2_gate
from pipeline.backend.budget import SearchBudget

NONE = -1


@dataclass(frozen=True)
class _Stacked:
    """A set of pairs' stacked innovations, by the Cholesky factor L of their covariance S
    (y = L^-1 nu) and their Jacobian's rows J: what one more pair needs to be scored without
    factoring S again (O(m^2 d) instead of O(m^3) for m rows)."""

    L: np.ndarray  # (m, m)
    y: np.ndarray  # (m,)
    J: np.ndarray  # (m, n): rows of the stacked Jacobian over the joint's variables
    log_det: float  # log det S

    @property
    def d2(self) -> float:
        return float(self.y @ self.y)

    @property
    def log_likelihood(self) -> float:
        return -0.5 * (self.d2 + self.log_det + len(self.y) * LOG_2PI)


EMPTY = _Stacked(np.zeros((0, 0)), np.zeros(0), np.zeros((0, 0)), 0.0)
# A node of the assignment search: depth, the pairs (detection, option) so far, the landmark
# slots they hold, their stacked innovations, and the priors of every detection's choice.
Node = tuple[int, list[tuple[int, int]], frozenset[int], _Stacked, float]


@dataclass(frozen=True)
class DetectionOptions:
    """One detection's candidate landmarks at the predicted pose."""

    residuals: np.ndarray  # (c, d): h(x_pred, l_j) - z
    pose_jacobians: np.ndarray  # (c, d, 6)
    landmark_jacobians: np.ndarray  # (c, d, k)
    slots: np.ndarray  # (c,) index of each candidate's landmark block in the covariance
    log_prior: np.ndarray  # (c,) log((1 - null_weight) P(report | landmark))
    covariance: np.ndarray  # (d, d): Gamma
    null_log_density: float  # log of the null component's density for this detection
    # (c,) how established each candidate is (its detections so far): between two candidates
    # the detection cannot tell apart, the established one takes it, so that a landmark mapped
    # twice does not split its detections between the two.
    seniority: np.ndarray | None = None

    @property
    def dim(self) -> int:
        return self.covariance.shape[0]

    def subset(self, options: np.ndarray) -> DetectionOptions:
        """The same detection with only the candidates `options` (indices)."""
        return DetectionOptions(
            self.residuals[options],
            self.pose_jacobians[options],
            self.landmark_jacobians[options],
            self.slots[options],
            self.log_prior[options],
            self.covariance,
            self.null_log_density,
            None if self.seniority is None else self.seniority[options],
        )


@dataclass(frozen=True)
class KeyframeProblem:
    detections: list[DetectionOptions]
    covariance: np.ndarray  # joint over [pose (6) | landmark blocks]
    block_offsets: np.ndarray  # (slots,) first row of each landmark block
    block_dims: np.ndarray  # (slots,)
    gate_confidence: float  # joint compatibility's chi-square confidence
    # (detection, option) -> its rows of J and of J Sigma: the search stacks the same pairs
    # into many trial assignments.
    _rows: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = field(
        default_factory=dict, compare=False, repr=False
    )

    def pair_rows(self, i: int, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Detection i's option k: its rows of the stacked Jacobian J (in the pose and its
        landmark's block) and of J Sigma."""
        rows = self._rows.get((i, k))
        if rows is None:
            det = self.detections[i]
            slot = det.slots[k]
            start, width = self.block_offsets[slot], self.block_dims[slot]
            J = np.zeros((det.dim, self.covariance.shape[0]))
            J[:, :6] = det.pose_jacobians[k]
            J[:, start : start + width] = det.landmark_jacobians[k]
            # J's two blocks times their rows of Sigma: O(d n), where J @ Sigma is O(d n^2)
            J_sigma = (
                det.pose_jacobians[k] @ self.covariance[:6]
                + det.landmark_jacobians[k] @ self.covariance[start : start + width]
            )
            rows = self._rows[i, k] = (J, J_sigma)
        return rows


def _extended(problem: KeyframeProblem, stacked: _Stacked, i: int, k: int) -> _Stacked | None:
    """`stacked` with detection i's option k added: S's new rows are J_new Sigma [J_old; J_new]^T
    plus Gamma, and L grows by a block row (L21 = S_new,old L^-T, L22 L22^T = the rest); None
    where rounding leaves that rest not positive definite."""
    J_new, J_sigma = problem.pair_rows(i, k)
    det = problem.detections[i]
    within = J_sigma @ J_new.T + det.covariance
    if len(stacked.y):
        L21 = solve_triangular(stacked.L, (J_sigma @ stacked.J.T).T, lower=True).T
        within = within - L21 @ L21.T
        rest = det.residuals[k] - L21 @ stacked.y
    else:
        L21 = np.zeros((det.dim, 0))
        rest = det.residuals[k]
    try:
        L22 = np.linalg.cholesky(0.5 * (within + within.T))
    except np.linalg.LinAlgError:
        return None
    m = len(stacked.y)
    L = np.zeros((m + det.dim, m + det.dim))
    L[:m, :m] = stacked.L
    L[m:, :m] = L21
    L[m:, m:] = L22
    y = np.concatenate([stacked.y, solve_triangular(L22, rest, lower=True)])
    J = np.concatenate([stacked.J, J_new]) if m else J_new
    return _Stacked(L, y, J, stacked.log_det + 2.0 * float(np.sum(np.log(np.diag(L22)))))


def stacked_pairs(problem: KeyframeProblem, pairs: list[tuple[int, int]]) -> _Stacked:
    """The stacked innovations of (detection, option) pairs, added one at a time."""
    stacked = EMPTY
    for i, k in pairs:
        grown = _extended(problem, stacked, i, k)
        if grown is None:
            raise np.linalg.LinAlgError("the pairs' innovation covariance is not positive definite")
        stacked = grown
    return stacked


def joint_log_likelihood(
    problem: KeyframeProblem, pairs: list[tuple[int, int]]
) -> tuple[float, float]:
    """(log N(nu; 0, S), nu^T S^-1 nu) of the pairs' stacked innovations."""
    if not pairs:
        return 0.0, 0.0
    stacked = stacked_pairs(problem, pairs)
    return stacked.log_likelihood, stacked.d2


def score(problem: KeyframeProblem, assignment: list[int]) -> float:
    """Log-score of an assignment (option index per detection, NONE for the null)."""
    pairs = [(i, k) for i, k in enumerate(assignment) if k != NONE]
    total, _ = joint_log_likelihood(problem, pairs)
    for i, k in enumerate(assignment):
        det = problem.detections[i]
        total += det.log_prior[k] if k != NONE else det.null_log_density
    return total


def _max_gain(det: DetectionOptions) -> float:
    """An upper bound on what pairing the detection can add over its null: the conditional
    covariance of its innovation is at least Gamma, so its density is at most N(0; Gamma)."""
    if len(det.slots) == 0:
        return 0.0
    _, log_det = np.linalg.slogdet(det.covariance)
    peak = -0.5 * (log_det + det.dim * LOG_2PI)
    return max(0.0, peak + float(np.max(det.log_prior)) - det.null_log_density)


class _Search:
    def __init__(
        self,
        problem: KeyframeProblem,
        max_nodes: int,
        required: tuple[int, int] | None,
        budget: SearchBudget | None = None,
    ):
        self.problem = problem
        self.max_nodes = max_nodes
        self.budget = budget
        self.required = required
        n = len(problem.detections)
        # The detections with candidates, fewest first: the tree narrows fastest. One without
        # any is its null whatever the others do (null_total counts it), so it adds no level.
        self.order = sorted(
            (i for i in range(n) if len(problem.detections[i].slots)),
            key=lambda i: len(problem.detections[i].slots),
        )
        if required is not None:
            self.order.remove(required[0])
            self.order.insert(0, required[0])
        gains = [_max_gain(problem.detections[i]) for i in self.order]
        self.remaining_gain = np.concatenate([np.cumsum(gains[::-1])[::-1], [0.0]])
        self.null_total = sum(d.null_log_density for d in problem.detections)
        total_dim = sum(d.dim for d in problem.detections)
        self.gates = {k: chi2_gate(k, problem.gate_confidence) for k in range(1, total_dim + 1)}
        self.nodes = 0
        self.exhausted = False
        self.best: list[int] | None = None
        self.best_score = -math.inf

    def run(self) -> tuple[list[int] | None, float]:
        """Depth first, branch and bound, on an explicit stack: a keyframe may hold more
        detections with candidates than Python's recursion allows levels. Each frame of the
        stack yields its node's children lazily, in the order a recursion would visit them."""
        stack: list[Iterator[Node]] = []
        self._enter(stack, (0, [], frozenset(), EMPTY, self.null_total))
        while stack and not self.exhausted:
            child = next(stack[-1], None)
            if child is None:
                stack.pop()
            else:
                self._enter(stack, child)
        return self.best, self.best_score

    def _enter(self, stack: list[Iterator[Node]], node: Node) -> None:
        """Visit `node` (depth, pairs, used slots, stacked innovations, priors): bound it,
        take it as the best if it is a full assignment, else push its children."""
        self.nodes += 1
        if self.nodes > self.max_nodes or (self.budget is not None and not self.budget.spend()):
            self.exhausted = True
            return
        depth, pairs, _, stacked, priors = node
        current = stacked.log_likelihood + priors
        if current + self.remaining_gain[depth] <= self.best_score:
            return
        if depth == len(self.order):
            assignment = [NONE] * len(self.problem.detections)
            for i, k in pairs:
                assignment[i] = k
            self.best, self.best_score = assignment, current
            return
        stack.append(self._children(node))

    def _children(self, node: Node) -> Iterator[Node]:
        """The node's detection paired with each option its gate admits, then left to its
        null (not for the required pairing)."""
        depth, pairs, used, stacked, priors = node
        i = self.order[depth]
        det = self.problem.detections[i]
        options = range(len(det.slots))
        if self.required is not None and depth == 0:
            options = [self.required[1]]
        for k in options:
            if det.slots[k] in used:
                continue
            grown = _extended(self.problem, stacked, i, k)
            if grown is None or grown.d2 > self.gates[len(grown.y)]:
                continue
            prior = priors - det.null_log_density + det.log_prior[k]
            yield depth + 1, [*pairs, (i, k)], used | {det.slots[k]}, grown, prior
        if self.required is None or depth > 0:
            yield depth + 1, pairs, used, stacked, priors


def indistinguishable(problem: KeyframeProblem, i: int, k: int, other: int) -> bool:
    """Whether detection i cannot tell its options k and `other` apart: the difference of
    their predictions is within the joint gate of its covariance (the two landmarks' joint
    uncertainty seen through the measurement, plus the measurement's noise). Such landmarks
    are likely one landmark mapped twice, which a merge will join; a choice between them is
    no ambiguity."""
    det = problem.detections[i]
    # J has two blocks, +H_k and -H_other: J Sigma J^T from their blocks of Sigma alone
    blocks = [
        (
            sign * det.landmark_jacobians[option],
            problem.block_offsets[det.slots[option]],
            problem.block_dims[det.slots[option]],
        )
        for option, sign in ((k, 1.0), (other, -1.0))
    ]
    covariance = det.covariance.copy()
    for H_a, a, width_a in blocks:
        for H_b, b, width_b in blocks:
            covariance += H_a @ problem.covariance[a : a + width_a, b : b + width_b] @ H_b.T
    difference = det.residuals[k] - det.residuals[other]
    d2 = float(difference @ np.linalg.solve(covariance, difference))
    return d2 <= chi2_gate(det.dim, problem.gate_confidence)


def alike_in_measurement(problem: KeyframeProblem, i: int, k: int, other: int) -> bool:
    """Whether detection i's options k and `other` predict the same measurement within its own
    noise: two estimates of one landmark, not a lookalike hidden by a large uncertainty."""
    det = problem.detections[i]
    difference = det.residuals[k] - det.residuals[other]
    d2 = float(difference @ np.linalg.solve(det.covariance, difference))
    return d2 <= chi2_gate(det.dim, problem.gate_confidence)


def _to_the_established(problem: KeyframeProblem, assignment: list[int]) -> list[int]:
    """Each pairing moved to the most established candidate (by `seniority`; a candidate that
    would close a loop has none) that predicts the same measurement as the one chosen, where
    no other detection holds that landmark."""
    out = list(assignment)
    used = {problem.detections[i].slots[k] for i, k in enumerate(out) if k != NONE}
    for i, k in enumerate(out):
        det = problem.detections[i]
        if k == NONE or det.seniority is None:
            continue
        for other in np.argsort(-det.seniority, kind="stable"):
            other = int(other)
            if det.seniority[other] <= det.seniority[k]:
                break
            if det.slots[other] not in used and alike_in_measurement(problem, i, k, other):
                used.discard(det.slots[k])
                used.add(det.slots[other])
                out[i] = other
                break
    return out


@dataclass(frozen=True)
class KeyframeDecision:
    assignment: list[int]  # option index per detection, NONE: the null
    unique: list[bool]  # per detection: its pairing has no close rival
    finished: bool  # the search ended within its node budget


def _decide(
    problem: KeyframeProblem,
    ambiguity_log_odds: float,
    max_nodes: int,
    budget: SearchBudget | None,
) -> KeyframeDecision:
    """The best assignment of all the problem's detections, and which of its pairings no rival
    comes close to."""
    n = len(problem.detections)
    search = _Search(problem, max_nodes, None, budget)
    best, best_score = search.run()
    if best is None or search.exhausted:
        return KeyframeDecision([NONE] * n, [False] * n, False)
    best = _to_the_established(problem, best)
    unique = [False] * n
    for i, k in enumerate(best):
        if k == NONE:
            continue
        unique[i] = True
        for other in range(len(problem.detections[i].slots)):
            if other == k or indistinguishable(problem, i, k, other):
                continue
            rival = _Search(problem, max_nodes, (i, other), budget)
            _, rival_score = rival.run()
            if rival.exhausted or rival_score >= best_score - ambiguity_log_odds:
                unique[i] = False
                break
    return KeyframeDecision(best, unique, True)


def detection_groups(problem: KeyframeProblem, max_detections: int) -> list[list[int]]:
    """The detections that have candidates, in groups of at most `max_detections` to be searched
    one after the other: all in one when they fit; else those that may take the same landmark
    (linked through shared candidates) in one group as far as it holds them, the links packed
    into groups in the order of their first detection."""
    with_options = [i for i, det in enumerate(problem.detections) if len(det.slots)]
    if len(with_options) <= max_detections:
        return [with_options] if with_options else []
    parent = {i: i for i in with_options}

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    first_with: dict[int, int] = {}
    for i in with_options:
        for slot in problem.detections[i].slots:
            j = first_with.setdefault(int(slot), i)
            parent[root(i)] = root(j)
    linked: dict[int, list[int]] = {}
    for i in with_options:
        linked.setdefault(root(i), []).append(i)
    groups: list[list[int]] = [[]]
    for members in linked.values():
        for start in range(0, len(members), max_detections):
            part = members[start : start + max_detections]
            if len(groups[-1]) + len(part) > max_detections:
                groups.append([])
            groups[-1].extend(part)
    return groups


def _group_problem(
    problem: KeyframeProblem,
    group: list[int],
    used: set[int],
    given: list[tuple[int, int]],
    given_stacked: _Stacked,
) -> tuple[KeyframeProblem, list[np.ndarray]]:
    """The detections of `group` as a problem of their own: the landmark slots `used` taken out
    of their options, the joint cut down to the pose and the landmarks left (each node's
    arithmetic then grows with the group, not the keyframe), conditioned on the innovations
    of the pairings `given` (their `given_stacked`): a Kalman update, the chain rule of the
    keyframe's likelihood. With the options kept of each detection (indices into its own)."""
    kept = [
        np.flatnonzero([int(slot) not in used for slot in problem.detections[i].slots])
        for i in group
    ]
    detections = [problem.detections[i].subset(keep) for i, keep in zip(group, kept, strict=True)]
    slots = sorted({int(slot) for det in detections for slot in det.slots})
    dims = problem.block_dims[slots]
    offsets = 6 + np.cumsum(dims) - dims  # each block's first row in the cut joint
    rows = np.concatenate(
        [np.arange(6)]
        + [np.arange(o, o + w) for o, w in zip(problem.block_offsets[slots], dims, strict=True)]
    )
    covariance = problem.covariance[np.ix_(rows, rows)]
    shift = np.zeros(len(rows))  # the state's mean given the pairings' innovations
    if given:
        J_sigma = np.concatenate([problem.pair_rows(i, k)[1][:, rows] for i, k in given])
        A = solve_triangular(given_stacked.L, J_sigma, lower=True)  # L^-1 J Sigma
        covariance = covariance - A.T @ A
        shift = A.T @ given_stacked.y
    slot_of = {slot: n for n, slot in enumerate(slots)}
    moved = []
    for det in detections:
        cut_slots = np.array([slot_of[int(slot)] for slot in det.slots], dtype=int)
        predicted = [
            H_x @ shift[:6] + H_l @ shift[o : o + H_l.shape[1]]
            for H_x, H_l, o in zip(
                det.pose_jacobians, det.landmark_jacobians, offsets[cut_slots], strict=True
            )
        ]
        residuals = det.residuals - np.array(predicted).reshape(det.residuals.shape)
        moved.append(replace(det, slots=cut_slots, residuals=residuals))
    cut = KeyframeProblem(
        moved, 0.5 * (covariance + covariance.T), offsets, dims, problem.gate_confidence
    )
    return cut, kept


def associate_keyframe(
    problem: KeyframeProblem,
    ambiguity_log_odds: float,
    max_nodes: int,
    max_detections: int | None = None,
    budget: SearchBudget | None = None,
    heartbeat: Callable[[str], None] | None = None,
) -> KeyframeDecision:
    """The best assignment, and which of its pairings no rival comes close to.

    Bounded work: every search (the best assignment's, each rival's) visits at most `max_nodes`
    nodes and spends them from the keyframe's `budget`; an unfinished search decides nothing
    (its detections go to the null, each a landmark of its own for a merge to join later; a
    rival unfinished leaves its pairing unmade). A keyframe with more than `max_detections`
    detections that have candidates is searched in groups (`detection_groups`), one after
    the other (`_group_problem`), each given the first `max_detections` pairings the groups
    before made, which pin the keyframe's pose: the searches' depth, and each node's
    arithmetic, stay bounded however many detections the keyframe holds. `heartbeat` hears
    which group is searched."""
    n = len(problem.detections)
    max_detections = max_detections or n
    groups = detection_groups(problem, max_detections)
    if len(groups) <= 1:
        return _decide(problem, ambiguity_log_odds, max_nodes, budget)
    assignment, unique, finished = [NONE] * n, [False] * n, True
    used: set[int] = set()
    given: list[tuple[int, int]] = []
    given_stacked = EMPTY
    for g, group in enumerate(groups):
        if heartbeat is not None:
            heartbeat(f"joint association, group {g + 1} of {len(groups)}")
        cut, kept = _group_problem(problem, group, used, given, given_stacked)
        decision = _decide(cut, ambiguity_log_odds, max_nodes, budget)
        finished = finished and decision.finished
        for local, i in enumerate(group):
            k = decision.assignment[local]
            if k == NONE:
                continue
            assignment[i], unique[i] = int(kept[local][k]), decision.unique[local]
            if not unique[i]:
                continue
            used.add(int(problem.detections[i].slots[assignment[i]]))
            if len(given) >= max_detections:  # enough to pin the pose; more would cost O(m^2)
                continue
            grown = _extended(problem, given_stacked, i, assignment[i])
            if grown is not None:
                given, given_stacked = [*given, (i, assignment[i])], grown
    return KeyframeDecision(assignment, unique, finished)
