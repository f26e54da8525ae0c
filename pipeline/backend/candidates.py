"""Scoring the landmarks a detection could be (METHOD.md, "Association weights").

For each detection: landmarks near where it puts its landmark are looked up in the spatial
index; each is scored with R = H Sigma H^T + Gamma, Sigma the *joint* marginal of the new pose
and the landmark. The new pose is not in iSAM2 yet (its odometry enters with the detections, in
one update), so its joint with a landmark is carried over from the previous pose through the
odometry, which is exact to first order: x_t = x_{t-1} * u gives dx_t = Ad(u^-1) dx_{t-1} + n.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L

from pipeline.backend import association as assoc
from pipeline.backend.geometry import (
    point_residual,
    pose_residual_batch,
    pose_residual_jacobians,
    predict_point_jacobians_batch,
    world_point_covariance,
    world_point_jacobian_pose,
)
from pipeline.backend.hypotheses import EstimateCache
from pipeline.backend.landmarks import LandmarkKind, LandmarkMap
from pipeline.backend.measurements import Measurement
from pipeline.backend.solver import Isam2Solver
from pipeline.config import AssociationConfig
from pipeline.errors import SolverError


@dataclass(frozen=True)
class PosePrediction:
    """The new pose's estimate and how its uncertainty follows from the anchor pose's."""

    pose_index: int
    anchor_key: int  # the pose already in iSAM2 that this one is predicted from
    pose: gtsam.Pose3
    transport: np.ndarray  # A: dx_new = A dx_anchor + noise
    process: np.ndarray  # Q: the odometry's covariance (zero for the anchor itself)

    def covariance(self, anchor_covariance: np.ndarray) -> np.ndarray:
        A = self.transport
        return A @ anchor_covariance @ A.T + self.process


@dataclass(frozen=True)
class Candidates:
    """The landmarks that passed the gate (chi-square on the Mahalanobis
    distance in R's metric), with their association weights (sum 1). `fit_sq` is each one's
    |h(x, l) - z|^2 in the measurement's own metric (Gamma) at the predicted pose: what a
    max-mixture factor sees at its first linearisation."""

    landmark_ids: np.ndarray
    weights: np.ndarray
    semantic: np.ndarray  # P(reported class | landmark)
    mahalanobis_sq: np.ndarray  # in R's metric; NaN where not needed: a sure, lone candidate
    searched: int  # how many landmarks the spatial search returned
    fit_sq: np.ndarray = field(default_factory=lambda: np.zeros(0))
    # For associating the keyframe's detections jointly (`joint_association.py`), per
    # candidate: h(x_pred, l) - z and its Jacobians in the new pose and in the landmark.
    residuals: np.ndarray | None = None
    pose_jacobians: np.ndarray | None = None
    landmark_jacobians: np.ndarray | None = None
    innovation_covariances: np.ndarray | None = None  # R of each candidate

    @staticmethod
    def none(searched: int = 0) -> Candidates:
        empty = np.zeros(0)
        return Candidates(np.zeros(0, dtype=int), empty, empty, empty, searched, empty)

    def __len__(self) -> int:
        return len(self.landmark_ids)


@dataclass(frozen=True)
class KeyframeCovariance:
    """Joint covariance of the new pose (first 6 rows) and the landmarks of the keyframe's
    candidates (`offsets[j]`: first row of landmark j's block)."""

    matrix: np.ndarray
    offsets: dict[int, int]


@dataclass
class _Screened:
    """One detection after the cheap screening: what the joint marginals are needed for."""

    ids: np.ndarray  # landmarks that may pass the gate
    semantic: np.ndarray
    residual: np.ndarray
    H_x: np.ndarray
    H_l: np.ndarray
    pose_part: np.ndarray
    searched: int
    sure: Candidates | None = None  # decided without joint marginals


def _all_sure(screened: list[_Screened], is_recent: Callable[[int], bool] | None) -> bool:
    """Every detection sure (or with nothing near), no landmark twice, every one seen lately."""
    if any(s.sure is None for s in screened):
        return False
    ids = [int(j) for s in screened for j in s.ids]
    if len(ids) != len(set(ids)):
        return False
    return is_recent is None or all(is_recent(j) for j in ids)


def covariance_bound(solver: Isam2Solver, landmarks: LandmarkMap, landmark_id: int) -> np.ndarray:
    """The landmark's marginal covariance as last computed. It only shrinks as factors come in
    (the map only gains information), so an old one bounds it from above; removing a factor
    from the landmark forgets it (`Landmark.covariance_bound = None`)."""
    landmark = landmarks.landmarks[landmark_id]
    if landmark.covariance_bound is None:
        landmark.covariance_bound = solver.marginal_covariance(L(landmark_id))
    return landmark.covariance_bound


def search_radius(
    prediction: PosePrediction,
    pose_covariance: np.ndarray,
    measurement: Measurement,
    sigmas: float,
    margin: float,
) -> tuple[np.ndarray, float]:
    """Where the detection puts its landmark in the world, and how far to look around it."""
    R = prediction.pose.rotation().matrix()
    p_body = measurement.body_point
    Jx = world_point_jacobian_pose(R, p_body)
    if measurement.kind is LandmarkKind.POSE:
        R_z = R @ measurement.relative_rotation
        measured = R_z @ measurement.covariance[3:, 3:] @ R_z.T
    else:
        measured = world_point_covariance(R, measurement.vector, measurement.covariance)
    world_cov = Jx @ pose_covariance @ Jx.T + measured
    spread = float(np.sqrt(max(np.linalg.eigvalsh(world_cov)[-1], 0.0)))
    return prediction.pose.transformFrom(p_body), sigmas * spread + margin


class CandidateScorer:
    def __init__(
        self,
        solver: Isam2Solver,
        landmarks: LandmarkMap,
        confusion: np.ndarray,
        config: AssociationConfig,
        keep_joint: bool = False,
        wide_gate: bool = False,
    ):
        """`keep_joint`: keep the keyframe's whole joint covariance (`last_joint`) and every
        candidate's residual and Jacobians, for associating the keyframe jointly; the gate is
        then the wider `joint_candidate_confidence`, since the joint test decides. `wide_gate`:
        that gate without the rest, for a method whose own step decides against a new
        landmark."""
        self.solver = solver
        self.landmarks = landmarks
        self.confusion = confusion
        self.config = config
        self.keep_joint = keep_joint
        self.confidence = (
            config.joint_candidate_confidence if keep_joint or wide_gate else config.chi2_confidence
        )
        self.last_joint: KeyframeCovariance | None = None

    def score(
        self,
        prediction: PosePrediction,
        measurements: list[Measurement],
        is_recent: Callable[[int], bool] | None = None,
        full: bool = False,
    ) -> list[Candidates]:
        """Candidates of every detection of one keyframe.

        Cheap bounds first screen each detection's nearby landmarks; the joint marginals of the
        anchor pose and every landmark still in play, for all the keyframe's detections at
        once, come from one iSAM2 query (one walk of the Bayes tree instead of one a pair).

        Keeping the joint (`keep_joint`), a keyframe whose every detection is sure (a lone
        candidate that fits even without the pose's and landmark's uncertainty, each its own,
        each seen lately: `is_recent`) needs no joint test, and gets none unless `full`."""
        self.last_joint = None
        if not measurements or len(self.landmarks) == 0:
            return [Candidates.none() for _ in measurements]
        pose_cov = prediction.covariance(self.solver.marginal_covariance(prediction.anchor_key))
        if not (np.all(np.isfinite(pose_cov)) and np.all(np.isfinite(prediction.pose.matrix()))):
            raise SolverError(
                f"the estimate diverged: {gtsam.DefaultKeyFormatter(prediction.anchor_key)} "
                "or its covariance is not finite"
            )
        nearby = []
        for m in measurements:
            center, radius = search_radius(
                prediction, pose_cov, m, self.config.search_sigmas, self.config.search_margin_m
            )
            nearby.append(self.landmarks.near(m.kind, center, radius))
        estimates = EstimateCache(self.solver, self.landmarks.is_pose)
        estimates.fetch([], set().union(*nearby))
        screened = [
            self._screen(prediction, pose_cov, m, ids, estimates)
            for m, ids in zip(measurements, nearby, strict=True)
        ]
        if not self.keep_joint:
            wanted = sorted({int(j) for s in screened if s.sure is None for j in s.ids})
            joints = self._joints(prediction, wanted)
            return [
                s.sure if s.sure is not None else self._finish(m, s, joints)
                for m, s in zip(measurements, screened, strict=True)
            ]
        if not full and _all_sure(screened, is_recent):
            return [s.sure for s in screened]  # type: ignore[misc]
        wanted = sorted({int(j) for s in screened for j in s.ids})
        joints = self._joints(prediction, wanted)
        return [
            self._finish(m, s, joints) if len(s.ids) else Candidates.none(s.searched)
            for m, s in zip(measurements, screened, strict=True)
        ]

    def _joints(
        self, prediction: PosePrediction, landmark_ids: list[int]
    ) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        """(Sigma_xl, Sigma_ll) of the new pose and each landmark, from iSAM2's joint marginal
        of the anchor pose and the landmarks (one query); without joint marginals (config),
        each landmark's marginal and no cross-covariance."""
        if not landmark_ids:
            return {}
        out: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        if self.config.joint_marginals or self.keep_joint:
            keys = [L(j) for j in landmark_ids]
            joint = self.solver.joint_covariance([prediction.anchor_key, *keys])
            if self.keep_joint:
                self.last_joint = self._transported(prediction, joint, landmark_ids)
            offset = 6
            for j in landmark_ids:
                dim = 6 if self.landmarks.landmarks[j].kind is LandmarkKind.POSE else 3
                block = slice(offset, offset + dim)
                out[j] = (prediction.transport @ joint[:6, block], joint[block, block])
                offset += dim
        else:
            for j in landmark_ids:
                sigma_ll = self.solver.marginal_covariance(L(j))
                out[j] = (np.zeros((6, sigma_ll.shape[0])), sigma_ll)
        for j, (_, sigma_ll) in out.items():
            self.landmarks.landmarks[j].covariance_bound = sigma_ll
        return out

    def _transported(
        self, prediction: PosePrediction, joint: np.ndarray, landmark_ids: list[int]
    ) -> KeyframeCovariance:
        """The anchor pose's joint with the landmarks, carried over to the new pose."""
        A = prediction.transport
        out = joint.copy()
        out[:6, :6] = prediction.covariance(joint[:6, :6])
        out[:6, 6:] = A @ joint[:6, 6:]
        out[6:, :6] = out[:6, 6:].T
        offsets, row = {}, 6
        for j in landmark_ids:
            offsets[j] = row
            row += 6 if self.landmarks.landmarks[j].kind is LandmarkKind.POSE else 3
        return KeyframeCovariance(out, offsets)

    def _screen(
        self,
        prediction: PosePrediction,
        pose_cov: np.ndarray,
        m: Measurement,
        ids: list[int],
        estimates: EstimateCache,
    ) -> _Screened:
        empty = np.zeros(0)
        nothing = _Screened(np.zeros(0, dtype=int), empty, empty, empty, empty, empty, len(ids))
        if not ids:
            nothing.sure = Candidates.none()
            return nothing
        searched = len(ids)
        column = self.confusion[:, m.detection.class_id]
        semantic = np.array([column @ self.landmarks.landmarks[j].class_probabilities for j in ids])
        # A class the detector never confuses with this one: weight zero, no need to look.
        ids = [j for j, s in zip(ids, semantic, strict=True) if s > 0.0]
        semantic = semantic[semantic > 0.0]
        if not ids:
            nothing.sure = Candidates.none(searched)
            return nothing
        gate = assoc.chi2_gate(m.dim, self.confidence)
        residual, H_x, H_l = self._residuals(m, prediction, ids, estimates)
        pose_part = H_x @ pose_cov @ np.swapaxes(H_x, 1, 2)
        # First, no joint marginals: Gamma <= R <= 2 (pose part + landmark part) + Gamma,
        # whatever the pose-landmark correlation, which bounds each Mahalanobis distance from
        # both sides. A landmark failing the gate under the larger R fails it for sure.
        landmark_cov = np.stack([covariance_bound(self.solver, self.landmarks, j) for j in ids])
        landmark_part = H_l @ landmark_cov @ np.swapaxes(H_l, 1, 2)
        bound = 2.0 * (pose_part + landmark_part) + m.covariance
        bound_d2 = assoc.mahalanobis_squared_batch(residual, bound)
        plausible = np.flatnonzero(bound_d2 <= gate)
        # After a long drift every landmark for tens of metres passes: the nearest few only.
        plausible = plausible[np.argsort(bound_d2[plausible], kind="stable")]
        plausible = np.sort(plausible[: self.config.max_candidates])
        out = _Screened(
            np.array(ids)[plausible],
            semantic[plausible],
            residual[plausible],
            H_x[plausible],
            H_l[plausible],
            pose_part[plausible],
            searched,
        )
        if len(plausible) == 0:
            out.sure = Candidates.none(searched)
        elif len(plausible) == 1:
            fit = assoc.mahalanobis_squared(out.residual[0], m.covariance)
            if fit <= assoc.chi2_gate(m.dim, self.config.chi2_confidence):
                # Passes even under the smaller R and has no rival: weight 1, whatever R is.
                out.sure = Candidates(
                    out.ids, np.ones(1), out.semantic, np.full(1, np.nan), searched, np.array([fit])
                )
        return out

    def _finish(
        self, m: Measurement, s: _Screened, joints: dict[int, tuple[np.ndarray, np.ndarray]]
    ) -> Candidates:
        """Gate and weigh a screened detection's landmarks with R from the joint marginals."""
        sigma_xl = np.stack([joints[int(j)][0] for j in s.ids])
        sigma_ll = np.stack([joints[int(j)][1] for j in s.ids])
        hx, hl = s.H_x, s.H_l
        cross = hx @ sigma_xl @ np.swapaxes(hl, 1, 2)
        R = s.pose_part + cross + np.swapaxes(cross, 1, 2) + hl @ sigma_ll @ np.swapaxes(hl, 1, 2)
        R = R + m.covariance
        R = 0.5 * (R + np.swapaxes(R, 1, 2))
        d2 = assoc.mahalanobis_squared_batch(s.residual, R)
        passed = d2 <= assoc.chi2_gate(m.dim, self.confidence)
        if not np.any(passed):
            return Candidates.none(s.searched)
        log_geo = assoc.gaussian_log_density_batch(s.residual[passed], R[passed])
        weights = assoc.association_weights(log_geo, s.semantic[passed])
        keep = weights >= self.config.min_weight
        fit = np.einsum(
            "ki,ij,kj->k", s.residual[passed][keep], m.information, s.residual[passed][keep]
        )
        return Candidates(
            landmark_ids=s.ids[passed][keep],
            weights=weights[keep] / weights[keep].sum(),
            semantic=s.semantic[passed][keep],
            mahalanobis_sq=d2[passed][keep],
            searched=s.searched,
            fit_sq=fit,
            residuals=s.residual[passed][keep] if self.keep_joint else None,
            pose_jacobians=hx[passed][keep] if self.keep_joint else None,
            landmark_jacobians=hl[passed][keep] if self.keep_joint else None,
            innovation_covariances=R[passed][keep] if self.keep_joint else None,
        )

    @staticmethod
    def _residuals(
        m: Measurement, prediction: PosePrediction, ids: list[int], estimates: EstimateCache
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Residual h(x, l) - z and Jacobians for each candidate, stacked."""
        R_x = prediction.pose.rotation().matrix()
        t_x = prediction.pose.translation()
        rows = estimates.rows([L(j) for j in ids])
        if m.kind is LandmarkKind.POSE:
            R_l, t_l = rows[:, :9].reshape(-1, 3, 3), rows[:, 9:]
            residual = pose_residual_batch(
                R_x, t_x, R_l, t_l, m.relative_rotation, m.relative_translation
            )
            H_x, H_l = pose_residual_jacobians(R_x, t_x, R_l, t_l)
            return residual, H_x, H_l
        z_pred, H_x, H_l = predict_point_jacobians_batch(R_x, t_x, rows[:, 9:])
        return point_residual(z_pred, m.vector), H_x, H_l
