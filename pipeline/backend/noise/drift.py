"""The odometry's noise per direction, from drift windows: the odometry composed over a window
of keyframes against the estimate's relative pose of the window's ends.

Over a window of W steps, the odometry's composed step U (covariance Q, each step's noise
carried to the window's end to first order) and the estimate's relative pose T between the
window's ends (covariance C, from iSAM2's joint marginal) differ by delta = Log(U^-1 T). Take
the window's odometry and the rest of the graph as two measurements of T, the odometry's with
the covariance Q_u it was given (the stated one at the scales in use) and the rest's with R:
the estimate fuses them, C^-1 = Q_u^-1 + R^-1, and delta = G (z_odometry - z_rest) with
G = I - C Q_u^-1. If the odometry's true covariance is Q(s) (the stated one at scales s, per
direction), delta ~ N(0, G Q(s) G^T + G R_true G^T), and G R G^T = C - C Q_u^-1 C. What the
rest is decides R_true: landmarks err as stated (R_true = R), but the rest of a loop is the
loop's other odometry, erring as this window's does. Read again once a loop closes, most
windows are decided by the rest of their loop, and taking R_true = R there read an understated
odometry high by up to 1 / (1 - lambda): the yaw at 1937 where the truth is 82 (a
street grid, noise 4), and the wide gates then closed wrong loops. So the rest is taken to err
as the odometry does: in the frame that whitens Q_u, with C = U diag(lambda) U^T,
G = U diag(1 - lambda) U^T and G R_true G^T = M Q_w(s) M^T, M = U diag(sqrt(lambda -
lambda^2)) U^T, Q_w(s) the true covariance whitened: exact for a loop, and where landmarks
decide the rest, a scale read between the statement and the truth (1 + (1 - lambda)(s - 1)
for one direction): a move never overshoots. A direction the rest decides nothing of
(lambda = 1) says nothing of s; one across a loop closure (lambda near 0) says much. Q(s) is
linear in the pair coefficients sqrt(s_i s_j) (`components.py`), so a window is one
`ScaleObservation` of the odometry's six directions, valid whatever scales are in use later:
the windows of every scale are read together.

iSAM2's estimate is relinearised only where it moved: along directions the landmarks leave to
the odometry, a window's discrepancy is about SETTLING_VARIANCE (whitened), not zero.
"""

from __future__ import annotations

import itertools
from collections import deque

import gtsam
import numpy as np

from pipeline.backend.noise.components import ScaleObservation, nonzero_pairs

SETTLING_VARIANCE = 1e-3


def transports(adjoints: np.ndarray) -> np.ndarray:
    """T_k = A_n ... A_{k+1} for the (n, 6, 6) steps' `adjoints` (Ad(step^-1)): how step k's
    right perturbation moves the composed pose at the window's end."""
    out = np.empty_like(adjoints)
    T = np.eye(6)
    for k in range(len(adjoints) - 1, -1, -1):
        out[k] = T
        T = T @ adjoints[k]
    return out


