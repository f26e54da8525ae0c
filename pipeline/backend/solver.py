"""A thin iSAM2 wrapper: batched factor additions and removals, handles for factors, and the
estimates and marginals the association step asks for.

GTSAM 4.3's Cholesky refuses ("Indeterminate linear system") to eliminate a variable whose
pivot, the information left once the variables eliminated before it are integrated out, is
below 2^-24 of its diagonal: half a double's digits lost (tests/test_planar.py shows it on a
2x2 system). A graph is refused, then, when one of its factors is some 4,000 times more precise
(in sigma) than what the rest leaves of the variable it pins, in the order iSAM2 eliminates.
What did that on valid logs, and what the back-end does instead:
- a detection measured through a projection: a loop closure's first step put a tag behind the
  sensor, its Jacobian vanished and Gauss-Newton diverged (now a Cartesian residual, full rank
  everywhere: `factors.point_measurement_factor`);
- a planar log's height, roll and pitch, left to the odometry's 1 mm / 1 mrad a step: a random
  walk, metres after a thousand keyframes (now the plane is stated: `planar.py`);
- covariances past what the factorisation keeps (a variance of 1e-14 beside 1e-4, a condition
  number of 1e12), a kilometres-long step (now refused by the reader: `pipeline/log/limits`);
- a pose eliminated last in an update, its marginal metres wide against millimetre odometry
  (now the landmarks go last, and an odometry-only update takes the newest landmark along:
  `landmarks_last`).
Should a graph still be refused, the whole graph is solved in batch (Levenberg-Marquardt) and
iSAM2 starts again from that solution; if Cholesky refuses that too, with QR factorisation,
which does without that test, and Dogleg steps, kept from there on. Marginals refused the same
way do the same. Each fallback is recorded (`fallbacks`, metrics.json's `solver_fallbacks`):
a valid log that needs one is a bug to report.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass

import gtsam
import numpy as np

from pipeline.backend.movement import MovementThresholds, is_landmark_key
from pipeline.config import Isam2Config
from pipeline.errors import SolverError

logger = logging.getLogger(__name__)


def gtsam_reason(message: str) -> str:
    """GTSAM's explanation in one line: its first sentence, with the variable it names."""
    lines = [line.strip() for line in message.strip().splitlines()]
    head = []
    for line in lines:
        if not line:
            break
        head.append(line)
    return " ".join(head) or "unknown error"


FALLBACK_KINDS = ("batch", "qr")


@dataclass(frozen=True)
class SolverFallback:
    """A graph Cholesky refused, and what the solver did: "batch" (solved again in batch, iSAM2
    started again there) or "qr" (QR factorisation from then on). Each is a bug to find: a
    valid log is solved without any."""

    update: int  # the iSAM2 update it happened at
    kind: str
    reason: str  # GTSAM's explanation, one line


def fallback_counts(fallbacks: list[SolverFallback]) -> dict[str, int]:
    """How many fallbacks of each kind (every kind listed, zeros included)."""
    counts = Counter(f.kind for f in fallbacks)
    return {kind: counts[kind] for kind in FALLBACK_KINDS}


def landmarks_last(
    graph: gtsam.NonlinearFactorGraph, root: int | None = None, max_last: int | None = None
) -> gtsam.KeyGroupMap:
    """iSAM2's ordering of an update: the variables of its new factors last (GTSAM's default:
    they stay at the root, where the next update finds them), and among them the landmarks
    after the poses. `root`, given for an update without landmarks (odometry alone), is a
    landmark the caller has iSAM2 eliminate again: it goes after the update's poses.

    The variable eliminated last keeps its marginal as its pivot. A pose's marginal grows with
    the drive (14 m across on a KITTI 05 run at noise x3) while its odometry pins it to
    millimetres: as the last, its pivot lost more than the 24 bits Cholesky allows, and a merge
    re-pointing a landmark's detections from fifteen poses was refused, and on another run an
    update holding one odometry step. A landmark's marginal is as wide, but its own
    measurements are centimetres, not millimetres, and the poses before it are then eliminated
    given it: their pivots are their information relative to it.

    An update whose new factors hold more than `max_last` landmarks (a crowded keyframe) puts
    only the newest of them last, and leaves the others to CCOLAMD with the variables it
    re-eliminates: all last, they would make one dense root clique (a keyframe of 1,000 new
    landmarks: 1,001 variables, where each later marginal of any of them took 12 s)."""
    keys = list(graph.keyVector())
    if root is not None:
        keys.append(root)
    landmarks = {key for key in keys if is_landmark_key(key)}
    last = landmarks if max_last is None or len(landmarks) <= max_last else {max(landmarks)}
    # CCOLAMD takes groups 0 .. n - 1 for n variables (those the update re-eliminates, at
    # least these): with two, the pose goes with the variables not constrained.
    first = 1 if len(keys) >= 3 else 0
    groups = gtsam.KeyGroupMap()
    for key in keys:
        if key in last:
            groups.insert2(key, first + 1)
        elif key not in landmarks:
            groups.insert2(key, first)
    return groups


