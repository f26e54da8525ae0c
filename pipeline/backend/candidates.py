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
from pipeline.geometry import point_from_bearing_elevation_range


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
    searched: int  # how many landmarks the spatial search returned
    # Of each landmark kept, once scored (`scored`): h(x, l) - z, its Jacobians, H_x P H_x^T.
    residual: np.ndarray | None = None
    H_x: np.ndarray | None = None
    H_l: np.ndarray | None = None
    pose_part: np.ndarray | None = None
    sure: Candidates | None = None  # decided without joint marginals

    @staticmethod
    def unscored(ids: list[int], semantic: np.ndarray) -> _Screened:
        """The landmarks found near, less those of a class the detector never confuses with
        the reported one (weight zero: no need to look)."""
        keep = semantic > 0.0
        out = _Screened(np.array(ids, dtype=int)[keep], semantic[keep], len(ids))
        if not np.any(keep):
            out.sure = Candidates.none(len(ids))
        return out

    def scored(
        self,
        kept: np.ndarray,
        residual: np.ndarray,
        H_x: np.ndarray,
        H_l: np.ndarray,
        pose_part: np.ndarray,
        covariance: np.ndarray,
        sure_gate: float,
    ) -> _Screened:
        """The landmarks `kept` by the cheap bound, with their residuals and Jacobians; sure
        when nothing is left, or one landmark that passes even under the smaller R (Gamma) and
        has no rival: weight 1, whatever R is."""
        out = _Screened(
            self.ids[kept], self.semantic[kept], self.searched, residual, H_x, H_l, pose_part
        )
        if len(kept) == 0:
            out.sure = Candidates.none(self.searched)
        elif len(kept) == 1:
            fit = assoc.mahalanobis_squared(residual[0], covariance)
            if fit <= sure_gate:
                out.sure = Candidates(
                    out.ids, np.ones(1), out.semantic, np.full(1, np.nan), self.searched,
                    np.array([fit]),
                )  # fmt: skip
        return out


def _spans(counts: list[int]) -> list[np.ndarray]:
    """Indices of each detection's pairs in the keyframe's stacked pairs, `counts[i]` each."""
    ends = np.cumsum(counts)
    return [np.arange(end - count, end) for end, count in zip(ends, counts, strict=True)]


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


