"""The back-end: keyframes in, iSAM2 estimate and associations out.

backend = Backend(config, confusion, "mm-nh")
for odometry, detections in keyframes:
    backend.add_keyframe(odometry, detections)
result = backend.result()
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X

from pipeline.backend.candidates import Candidates, CandidateScorer, PosePrediction
from pipeline.backend.factors import odometry_factor, pose_from_message
from pipeline.backend.hypotheses import AssociationRecord
from pipeline.backend.landmarks import LandmarkKind, LandmarkMap
from pipeline.backend.measurements import make_measurement
from pipeline.backend.merges import MergeFinder
from pipeline.backend.methods import BackendContext, make_method
from pipeline.backend.noise import (
    NoiseScales,
    OdometryDrift,
    OdometryScaleMove,
    odometry_scale_move,
    updated,
)
from pipeline.backend.planar import planar_prior_factors
from pipeline.backend.solver import Isam2Solver, SolverFallback, fallback_counts
from pipeline.config import Config
from pipeline.log.messages import Detection, Odometry

logger = logging.getLogger(__name__)

# Cells of the landmark index: about the spread of a search, so a query touches few cells.
INDEX_CELL_SIZE_M = 10.0


@dataclass
class KeyframeReport:
    """What happened at one keyframe: for viewers, progress and benchmarks."""

    pose_index: int
    records: list[AssociationRecord]
    candidates: list[Candidates]
    # Associations this keyframe changed (once each): earlier detections', and its own where
    # refine moved them off their first choice. One that left and came back is not in it.
    switched: list[AssociationRecord]
    seconds: float
    merged: list[tuple[int, int]] = field(default_factory=list)  # (duplicate, survivor) ids
    # Graphs Cholesky refused at this keyframe, and what the solver did (each one a bug)
    solver_fallbacks: list[SolverFallback] = field(default_factory=list)


@dataclass
class BackendResult:
    poses: list[gtsam.Pose3]
    landmark_ids: list[int]
    landmark_values: list  # np.ndarray positions or gtsam.Pose3
    records: list[AssociationRecord]
    landmarks: LandmarkMap
    switches: int = 0
    merges: int = 0
    noise: NoiseScales | None = None  # the noise scales at the end
    odometry_moves: list[OdometryScaleMove] = field(default_factory=list)  # in order
    # what the loops closed by merges said of the odometry's scale (`DriftScaleBelief.report`)
    loop_drift: dict | None = None
    step_seconds: list[float] = field(default_factory=list)
    solver_fallbacks: dict[str, int] = field(default_factory=dict)  # by kind


class Backend:
    def __init__(self, config: Config, confusion: np.ndarray, method: str, planar: bool = False):
        """`planar`: the log moves in a plane, stated as a prior on every pose's height and tilt
        (`pipeline/backend/planar.py`, `[prior] planar`)."""
        self.config = config
        self.planar = planar
        self.solver = Isam2Solver(config.isam2, config.landmarks.use_relative_pose)
        self.landmarks = LandmarkMap(num_classes=confusion.shape[0], cell_size=INDEX_CELL_SIZE_M)
        self.context = BackendContext(self.solver, self.landmarks, confusion, config)
        self.method = make_method(method, self.context)
        self.scorer = CandidateScorer(
            self.solver,
            self.landmarks,
            confusion,
            config.association,
            self.method.wants_joint,
            wide_gate=getattr(self.method, "wide_gate", False),
        )
        self.merger = (
            MergeFinder(
                self.context,
                config.merges,
                config.association.search_margin_m,
                self.method.space[LandmarkKind.POINT],
            )
            if getattr(self.method, "merges_landmarks", False)
            else None
        )
        self.merges = 0
        n = config.noise
        # Only a method that estimates the measurement noise (its sure pairings) rescales.
        self.estimates_noise = n.estimate and self.method.wants_joint
        start = n.odometry_scale
        if self.estimates_noise:  # from odometry_start_scale, never below its floor
            start = max(n.odometry_start_scale, n.odometry_scale)
        self.noise = NoiseScales(start, tuple(n.measurement_scale))
        self.odometry_moves: list[OdometryScaleMove] = []  # in order
        self.drift = (
            OdometryDrift(n.drift_window, n.drift_windows, n.min_drift_windows, n.long_drift_window)
            if self.estimates_noise
            else None
        )
        self.records: list[AssociationRecord] = []
        # (handle, odometry) of each pose's odometry factor, while its scale may change
        self._odometry: list[tuple[int, Odometry]] = []
        self.num_poses = 0
        self.switches = 0
        self.step_seconds: list[float] = []
        # (pose, detection) -> landmark as last reported: refine's rounds may switch a record
        # away and back within one keyframe, which is no change.
        self._reported: dict[tuple[int, int], int] = {}

    def _add_origin(self) -> gtsam.Pose3:
        p = self.config.prior
        sigmas = np.array([p.pose0_sigma_rotation] * 3 + [p.pose0_sigma_translation] * 3)
        origin = gtsam.Pose3()
        self.solver.add(
            gtsam.PriorFactorPose3(X(0), origin, gtsam.noiseModel.Diagonal.Sigmas(sigmas))
        )
        self.solver.insert(X(0), origin)
        self.solver.update()
        return origin

    def predict(self, odometry: Odometry | None) -> PosePrediction:
        """The new pose from the last one and the odometry; pose 0 is the origin."""
        index = self.num_poses
        if odometry is None:
            return PosePrediction(index, X(0), self._add_origin(), np.eye(6), np.zeros((6, 6)))
        step = pose_from_message(odometry.translation, odometry.rotation)
        pose = self.solver.pose(X(index - 1)).compose(step)
        handle, covariance = self._add_odometry(index - 1, odometry)
        if self.drift is not None:
            self.drift.add_step(step, np.reshape(odometry.covariance, (6, 6)))
            self._odometry.append((handle, odometry))
        self.solver.insert(X(index), pose)
        if self.planar:
            p = self.config.prior
            for factor in planar_prior_factors(
                X(index), p.planar_height_sigma_m, p.planar_tilt_sigma_rad
            ):
                self.solver.add(factor)
        return PosePrediction(index, X(index - 1), pose, step.inverse().AdjointMap(), covariance)

    def add_keyframe(
        self, odometry: Odometry | None, detections: list[Detection]
    ) -> KeyframeReport:
        """Predict, score candidates, choose factors, update iSAM2, revisit associations."""
        start = time.perf_counter()
        fallbacks_before = len(self.solver.fallbacks)
        if (odometry is None) != (self.num_poses == 0):
            raise ValueError("odometry is needed for every keyframe but the first")
        prediction = self.predict(odometry)
        self.context.prediction = prediction
        point_scale = self.noise.measurement_matrix()
        use_pose = self.config.landmarks.use_relative_pose
        measurements = [
            make_measurement(prediction.pose_index, k, d, use_pose, point_scale)
            for k, d in enumerate(detections)
        ]
        if self.method.uses_candidates:
            n = self.config.noise
            candidates = self.scorer.score(
                prediction,
                measurements,
                is_recent=lambda j: self.context.seen_lately(j, prediction.pose_index),
                # now and then the whole joint test, so that sure pairings tell the noise too
                full=n.estimate and prediction.pose_index % n.sample_every == 0,
            )
        else:
            candidates = [Candidates.none() for _ in measurements]
        self.context.keyframe_covariance = self.scorer.last_joint
        records = self.method.associate_keyframe(measurements, candidates)
        for record in records:
            self.context.register(record)
        self.records.extend(records)
        for r in records:
            self._reported[r.measurement.pose_index, r.measurement.detection_index] = r.landmark_id
        self.num_poses += 1
        marked = self.solver.update()
        switched: list[AssociationRecord] = []
        if self.method.uses_candidates:  # known association needs no map search or revisits
            switched = self.method.refine(self.context.after_update(marked))
        merged = self.merge(prediction.pose_index)
        if merged:
            switched += self.method.refine(self.context.after_update(self.solver.update()))
        if self._rescale_noise(prediction.pose_index):
            switched += self.method.refine(self.context.after_update(self.solver.update(anew=True)))
        switched = self._changed(switched)
        for record in switched:
            self.context.seen(record)
        self.switches += len(switched)
        seconds = time.perf_counter() - start
        self.step_seconds.append(seconds)
        return KeyframeReport(
            prediction.pose_index,
            records,
            candidates,
            switched,
            seconds,
            merged,
            self.solver.fallbacks[fallbacks_before:],
        )

    def _changed(self, switched: list[AssociationRecord]) -> list[AssociationRecord]:
        """The records among `switched` whose landmark now differs from the one last reported
        (or the landmark that one was merged into), once each, in the order of their first
        switch."""
        changed = []
        for r in {id(r): r for r in switched}.values():
            key = (r.measurement.pose_index, r.measurement.detection_index)
            before = self._reported[key]
            if before >= 0:
                before = self.landmarks.resolve(before)
            if r.landmark_id != before:
                self._reported[key] = r.landmark_id
                changed.append(r)
        return changed

    def _rescale_noise(self, pose_index: int) -> bool:
        """Every few keyframes, the noise scales corrected: the measurement's by the latest
        sure pairings, the odometry's by its drift against the estimate or by the loops closed
        so far. Whether the odometry's changed (every odometry factor is then reweighted,
        pending: the graph is to be solved anew)."""
        n = self.config.noise
        if not self.estimates_noise or pose_index % n.update_every:
            return False
        measurement = self.context.innovations.corrections()
        if measurement is not None:
            self.noise = updated(self.noise, measurement, (n.min_scale, n.max_scale), n.max_step)
            self.context.innovations.clear()  # they were whitened with the scales replaced
        logger.debug("pose %d: noise scales %s", pose_index, self.noise)
        moves = self._odometry_moves(pose_index)
        if not moves:
            return False
        move = max(moves, key=lambda m: m.after)
        self.odometry_moves.append(move)
        logger.debug(
            "pose %d: odometry scale %.3g -> %.3g (%s, %.1f nats)",
            pose_index,
            move.before,
            move.after,
            move.source,
            move.evidence,
        )
        self.noise = NoiseScales(move.after, self.noise.measurement)
        self._reweight_odometry()
        return True

    def _odometry_moves(self, pose_index: int) -> list[OdometryScaleMove]:
        """The clear moves (`odometry_scale_move`) of the odometry's scale that the drift
        windows ending now and the loops the merges closed so far say (the loops' only up: a
        loop that closes at the current scale says little of a smaller one)."""
        n, current = self.config.noise, self.noise.odometry
        readings = []
        windows = self._drift_reading(pose_index)
        if windows is not None:
            # Down only to undo a start set above the floor (odometry_scale): once the windows
            # have raised the scale, a map bent by the loops it let close reads unevenly, and
            # coming down again made kitti05-cars (noise x3, calibrated, seed 5) 10.4 -> 16.6 m.
            down = not any(m.after > m.before for m in self.odometry_moves)
            readings.append(("windows", *windows, down))
        if n.scale_from_loops and self.merger is not None:
            loops = self.merger.drift_belief.reading(current)
            if loops is not None:
                readings.append(("loops", min(loops[0], n.max_scale), loops[1], False))
        moves = []
        for source, scale, evidence, down in readings:
            after = odometry_scale_move(
                current, scale, evidence, n.drift_deadband, n.drift_evidence, down=down
            )
            if after is not None:
                moves.append(OdometryScaleMove(pose_index, current, after, evidence, source))
        return moves

    def _drift_reading(self, pose_index: int) -> tuple[float, float] | None:
        """The odometry's scale its windows say and their evidence, with the windows ending
        now."""
        if self.drift is None:
            return None
        n = self.config.noise
        last = X(pose_index)
        last_pose = self.solver.pose(last)
        for length in self.drift.due(pose_index, n.update_every):
            first = X(pose_index - length)
            relative = self.solver.pose(first).between(last_pose)
            joint = self.solver.joint_covariance([first, last])
            self.drift.observe(relative, joint, self.noise.odometry, length)
        return self.drift.reading((n.odometry_scale, n.max_scale))

    def _add_odometry(self, k: int, odometry: Odometry) -> tuple[int, np.ndarray]:
        """The factor of `odometry` from pose k to k + 1, its stated covariance at the
        odometry's current scale, added to the solver: (its handle, that covariance)."""
        covariance = self.noise.odometry * np.reshape(odometry.covariance, (6, 6))
        return self.solver.add(odometry_factor(X(k), X(k + 1), odometry, covariance)), covariance

    def _reweight_odometry(self) -> None:
        """Every odometry factor again with the odometry's current scale. The whole map's
        uncertainty changes with it: the landmarks' covariance bounds are forgotten."""
        for k, (handle, odometry) in enumerate(self._odometry):
            self.solver.remove(handle)
            self._odometry[k] = (self._add_odometry(k, odometry)[0], odometry)
        for landmark in self.landmarks.landmarks.values():
            landmark.covariance_bound = None

    def merge(self, pose_index: int) -> list[tuple[int, int]]:
        """Merge duplicated landmarks (every few keyframes); the merges stay pending in iSAM2."""
        if self.merger is None or pose_index % self.config.merges.every_keyframes:
            return []
        merged = self.merger.find(pose_index, self.noise.odometry)
        for duplicate, survivor in merged:
            self.method.merge(survivor, duplicate)
        self.merges += len(merged)
        return merged

    def result(self) -> BackendResult:
        self.method.finish()
        values = self.solver.estimate()
        poses = [values.atPose3(X(i)) for i in range(self.num_poses)]
        ids = sorted(self.landmarks.landmarks)
        landmark_values = [
            values.atPose3(L(j))
            if self.landmarks.landmarks[j].kind is LandmarkKind.POSE
            else values.atPoint3(L(j))
            for j in ids
        ]
        return BackendResult(
            poses=poses,
            landmark_ids=ids,
            landmark_values=landmark_values,
            records=self.records,
            landmarks=self.landmarks,
            switches=self.switches,
            merges=self.merges,
            noise=self.noise,
            odometry_moves=self.odometry_moves,
            loop_drift=None if self.merger is None else self.merger.drift_belief.report(),
            step_seconds=self.step_seconds,
            solver_fallbacks=fallback_counts(self.solver.fallbacks),
        )