def _landmark_keys(factor: gtsam.NonlinearFactor) -> list[int]:
    keys = factor.keys()  # a KeyVector, not a dict
    return [k for k in keys if is_landmark_key(k)]


def relinearization_thresholds(
    config: Isam2Config, pose_landmarks: bool = False
) -> float | gtsam.ISAM2ThresholdMap:
    """GTSAM's relinearisation threshold: one scalar, or per variable type (poses 'x': rotation
    then translation, in Pose3's tangent order; point landmarks 'l'). GTSAM keys the map by
    symbol letter, so landmarks of two dimensions (points and poses, `pose_landmarks`) take
    the scalar."""
    if not config.per_type_thresholds or pose_landmarks:
        return config.relinearize_threshold
    thresholds = gtsam.ISAM2ThresholdMap()
    rotation, translation = config.pose_rotation_threshold_rad, config.pose_translation_threshold_m
    thresholds.insert(("x", np.array([rotation] * 3 + [translation] * 3)))
    thresholds.insert(("l", np.full(3, config.landmark_threshold_m)))
    return thresholds


def movement_thresholds(config: Isam2Config) -> MovementThresholds:
    """The same thresholds for telling which variables moved after an update."""
    if not config.per_type_thresholds:
        return MovementThresholds.uniform(config.relinearize_threshold)
    return MovementThresholds(
        config.pose_rotation_threshold_rad,
        config.pose_translation_threshold_m,
        config.landmark_threshold_m,
    )