def search_regions(
    prediction: PosePrediction,
    pose_covariance: np.ndarray,
    measurements: list[Measurement],
    sigmas: float,
    margin: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Where each detection of a keyframe puts its landmark in the world (n, 3), and how far
    to look around it (n,): `sigmas` times the largest spread of that point, the predicted
    pose's uncertainty and the detection's own, plus `margin`."""
    R = prediction.pose.rotation().matrix()
    is_pose = np.array([m.kind is LandmarkKind.POSE for m in measurements])
    p_body = np.empty((len(measurements), 3))
    measured = np.empty((len(measurements), 3, 3))
    points = [m for m in measurements if m.kind is LandmarkKind.POINT]
    if points:
        vectors = np.array([m.vector for m in points])
        p_body[~is_pose] = point_from_bearing_elevation_range(vectors)
        covariances = np.array([m.covariance for m in points])
        measured[~is_pose] = world_point_covariance(R, vectors, covariances)
    poses = [m for m in measurements if m.kind is LandmarkKind.POSE]
    if poses:
        p_body[is_pose] = np.array([m.relative_translation for m in poses])
        R_z = R @ np.array([m.relative_rotation for m in poses])
        translation_covariance = np.array([m.covariance[3:, 3:] for m in poses])
        measured[is_pose] = R_z @ translation_covariance @ np.swapaxes(R_z, 1, 2)
    Jx = world_point_jacobian_pose(R, p_body)
    world_cov = Jx @ pose_covariance @ np.swapaxes(Jx, 1, 2) + measured
    spread = np.sqrt(np.maximum(np.linalg.eigvalsh(world_cov)[:, -1], 0.0))
    return p_body @ R.T + prediction.pose.translation(), sigmas * spread + margin


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
        """`keep_joint`: return the keyframe's whole joint covariance (`score`) and every
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

    def score(
        self,
        prediction: PosePrediction,
        measurements: list[Measurement],
        is_recent: Callable[[int], bool] | None = None,
        full: bool = False,
    ) -> tuple[list[Candidates], KeyframeCovariance | None]:
        """Candidates of every detection of one keyframe, and (`keep_joint`) the new pose's
        joint covariance with every candidate, where the joint marginals were asked.

        Cheap bounds first screen each detection's nearby landmarks; the joint marginals of the
        anchor pose and every landmark still in play, for all the keyframe's detections at
        once, come from one iSAM2 query (one walk of the Bayes tree instead of one a pair).
        Every (detection, landmark) pair of the keyframe is scored in a few array operations.

        Keeping the joint (`keep_joint`), a keyframe whose every detection is sure (a lone
        candidate that fits even without the pose's and landmark's uncertainty, each its own,
        each seen lately: `is_recent`) needs no joint test, and gets none unless `full`."""
        if not measurements or len(self.landmarks) == 0:
            return [Candidates.none() for _ in measurements], None
        pose_cov = prediction.covariance(self.solver.marginal_covariance(prediction.anchor_key))
        if not (np.all(np.isfinite(pose_cov)) and np.all(np.isfinite(prediction.pose.matrix()))):
            raise SolverError(
                f"the estimate diverged: {gtsam.DefaultKeyFormatter(prediction.anchor_key)} "
                "or its covariance is not finite"
            )
        centers, radii = search_regions(
            prediction, pose_cov, measurements, self.config.search_sigmas,
            self.config.search_margin_m,
        )  # fmt: skip
        nearby = self.landmarks.near_many([m.kind for m in measurements], centers, radii)
        estimates = EstimateCache(self.solver, self.landmarks.is_pose)
        estimates.fetch([], set().union(*nearby))
        screened = self._screen(prediction, pose_cov, measurements, nearby, estimates)
        if not self.keep_joint:
            wanted = sorted({int(j) for s in screened if s.sure is None for j in s.ids})
            to_finish = [i for i, s in enumerate(screened) if s.sure is None]
        elif not full and _all_sure(screened, is_recent):
            return [s.sure for s in screened], None  # type: ignore[misc]
        else:
            wanted = sorted({int(j) for s in screened for j in s.ids})
            to_finish = [i for i, s in enumerate(screened) if len(s.ids)]
        joints, keyframe_joint = self._joints(prediction, wanted)
        out = [s.sure if s.sure is not None else Candidates.none(s.searched) for s in screened]
        finished = self._finish(
            [measurements[i] for i in to_finish], [screened[i] for i in to_finish], joints
        )
        for i, candidates in zip(to_finish, finished, strict=True):
            out[i] = candidates
        return out, keyframe_joint

    def _joints(
        self, prediction: PosePrediction, landmark_ids: list[int]
    ) -> tuple[dict[int, tuple[np.ndarray, np.ndarray]], KeyframeCovariance | None]:
        """(Sigma_xl, Sigma_ll) of the new pose and each landmark, from iSAM2's joint marginal
        of the anchor pose and the landmarks (one query); without joint marginals (config),
        each landmark's marginal and no cross-covariance. With `keep_joint`, also the new
        pose's whole joint with the landmarks."""
        if not landmark_ids:
            return {}, None
        out: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        keyframe_joint = None
        if self.config.joint_marginals or self.keep_joint:
            keys = [L(j) for j in landmark_ids]
            joint = self.solver.joint_covariance([prediction.anchor_key, *keys])
            if self.keep_joint:
                keyframe_joint = self._transported(prediction, joint, landmark_ids)
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
        return out, keyframe_joint

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
        measurements: list[Measurement],
        nearby: list[list[int]],
        estimates: EstimateCache,
    ) -> list[_Screened]:
        """Each detection's nearby landmarks screened without joint marginals: R lies between
        Gamma and 2 (pose part + landmark part) + Gamma whatever the pose-landmark correlation,
        which bounds each Mahalanobis distance from both sides. A landmark failing the gate
        under the larger R fails it for sure. The pairs of each kind of landmark are scored
        together."""
        lms = self.landmarks.landmarks
        out: list[_Screened] = []
        for m, ids in zip(measurements, nearby, strict=True):
            column = self.confusion[:, m.detection.class_id]
            semantic = np.array([column @ lms[j].class_probabilities for j in ids])
            out.append(_Screened.unscored(ids, semantic))
        for kind in LandmarkKind:
            rows = [i for i, m in enumerate(measurements) if m.kind is kind and len(out[i].ids)]
            if not rows:
                continue
            counts = [len(out[i].ids) for i in rows]
            det = np.repeat(rows, counts)
            ids = np.concatenate([out[i].ids for i in rows])
            residual, H_x, H_l = self._residuals(
                kind, [measurements[i] for i in det], prediction, ids, estimates
            )
            pose_part = H_x @ pose_cov @ np.swapaxes(H_x, 1, 2)
            landmark_cov = np.stack([covariance_bound(self.solver, self.landmarks, j) for j in ids])
            landmark_part = H_l @ landmark_cov @ np.swapaxes(H_l, 1, 2)
            gamma = np.repeat([measurements[i].covariance for i in rows], counts, axis=0)
            bound_d2 = assoc.mahalanobis_squared_batch(
                residual, 2.0 * (pose_part + landmark_part) + gamma
            )
            dim = measurements[rows[0]].dim
            gate = assoc.chi2_gate(dim, self.confidence)
            sure_gate = assoc.chi2_gate(dim, self.config.chi2_confidence)
            for i, pairs in zip(rows, _spans(counts), strict=True):
                plausible = np.flatnonzero(bound_d2[pairs] <= gate)
                # After a long drift every landmark for tens of metres passes: the nearest few.
                plausible = plausible[np.argsort(bound_d2[pairs][plausible], kind="stable")]
                kept = pairs[np.sort(plausible[: self.config.max_candidates])]
                out[i] = out[i].scored(
                    kept - pairs[0], residual[kept], H_x[kept], H_l[kept], pose_part[kept],
                    measurements[i].covariance, sure_gate,
                )  # fmt: skip
        return out

    def _finish(
        self,
        measurements: list[Measurement],
        screened: list[_Screened],
        joints: dict[int, tuple[np.ndarray, np.ndarray]],
    ) -> list[Candidates]:
        """Gate and weigh screened detections' landmarks with R from the joint marginals; the
        pairs of each kind of landmark in one batch."""
        out: list[Candidates] = [Candidates.none(s.searched) for s in screened]
        for kind in LandmarkKind:
            rows = [i for i, m in enumerate(measurements) if m.kind is kind]
            if not rows:
                continue
            counts = [len(screened[i].ids) for i in rows]
            ids = np.concatenate([screened[i].ids for i in rows])
            sigma_xl = np.stack([joints[int(j)][0] for j in ids])
            sigma_ll = np.stack([joints[int(j)][1] for j in ids])
            hx = np.concatenate([screened[i].H_x for i in rows])
            hl = np.concatenate([screened[i].H_l for i in rows])
            residual = np.concatenate([screened[i].residual for i in rows])
            cross = hx @ sigma_xl @ np.swapaxes(hl, 1, 2)
            R = np.concatenate([screened[i].pose_part for i in rows])
            R = R + cross + np.swapaxes(cross, 1, 2) + hl @ sigma_ll @ np.swapaxes(hl, 1, 2)
            R = R + np.repeat([measurements[i].covariance for i in rows], counts, axis=0)
            R = 0.5 * (R + np.swapaxes(R, 1, 2))
            d2 = assoc.mahalanobis_squared_batch(residual, R)
            passed = d2 <= assoc.chi2_gate(measurements[rows[0]].dim, self.confidence)
            log_geo = np.full(len(d2), -np.inf)
            if np.any(passed):
                log_geo[passed] = assoc.gaussian_log_density_batch(residual[passed], R[passed])
            for i, pairs in zip(rows, _spans(counts), strict=True):
                gated = pairs[passed[pairs]]
                if len(gated):
                    out[i] = self._weighed(
                        measurements[i], screened[i], gated - pairs[0], log_geo[gated],
                        d2[gated], R[gated],
                    )  # fmt: skip
        return out

    def _weighed(
        self,
        m: Measurement,
        s: _Screened,
        passed: np.ndarray,
        log_geo: np.ndarray,
        d2: np.ndarray,
        R: np.ndarray,
    ) -> Candidates:
        """The candidates of one detection from its pairs that passed the gate (`passed`: their
        indices among its screened ones)."""
        weights = assoc.association_weights(log_geo, s.semantic[passed])
        keep = weights >= self.config.min_weight
        kept = passed[keep]
        fit = np.einsum("ki,ij,kj->k", s.residual[kept], m.information, s.residual[kept])
        return Candidates(
            landmark_ids=s.ids[kept],
            weights=weights[keep] / weights[keep].sum(),
            semantic=s.semantic[kept],
            mahalanobis_sq=d2[keep],
            searched=s.searched,
            fit_sq=fit,
            residuals=s.residual[kept] if self.keep_joint else None,
            pose_jacobians=s.H_x[kept] if self.keep_joint else None,
            landmark_jacobians=s.H_l[kept] if self.keep_joint else None,
        )

    @staticmethod
    def _residuals(
        kind: LandmarkKind,
        measurements: list[Measurement],
        prediction: PosePrediction,
        ids: np.ndarray,
        estimates: EstimateCache,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Residual h(x, l) - z and Jacobians of each (detection, landmark) pair, stacked:
        `measurements[k]` (all of `kind`) paired with landmark `ids[k]`."""
        R_x = prediction.pose.rotation().matrix()
        t_x = prediction.pose.translation()
        rows = estimates.rows([L(int(j)) for j in ids])
        if kind is LandmarkKind.POSE:
            R_l, t_l = rows[:, :9].reshape(-1, 3, 3), rows[:, 9:]
            residual = pose_residual_batch(
                R_x, t_x, R_l, t_l,
                np.array([m.relative_rotation for m in measurements]),
                np.array([m.relative_translation for m in measurements]),
            )  # fmt: skip
            H_x, H_l = pose_residual_jacobians(R_x, t_x, R_l, t_l)
            return residual, H_x, H_l
        z_pred, H_x, H_l = predict_point_jacobians_batch(R_x, t_x, rows[:, 9:])
        return point_residual(z_pred, np.array([m.vector for m in measurements])), H_x, H_l
