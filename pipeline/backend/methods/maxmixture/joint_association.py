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
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from pipeline.backend.association import LOG_2PI, chi2_gate

NONE = -1
# A node of the assignment search: depth, the pairs (detection, option) so far, the landmark
# slots they hold, their joint log-likelihood, and the priors of every detection's choice.
Node = tuple[int, list[tuple[int, int]], frozenset[int], float, float]


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
            rows = self._rows[i, k] = (J, J @ self.covariance)
        return rows


def _stack(problem: KeyframeProblem, pairs: list[tuple[int, int]]):
    """Innovations and their covariance S = J Sigma J^T + Gamma for (detection, option) pairs."""
    blocks = [problem.pair_rows(i, k) for i, k in pairs]
    J = np.concatenate([jacobian for jacobian, _ in blocks])
    J_sigma = np.concatenate([product for _, product in blocks])
    nu = np.concatenate([problem.detections[i].residuals[k] for i, k in pairs])
    gamma = np.zeros((len(nu), len(nu)))
    row = 0
    for i, _ in pairs:
        d = problem.detections[i].dim
        gamma[row : row + d, row : row + d] = problem.detections[i].covariance
        row += d
    return nu, J_sigma @ J.T + gamma


def joint_log_likelihood(
    problem: KeyframeProblem, pairs: list[tuple[int, int]]
) -> tuple[float, float]:
    """(log N(nu; 0, S), nu^T S^-1 nu) of the pairs' stacked innovations."""
    if not pairs:
        return 0.0, 0.0
    nu, S = _stack(problem, pairs)
    L = np.linalg.cholesky(0.5 * (S + S.T))
    y = np.linalg.solve(L, nu)
    d2 = float(y @ y)
    log_det = 2.0 * float(np.sum(np.log(np.diag(L))))
    return -0.5 * (d2 + log_det + len(nu) * LOG_2PI), d2


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
    def __init__(self, problem: KeyframeProblem, max_nodes: int, required: tuple[int, int] | None):
        self.problem = problem
        self.max_nodes = max_nodes
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
        self._enter(stack, (0, [], frozenset(), 0.0, self.null_total))
        while stack and not self.exhausted:
            child = next(stack[-1], None)
            if child is None:
                stack.pop()
            else:
                self._enter(stack, child)
        return self.best, self.best_score

    def _enter(self, stack: list[Iterator[Node]], node: Node) -> None:
        """Visit `node` (depth, pairs, used slots, joint log-likelihood, priors): bound it,
        take it as the best if it is a full assignment, else push its children."""
        self.nodes += 1
        if self.nodes > self.max_nodes:
            self.exhausted = True
            return
        depth, pairs, _, log_lik, priors = node
        current = log_lik + priors
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
        depth, pairs, used, log_lik, priors = node
        i = self.order[depth]
        det = self.problem.detections[i]
        options = range(len(det.slots))
        if self.required is not None and depth == 0:
            options = [self.required[1]]
        for k in options:
            if det.slots[k] in used:
                continue
            trial = [*pairs, (i, k)]
            trial_lik, d2 = joint_log_likelihood(self.problem, trial)
            dims = sum(self.problem.detections[a].dim for a, _ in trial)
            if d2 > self.gates[dims]:
                continue
            prior = priors - det.null_log_density + det.log_prior[k]
            yield depth + 1, trial, used | {det.slots[k]}, trial_lik, prior
        if self.required is None or depth > 0:
            yield depth + 1, pairs, used, log_lik, priors


def indistinguishable(problem: KeyframeProblem, i: int, k: int, other: int) -> bool:
    """Whether detection i cannot tell its options k and `other` apart: the difference of
    their predictions is within the joint gate of its covariance (the two landmarks' joint
    uncertainty seen through the measurement, plus the measurement's noise). Such landmarks
    are likely one landmark mapped twice, which a merge will join; a choice between them is
    no ambiguity."""
    det = problem.detections[i]
    n = problem.covariance.shape[0]
    J = np.zeros((det.dim, n))
    for option, sign in ((k, 1.0), (other, -1.0)):
        slot = det.slots[option]
        start, width = problem.block_offsets[slot], problem.block_dims[slot]
        J[:, start : start + width] += sign * det.landmark_jacobians[option]
    covariance = J @ problem.covariance @ J.T + det.covariance
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


def associate_keyframe(
    problem: KeyframeProblem, ambiguity_log_odds: float, max_nodes: int
) -> KeyframeDecision:
    """The best assignment, and which of its pairings no rival comes close to."""
    n = len(problem.detections)
    search = _Search(problem, max_nodes, None)
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
            rival = _Search(problem, max_nodes, (i, other))
            _, rival_score = rival.run()
            if rival.exhausted or rival_score >= best_score - ambiguity_log_odds:
                unique[i] = False
                break
    return KeyframeDecision(best, unique, True)