class Isam2Solver:
    """Collects factors and values, then applies them in one iSAM2 update.

    Factors are named by handles (ints given by `add`), because iSAM2 only tells a factor's slot
    after the update that inserts it; `remove` takes a handle of an already committed factor.
    """

    def __init__(self, config: Isam2Config, pose_landmarks: bool = False):
        self.config = config
        self.pose_landmarks = pose_landmarks
        self.factorization = config.factorization
        self.isam = gtsam.ISAM2(self._params(self.factorization))
        self._committed: dict[int, gtsam.NonlinearFactor] = {}  # handle -> factor in iSAM2
        self._pending: dict[int, gtsam.NonlinearFactor] = {}  # handle -> factor, in order
        self._values = gtsam.Values()
        self._removals: list[int] = []
        self._slots: dict[int, int] = {}
        # Committed factors on each landmark, and the newest landmark an update has seen: the
        # root an odometry-only update re-eliminates last (`landmarks_last`).
        self._landmark_factors: Counter[int] = Counter()
        self._root: int | None = None
        self._next_handle = 0
        self.num_updates = 0
        self.fallbacks: list[SolverFallback] = []  # in order

    def _params(self, factorization: str) -> gtsam.ISAM2Params:
        c = self.config
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(relinearization_thresholds(c, self.pose_landmarks))
        params.relinearizeSkip = c.relinearize_skip
        params.enablePartialRelinearizationCheck = c.partial_relinearization_check
        # The QR fallback takes over a graph Cholesky found ill-conditioned, often one a wrong
        # loop closure bent: Gauss-Newton steps there can oscillate (relinearising every
        # variable at every update) and diverge, where Dogleg's trust region converges.
        if factorization == "QR":
            optimisation = gtsam.ISAM2DoglegParams()
        else:
            optimisation = gtsam.ISAM2GaussNewtonParams()
        optimisation.setWildfireThreshold(c.wildfire_threshold)
        params.setOptimizationParams(optimisation)
        params.setFactorization(factorization)
        return params

    def add(self, factor: gtsam.NonlinearFactor) -> int:
        handle = self._next_handle
        self._next_handle += 1
        self._pending[handle] = factor
        return handle

    def insert(self, key: int, value) -> None:
        self._values.insert(key, value)

    def remove(self, handle: int) -> None:
        """Take a factor out: a committed one at the next update, a pending one at once."""
        if self._pending.pop(handle, None) is None:
            self._removals.append(self._slots.pop(handle))
            self._landmark_factors.subtract(_landmark_keys(self._committed.pop(handle)))

    @property
    def has_pending(self) -> bool:
        return bool(self._pending) or bool(self._removals)

    def update(self, anew: bool = False) -> set[int]:
        """Apply what is pending; returns iSAM2's marked keys (new factors' keys, removed
        factors' keys and every relinearised variable): the variables whose estimate moved.

        `anew`: solve the whole graph again in a fresh iSAM2 instead (every key is marked), for
        a change to most factors, which an incremental update would order badly: it eliminates
        the keys of new factors last, and with every pose among them the landmarks' elimination
        joins all the poses they saw into dense cliques that every later step pays for."""
        old = self.isam
        try:
            if anew:
                result = self._rebuild(self.factorization, old.getLinearizationPoint())
            else:
                result = self._incremental()
        except RuntimeError as exc:
            self._check_refusal(exc, f"iSAM2 update {self.num_updates}")
            result = self._solve_again(old.getLinearizationPoint())
        self._clear_pending()
        self.num_updates += 1
        return set(result.getMarkedKeys())

    def _incremental(self) -> gtsam.ISAM2Result:
        graph = gtsam.NonlinearFactorGraph()
        for factor in self._pending.values():
            graph.add(factor)
        params = gtsam.ISAM2UpdateParams()
        params.removeFactorIndices = self._removals
        landmarks = {k for factor in self._pending.values() for k in _landmark_keys(factor)}
        if landmarks:
            self._root = max(landmarks)  # the newest
        root = None
        if not landmarks and self._root is not None and self._landmark_factors[self._root] > 0:
            root = self._root
            extra = gtsam.KeyList()
            extra.push_back(root)
            params.extraReelimKeys = extra
        params.constrainedKeys = landmarks_last(graph, root, self.config.max_root_landmarks)
        result = self.isam.update(graph, self._values, params)
        for handle, slot in zip(self._pending, result.getNewFactorsIndices(), strict=True):
            self._slots[handle] = slot
        return result

    def _clear_pending(self) -> None:
        for factor in self._pending.values():
            self._landmark_factors.update(_landmark_keys(factor))
        self._committed.update(self._pending)
        self._values = gtsam.Values()
        self._pending = {}
        self._removals = []

    def _check_refusal(self, exc: RuntimeError, what: str) -> None:
        """Raise `SolverError` unless `exc` is Cholesky's conditioning test and QR is untried;
        else the batch solve that follows is recorded."""
        reason = gtsam_reason(str(exc))
        if self.factorization == "QR" or "Indeterminate" not in reason:
            raise SolverError(f"{what} failed: {reason}") from exc
        logger.warning("%s: %s; solving the graph again in batch", what, reason)
        self.fallbacks.append(SolverFallback(self.num_updates, "batch", f"{what}: {reason}"))

    def _solve_again(self, theta: gtsam.Values) -> gtsam.ISAM2Result:
        """Everything (`_graph`) solved in batch by Levenberg-Marquardt from `theta`, then a
        new iSAM2 at that solution: with the factorisation so far if it takes it, else with QR.

        Cholesky refuses a graph when an update's step went wrong: a large loop closure whose
        Gauss-Newton step from a poor linearisation bent the stiff odometry, so that one block
        is nearly singular. Incremental steps from there (QR and Dogleg included) kept the bend
        and grew it, to tens of metres with known association (indoor-tags noise x6, a city
        grid); LM's damped iterations undo it, and the conditioning comes back with it."""
        solved, what = theta, "in the batch solve"
        try:
            solved = self._batch_solve(*self._graph(theta))
            what = "after the batch solve"
            return self._rebuild(self.factorization, solved)
        except RuntimeError as exc:
            reason = gtsam_reason(str(exc))
            logger.warning("iSAM2 update %d: %s %s; QR from here", self.num_updates, reason, what)
        return self._rebuild_with_qr(solved)

    def batch_optimum(self) -> tuple[float, float, gtsam.Values]:
        """The graph's cost (GTSAM's error: half the sum of the squared whitened residuals) at
        iSAM2's estimate and at the optimum Levenberg-Marquardt reaches from there, and that
        optimum. iSAM2 relinearises a variable only once its step passes a threshold, so its
        estimate solves the graph as linearised where the variables stood. The factors and
        the linearisation point stay as they were (`data_tools/optimality.py`)."""
        graph, values = self._graph(self.estimate())
        optimum = self._batch_solve(graph, values)
        return graph.error(values), graph.error(optimum), optimum

    def _batch_solve(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> gtsam.Values:
        """Levenberg-Marquardt on `graph` from `values`, at most `batch_iterations` iterations."""
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(self.config.batch_iterations)
        return gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()

    def _rebuild_with_qr(self, theta: gtsam.Values) -> gtsam.ISAM2Result:
        try:
            result = self._rebuild("QR", theta)
        except RuntimeError as exc:
            reason = gtsam_reason(str(exc))
            raise SolverError(f"iSAM2 update {self.num_updates} failed: {reason}") from exc
        reason = "Cholesky refused the graph after a batch solve"
        self.fallbacks.append(SolverFallback(self.num_updates, "qr", reason))
        return result

    def _graph(self, theta: gtsam.Values) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
        """Every factor in the graph (committed, then pending; removals left out) and the
        values to start from: `theta` (the old iSAM2's linearisation point) for the variables
        some factor still holds, and the pending values the old iSAM2 did not take."""
        factors = {**self._committed, **self._pending}
        graph = gtsam.NonlinearFactorGraph()
        keys: set[int] = set()
        for factor in factors.values():
            graph.add(factor)
            keys.update(factor.keys())
        values = gtsam.Values(theta)
        for key in theta.keys():  # noqa: SIM118 - gtsam.Values iterates as a pybind object
            if key not in keys:  # a variable every factor of which was removed
                values.erase(key)
        new = gtsam.Values(self._values)
        for key in new.keys():  # noqa: SIM118
            if values.exists(key):
                new.erase(key)
        values.insert(new)
        return graph, values

    def _rebuild(self, factorization: str, theta: gtsam.Values) -> gtsam.ISAM2Result:
        """A new iSAM2 (`factorization`) given `_graph(theta)`; the handles follow."""
        handles = [*self._committed, *self._pending]
        graph, values = self._graph(theta)
        isam = gtsam.ISAM2(self._params(factorization))
        result = isam.update(graph, values)  # raises before anything here changes
        self.factorization, self.isam = factorization, isam
        self._slots = dict(zip(handles, result.getNewFactorsIndices(), strict=True))
        return result

    def pose(self, key: int) -> gtsam.Pose3:
        return self.isam.calculateEstimatePose3(key)

    def point(self, key: int) -> np.ndarray:
        return self.isam.calculateEstimatePoint3(key)

    def estimate(self) -> gtsam.Values:
        """Every variable's estimate, the back-substitution carried through the whole tree:
        after an update iSAM2 stops it where a variable's step changes by less than the
        wildfire threshold (`[isam2]`, for speed), which left Victoria Park's path with
        centimetre side-slips its millimetre lateral odometry forbids (Known DA's graph cost
        122,774 there, its optimum 3,092; carried through: 3,844). What a replay returns; iSAM2
        keeps the completed step, and the next update starts from it."""
        return self.isam.calculateBestEstimate()

    def estimate_of(self, keys: list[int]) -> gtsam.Values:
        """The estimates of `keys` only, as Values (to evaluate factors on them)."""
        return self.isam.calculateEstimate(keys)

    def flat_estimates(self, keys: list[int], is_pose3: np.ndarray) -> np.ndarray:
        """Estimates of `keys` (sorted, unique) in one call, as rows [R (9, row-major), t (3)];
        a point's rotation part is zero. `is_pose3[i]` tells a Pose3 from a Point3."""
        out = np.zeros((len(keys), 12))
        if not keys:
            return out
        values = self.isam.calculateEstimate(keys)
        if np.any(is_pose3):
            out[is_pose3] = gtsam.utilities.extractPose3(values)
        if not np.all(is_pose3):
            out[~is_pose3, 9:] = gtsam.utilities.extractPoint3(values)
        return out

    def marginal_covariance(self, key: int) -> np.ndarray:
        return self._marginal(lambda: self.isam.marginalCovariance(key))

    def joint_covariance(self, keys: list[int]) -> np.ndarray:
        """Joint marginal covariance of `keys`, blocks in the order given."""
        return self._marginal(lambda: self.isam.jointMarginalCovariance(keys).fullMatrix())

    def _marginal(self, query: Callable[[], np.ndarray]) -> np.ndarray:
        """`query` of the current iSAM2, asked again after a move to QR if Cholesky refuses it.

        Marginals eliminate with the update's factorisation, so Cholesky's conditioning test
        can refuse a variable held only by its weak prior (a landmark every mixture of which
        chose another): the solver solves again as an update would, taking what is pending,
        and moves to QR if Cholesky still refuses the query."""
        what = f"marginals after iSAM2 update {self.num_updates}"
        try:
            return query()
        except RuntimeError as exc:
            self._check_refusal(exc, what)
            self._solve_again(self.isam.getLinearizationPoint())
            self._clear_pending()
        try:
            return query()
        except RuntimeError as exc:  # the batch solve did not help: QR, as an update would
            self._check_refusal(exc, what)
            self._rebuild_with_qr(self.isam.getLinearizationPoint())
            return query()
