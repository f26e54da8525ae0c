"""Scoring the landmarks a detection could be (METHOD.md, "Association weights").

For each detection: landmarks near where it puts its landmark are looked up in the spatial
index; each is scored with R = H Sigma H^T + Gamma, Sigma the *joint* marginal of the new pose
and the landmark. The new pose is not in iSAM2 yet (its odometry enters with the detections, in
one update), so its joint with a landmark is carried over from the previous pose through the
odometry, which is exact to first order: x_t = x_{t-1} * u gives dx_t = Ad(u^-1) dx_{t-1} + n.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L

from pipeline.backend import association as assoc
from pipeline.backend.geometry import (
    point_residual,
    pose_residual_batch,
    pose_residual_jacobians,
    predict_point_jacobians_batch,
    world_point_jacobian_pose,
)
from pipeline.backend.hypotheses import EstimateCache
from pipeline.backend.landmarks import LandmarkKind, LandmarkMap
from pipeline.backend.measurements import Measurement
from pipeline.backend.solver import Isam2Solver
from pipeline.config import AssociationConfig
from pipeline.geometry import bearing_elevation_range_jacobian


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
    """The landmarks that passed the gate, with their association weights (sum 1)."""

    landmark_ids: np.ndarray
    weights: np.ndarray
    semantic: np.ndarray  # P(reported class | landmark)
    mahalanobis_sq: np.ndarray  # NaN where not needed: a sure, lone candidate
    searched: int  # how many landmarks the spatial search returned

    @staticmethod
    def none(searched: int = 0) -> Candidates:
        empty = np.zeros(0)
        return Candidates(np.zeros(0, dtype=int), empty, empty, empty, searched)

    def __len__(self) -> int:
        return len(self.landmark_ids)


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
        R_z = measurement.relative_rotation
        body_cov = R_z @ measurement.covariance[3:, 3:] @ R_z.T
    else:
        Jz = np.linalg.inv(bearing_elevation_range_jacobian(p_body))
        body_cov = Jz @ measurement.covariance @ Jz.T
    world_cov = Jx @ pose_covariance @ Jx.T + R @ body_cov @ R.T
    spread = float(np.sqrt(max(np.linalg.eigvalsh(world_cov)[-1], 0.0)))
    return prediction.pose.transformFrom(p_body), sigmas * spread + margin


class CandidateScorer:
    def __init__(
        self,
        solver: Isam2Solver,
        landmarks: LandmarkMap,
        confusion: np.ndarray,
        config: AssociationConfig,
    ):
        self.solver = solver
        self.landmarks = landmarks
        self.confusion = confusion
        self.config = config

    def score(
        self, prediction: PosePrediction, measurements: list[Measurement]
    ) -> list[Candidates]:
        """Candidates of every detection of one keyframe."""
        if not measurements or len(self.landmarks) == 0:
            return [Candidates.none() for _ in measurements]
        pose_cov = prediction.covariance(self.solver.marginal_covariance(prediction.anchor_key))
        nearby = []
        for m in measurements:
            center, radius = search_radius(
                prediction, pose_cov, m, self.config.search_sigmas, self.config.search_margin_m
            )
            nearby.append(self.landmarks.near(m.kind, center, radius))
        estimates = EstimateCache(self.solver, self.landmarks.is_pose)
        estimates.fetch([], set().union(*nearby))
        joints: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # shared by the keyframe's detections
        return [
            self._score_one(prediction, pose_cov, m, ids, estimates, joints)
            for m, ids in zip(measurements, nearby, strict=True)
        ]

    def _landmark_covariance_bound(self, landmark_id: int) -> np.ndarray:
        """The landmark's marginal covariance as last computed. It only shrinks as factors come
        in, so an old one bounds it from above; removing a factor from the landmark forgets it
        (`Landmark.covariance_bound = None`)."""
        landmark = self.landmarks.landmarks[landmark_id]
        if landmark.covariance_bound is None:
            landmark.covariance_bound = self.solver.marginal_covariance(L(landmark_id))
        return landmark.covariance_bound

    def _joint(self, prediction: PosePrediction, landmark_id: int, joints: dict):
        """(Sigma_xl, Sigma_ll) of the new pose and the landmark, from iSAM2's joint marginal of
        the anchor pose and the landmark. Pairwise: GTSAM answers two keys from the Bayes tree,
        but more than two by eliminating the whole graph. Without joint marginals (config), the
        landmark's marginal and no cross-covariance."""
        if landmark_id in joints:
            return joints[landmark_id]
        key = L(landmark_id)
        if self.config.joint_marginals:
            joint = self.solver.joint_covariance([prediction.anchor_key, key])
            sigma_xl, sigma_ll = prediction.transport @ joint[:6, 6:], joint[6:, 6:]
        else:
            sigma_ll = self.solver.marginal_covariance(key)
            sigma_xl = np.zeros((6, sigma_ll.shape[0]))
        self.landmarks.landmarks[landmark_id].covariance_bound = sigma_ll
        joints[landmark_id] = (sigma_xl, sigma_ll)
        return joints[landmark_id]

    def _score_one(
        self,
        prediction: PosePrediction,
        pose_cov: np.ndarray,
        m: Measurement,
        ids: list[int],
        estimates: EstimateCache,
        joints: dict,
    ) -> Candidates:
        if not ids:
            return Candidates.none()
        searched = len(ids)
        column = self.confusion[:, m.detection.class_id]
        semantic = np.array([column @ self.landmarks.landmarks[j].class_probabilities for j in ids])
        # A class the detector never confuses with this one: weight zero, no need to look.
        ids = [j for j, s in zip(ids, semantic, strict=True) if s > 0.0]
        semantic = semantic[semantic > 0.0]
        if not ids:
            return Candidates.none(searched)
        gate = assoc.chi2_gate(m.dim, self.config.chi2_confidence)
        residual, H_x, H_l = self._residuals(m, prediction, ids, estimates)
        pose_part = H_x @ pose_cov @ np.swapaxes(H_x, 1, 2)
        # First, no joint marginals: Gamma <= R <= 2 (pose part + landmark part) + Gamma,
        # whatever the pose-landmark correlation, which bounds each Mahalanobis distance from
        # both sides. A landmark failing the gate under the larger R fails it for sure.
        landmark_cov = np.stack([self._landmark_covariance_bound(j) for j in ids])
        landmark_part = H_l @ landmark_cov @ np.swapaxes(H_l, 1, 2)
        bound = 2.0 * (pose_part + landmark_part) + m.covariance
        plausible = np.flatnonzero(assoc.mahalanobis_squared_batch(residual, bound) <= gate)
        if len(plausible) == 0:
            return Candidates.none(searched)
        if len(plausible) == 1:
            k = plausible[0]
            if assoc.mahalanobis_squared(residual[k], m.covariance) <= gate:
                # Passes even under the smaller R and has no rival: weight 1, whatever R is.
                return Candidates(
                    np.array([ids[k]]), np.ones(1), semantic[[k]], np.full(1, np.nan), searched
                )

        sigmas = [self._joint(prediction, ids[k], joints) for k in plausible]
        sigma_xl = np.stack([s[0] for s in sigmas])
        sigma_ll = np.stack([s[1] for s in sigmas])
        hx, hl = H_x[plausible], H_l[plausible]
        cross = hx @ sigma_xl @ np.swapaxes(hl, 1, 2)
        R = (
            pose_part[plausible]
            + cross
            + np.swapaxes(cross, 1, 2)
            + hl @ sigma_ll @ np.swapaxes(hl, 1, 2)
            + m.covariance
        )
        R = 0.5 * (R + np.swapaxes(R, 1, 2))
        d2 = assoc.mahalanobis_squared_batch(residual[plausible], R)
        passed = d2 <= gate
        if not np.any(passed):
            return Candidates.none(searched)
        chosen = plausible[passed]
        log_geo = assoc.gaussian_log_density_batch(residual[chosen], R[passed])
        weights = assoc.association_weights(log_geo, semantic[chosen])
        keep = weights >= self.config.min_weight
        return Candidates(
            landmark_ids=np.array(ids)[chosen][keep],
            weights=weights[keep] / weights[keep].sum(),
            semantic=semantic[chosen][keep],
            mahalanobis_sq=d2[passed][keep],
            searched=searched,
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
