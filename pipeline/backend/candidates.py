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
    bearing_elevation_range_jacobian,
    point_residual,
    pose_residual_batch,
    pose_residual_jacobians,
    predict_point,
    world_point_jacobian_pose,
)
from pipeline.backend.landmarks import LandmarkKind, LandmarkMap
from pipeline.backend.measurements import Measurement
from pipeline.backend.solver import Isam2Solver
from pipeline.config import AssociationConfig


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
        joints: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # shared by the keyframe's detections
        return [self._score_one(prediction, pose_cov, m, joints) for m in measurements]

    def _estimate(self, landmark_id: int):
        if self.landmarks.landmarks[landmark_id].kind is LandmarkKind.POSE:
            return self.solver.pose(L(landmark_id))
        return self.solver.point(L(landmark_id))

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
        self, prediction: PosePrediction, pose_cov: np.ndarray, m: Measurement, joints: dict
    ) -> Candidates:
        center, radius = search_radius(
            prediction, pose_cov, m, self.config.search_sigmas, self.config.search_margin_m
        )
        ids = self.landmarks.near(m.kind, center, radius)
        if not ids:
            return Candidates.none()
        gate = assoc.chi2_gate(m.dim, self.config.chi2_confidence)
        R_x = prediction.pose.rotation().matrix()
        t_x = prediction.pose.translation()
        column = self.confusion[:, m.detection.class_id]
        # First pass, no joint marginals: Gamma <= R <= 2 (pose part + landmark part) + Gamma
        # whatever the pose-landmark correlation, which bounds each Mahalanobis distance from
        # both sides. A landmark failing the gate under the larger R fails it for sure.
        plausible = []
        for j in ids:
            semantic = float(column @ self.landmarks.landmarks[j].class_probabilities)
            if semantic <= 0.0:
                continue  # a class the detector never confuses with this one: weight zero
            residual, H_x, H_l = self._residual(m, R_x, t_x, self._estimate(j))
            pose_part = H_x @ pose_cov @ H_x.T
            bound = 2.0 * (pose_part + H_l @ self._landmark_covariance_bound(j) @ H_l.T)
            if assoc.mahalanobis_squared(residual, bound + m.covariance) > gate:
                continue
            plausible.append((j, semantic, residual, H_x, H_l, pose_part))
        if not plausible:
            return Candidates.none(len(ids))
        if len(plausible) == 1:
            j, semantic, residual, *_ = plausible[0]
            if assoc.mahalanobis_squared(residual, m.covariance) <= gate:
                # Passes even under the smaller R and has no rival: weight 1, whatever R is.
                return Candidates(
                    np.array([j]), np.ones(1), np.array([semantic]), np.full(1, np.nan), len(ids)
                )

        kept, log_geo, semantics, maha = [], [], [], []
        for j, semantic, residual, H_x, H_l, pose_part in plausible:
            sigma_xl, sigma_ll = self._joint(prediction, j, joints)
            cross = H_x @ sigma_xl @ H_l.T
            HSH = pose_part + cross + cross.T + H_l @ sigma_ll @ H_l.T
            R = 0.5 * (HSH + HSH.T) + m.covariance
            d2 = assoc.mahalanobis_squared(residual, R)
            if d2 > gate:
                continue
            kept.append(j)
            maha.append(d2)
            log_geo.append(assoc.gaussian_log_density(residual, R))
            semantics.append(semantic)
        if not kept:
            return Candidates.none(len(ids))
        weights = assoc.association_weights(np.array(log_geo), np.array(semantics))
        keep = weights >= self.config.min_weight
        weights = weights[keep] / weights[keep].sum()
        return Candidates(
            landmark_ids=np.array(kept)[keep],
            weights=weights,
            semantic=np.array(semantics)[keep],
            mahalanobis_sq=np.array(maha)[keep],
            searched=len(ids),
        )

    @staticmethod
    def _residual(m: Measurement, R_x, t_x, landmark) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if m.kind is LandmarkKind.POSE:
            R_l, t_l = landmark.rotation().matrix(), landmark.translation()
            residual = pose_residual_batch(
                R_x, t_x, R_l, t_l, m.relative_rotation, m.relative_translation
            )
            H_x, H_l = pose_residual_jacobians(R_x, t_x, R_l, t_l)
            return residual, H_x, H_l
        z_pred, H_x, H_l = predict_point(R_x, t_x, np.asarray(landmark))
        return point_residual(z_pred, m.vector), H_x, H_l