def composed_basis(T: np.ndarray, stated: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """(P, 6, 6): the composed covariance sum_k T_k S_k(s) T_k^T as sum_p c_p(s) basis[p], for
    the steps' (n, 6, 6) transports T and stated covariances."""
    i, j = pairs[:, 0], pairs[:, 1]
    basis = np.einsum("np,nap,nbp->pab", stated[:, i, j], T[:, :, i], T[:, :, j])
    off = i != j
    basis[off] += np.swapaxes(basis[off], 1, 2)
    return basis


def relative_covariance(relative: gtsam.Pose3, joint: np.ndarray) -> np.ndarray:
    """Covariance of T = x_a^-1 x_b from the (12, 12) joint of x_a and x_b: a perturbation
    x_a Exp(e_a), x_b Exp(e_b) moves T by T Exp(e_b - Ad(T^-1) e_a)."""
    J = np.hstack([-relative.inverse().AdjointMap(), np.eye(6)])
    return J @ joint @ J.T


def window_discrepancy(
    T: np.ndarray, steps: list[gtsam.Pose3], estimated: list[gtsam.Pose3]
) -> np.ndarray:
    """Log(U^-1 T_est) of a window to first order, as the sum of its steps' own discrepancies
    carried to its end: sum_k T_k Log(u_k^-1 e_k), u_k the odometry's steps and e_k the
    estimate's. Each step's is small; the window's whole, composed, is bent beyond first order
    by the heading's error (by about theta^2 L / 2 along the way: at KITTI 05's noise x5, 0.16
    m over 50 keyframes where the stated steps allow 0.06 m), which no scale explains."""
    residuals = np.array(
        [gtsam.Pose3.Logmap(u.between(e)) for u, e in zip(steps, estimated, strict=True)]
    )
    return np.einsum("kab,kb->a", T, residuals)


def drift_observation(
    discrepancy: np.ndarray,
    T: np.ndarray,
    stated: np.ndarray,
    relative: gtsam.Pose3,
    joint: np.ndarray,
    used: np.ndarray,
) -> ScaleObservation:
    """One window as an observation of the odometry's scales: its `discrepancy` (the
    odometry's composed step against the estimate's, `window_discrepancy`), the steps'
    transports `T` and stated covariances, the estimate's `relative` pose of the ends and the
    (12, 12) joint covariance of the ends, taken with the odometry at scales `used`."""
    pairs = nonzero_pairs(stated)
    basis = composed_basis(T, stated, pairs)
    Q = np.einsum("p,pab->ab", np.sqrt(used[pairs[:, 0]] * used[pairs[:, 1]]), basis)
    W = np.linalg.inv(np.linalg.cholesky(Q))  # whitens Q: W Q W^T = I
    delta = W @ discrepancy
    C = W @ relative_covariance(relative, joint) @ W.T
    lam, U = np.linalg.eigh(0.5 * (C + C.T))
    lam = np.clip(lam, 0.0, 1.0)  # the estimate knows at most what the odometry says
    GW = ((U * (1.0 - lam)) @ U.T) @ W
    # the rest's part, C - C Q_u^-1 C = M M^T, scaled with the odometry (see the docstring)
    MW = ((U * np.sqrt(lam - lam**2)) @ U.T) @ W
    return ScaleObservation.made(
        delta,
        SETTLING_VARIANCE * np.eye(6),
        GW @ basis @ GW.T + MW @ basis @ MW.T,
        pairs,
        np.asarray(used, dtype=float),
    )


class DriftWindows:
    """The odometry's steps and the windows read from them: of `length` keyframes every
    `every` keyframes, and of `long_length` (if any) every as many, the latest `kept` of them.
    A slow odometry bias drifts more over a long window than white noise of the same step
    sigma, and the loops that must close are long: long windows read it where short ones read
    the white part.

    The windows are read anew at every reading, at the estimate of then: a loop closed
    after a window ended corrects the poses inside it, and its discrepancy then says what the
    loop says of the odometry. Read once, at its end, a window inside a loop not yet closed
    follows the odometry and says nothing; the loops' evidence would reach only the windows
    ending just after each closure (indoors, with few loops, the yaw's scale was learnt a
    thousand keyframes late)."""

    def __init__(self, length: int, long_length: int = 0, kept: int = 40):
        self.length = length
        self.long_length = long_length
        self.windows: deque[tuple[int, int]] = deque(maxlen=kept)  # (first, last) keyframes
        # step k goes from keyframe k to k + 1; those before the oldest window's are dropped
        self._first_step = 0
        self._steps: list[gtsam.Pose3] = []
        self._adjoints: list[np.ndarray] = []
        self._stated: list[np.ndarray] = []

    def add_step(self, step: gtsam.Pose3, stated: np.ndarray) -> None:
        self._steps.append(step)
        self._adjoints.append(step.inverse().AdjointMap())
        self._stated.append(np.asarray(stated, dtype=float))

    def due(self, pose_index: int, every: int) -> list[int]:
        """The window lengths ending at keyframe `pose_index`, checked every `every`
        keyframes: each length whose steps are known, every `every` keyframes or, when longer,
        every its own length, so that no two windows of one length overlap."""
        lengths = [self.length] + ([self.long_length] if self.long_length else [])
        known = self._first_step + len(self._steps)
        return [n for n in lengths if known >= n and pose_index % max(n, every) == 0]

    def open(self, pose_index: int, lengths: list[int]) -> None:
        """Windows of `lengths` ending at keyframe `pose_index` join the open ones; the steps
        no open window reads, nor the longest that may open next, are let go."""
        self.windows.extend((pose_index - n, pose_index) for n in lengths)
        longest = max(self.length, self.long_length)
        firsts = [first for first, _ in self.windows]
        drop = min([*firsts, pose_index - longest]) - self._first_step
        if drop > 0:
            del self._steps[:drop], self._adjoints[:drop], self._stated[:drop]
            self._first_step += drop

    def observe(
        self, first: int, poses: list[gtsam.Pose3], joint: np.ndarray, used: np.ndarray
    ) -> ScaleObservation:
        """The window from keyframe `first` over len(poses) - 1 steps: the estimate's `poses`
        of its keyframes, the (12, 12) joint covariance of its ends, the odometry at `used`."""
        window = slice(first - self._first_step, first - self._first_step + len(poses) - 1)
        steps = self._steps[window]
        estimated = [a.between(b) for a, b in itertools.pairwise(poses)]
        T = transports(np.array(self._adjoints[window]))
        stated = np.array(self._stated[window])
        relative = poses[0].between(poses[-1])
        discrepancy = window_discrepancy(T, steps, estimated)
        return drift_observation(discrepancy, T, stated, relative, joint, used)
