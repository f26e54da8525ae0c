"""The back-end: keyframes in, iSAM2 estimate and associations out.

backend = Backend(config, confusion, "mm-nh")
for odometry, detections in keyframes:
    report = backend.add_keyframe(odometry, detections)
result = backend.result()

Each keyframe is one story (`add_keyframe`): predict the new pose from the odometry, score the
landmarks each detection could be, associate (the method's step), update iSAM2, settle the
associations the update moved, merge duplicated landmarks, learn the noise, and report. At the
log's end (`result`), a last merge check takes every point landmark as a source
(`[merges] final_check`).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
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
from pipeline.backend.methods import make_method
from pipeline.backend.methods.base import BackendContext, Keyframe
from pipeline.backend.noise import HeldDetections, NoiseLearner, NoiseMove, NoiseScales
from pipeline.backend.planar import planar_prior_factors
from pipeline.backend.solver import Isam2Solver, SolverFallback, fallback_counts
from pipeline.backend.view import ReadOnlyMap
from pipeline.config import Config
from pipeline.log.messages import Detection, Odometry

logger = logging.getLogger(__name__)

# Cells of the landmark index: about the spread of a search, so a query touches few cells.
INDEX_CELL_SIZE_M = 10.0


@dataclass(frozen=True)
class KeyframeReport:
    """What happened at one keyframe: for viewers, progress and benchmarks. `map` is the
    back-end's map as it stands after the keyframe, read-only."""

    pose_index: int
    records: list[AssociationRecord]
    candidates: list[Candidates]
    # Associations this keyframe changed (once each): earlier detections', and its own where
    # refine moved them off their first choice. One that left and came back is not in it.
    switched: list[AssociationRecord]
    merged: list[tuple[int, int]]  # (duplicate, survivor) ids
    # Graphs Cholesky refused at this keyframe, and what the solver did (each one a bug)
    solver_fallbacks: list[SolverFallback]
    map: ReadOnlyMap
    noise: NoiseScales  # the noise scales in use after the keyframe


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
    noise_moves: list[NoiseMove] = field(default_factory=list)  # in order
    # what the loops closed by merges said of the odometry's scale (`DriftScaleBelief.report`)
    loop_drift: dict | None = None
    solver_fallbacks: dict[str, int] = field(default_factory=dict)  # by kind


class Backend:
    def __init__(
        self,
        config: Config,
        confusion: np.ndarray,
        method: str,
        planar: bool = False,
        heartbeat: Callable[[str], None] | None = None,
    ):
        """`planar`: the log moves in a plane, stated as a prior on every pose's height and tilt
        (`pipeline/backend/planar.py`, `[prior] planar`). `heartbeat` hears, now and then,
        what a keyframe is doing (the replay's progress shows it while a keyframe is slow)."""
        self.config = config
        self.planar = planar
        self.solver = Isam2Solver(config.isam2, config.landmarks.use_relative_pose)
        self.landmarks = LandmarkMap(num_classes=confusion.shape[0], cell_size=INDEX_CELL_SIZE_M)
        self.context = BackendContext(self.solver, self.landmarks, confusion, config)
        if heartbeat is not None:  # told the pose it is at
            self.context.heartbeat = lambda doing: heartbeat(f"pose {self.num_poses - 1}: {doing}")
        self.method = make_method(method, self.context)
        self.scorer = CandidateScorer(
            self.solver,
            self.landmarks,
            confusion,
            config.association,
            self.method.wants_joint,
            wide_gate=self.method.wide_gate,
        )
        self.merger = (
            MergeFinder(
                self.context,
                config.merges,
                config.association.search_margin_m,
                self.context.space[LandmarkKind.POINT],
            )
            if self.method.merges_landmarks
            else None
        )
        # Only a method that associates keyframes jointly sees the sure pairings that tell the
        # detections' noise: it alone learns the noise.
        self.noise = NoiseLearner(config.noise, self.method.wants_joint, planar)
        self.records: list[AssociationRecord] = []
        self._first_record: list[int] = []  # per pose, its first record's index in `records`
        # (handle, odometry) of each pose's odometry factor, while its scale may change
        self._odometry: list[tuple[int, Odometry]] = []
        self.num_poses = 0
        self.switches = 0
        self.merges = 0
        self._finished = False
        # (pose, detection) -> landmark as last reported: refine's rounds may switch a record
        # away and back within one keyframe, which is no change.
        self._reported: dict[tuple[int, int], int] = {}

    def add_keyframe(
        self, odometry: Odometry | None, detections: list[Detection]
    ) -> KeyframeReport:
        """Predict, score candidates, associate, update iSAM2, settle, merge, learn, report."""
        fallbacks = len(self.solver.fallbacks)
        beat = self.context.heartbeat
        prediction = self.predict(odometry)
        beat(f"scoring {len(detections)} detections")
        keyframe = self.score(prediction, detections)
        beat(f"associating {len(detections)} detections")
        records = self.associate(keyframe)
        beat("updating iSAM2")
        switched = self.settle(self.solver.update())
        merged = self.merge(prediction)
        if merged:
            beat(f"updating iSAM2 after {len(merged)} merges")
            switched += self.settle(self.solver.update())
        if self.learn_noise(prediction.pose_index):
            beat("updating iSAM2 at the noise learnt")
            switched += self.settle(self.solver.update(anew=True))
        return self.report(keyframe, records, switched, merged, fallbacks)

    def predict(self, odometry: Odometry | None) -> PosePrediction:
        """The new pose from the last one and the odometry; pose 0 is the origin."""
        if (odometry is None) != (self.num_poses == 0):
            raise ValueError("odometry is needed for every keyframe but the first")
        index = self.num_poses
        self.num_poses += 1
        if odometry is None:
            return PosePrediction(index, X(0), self._add_origin(), np.eye(6), np.zeros((6, 6)))
        step = pose_from_message(odometry.translation, odometry.rotation)
        pose = self.solver.pose(X(index - 1)).compose(step)
        handle, covariance = self._add_odometry(index - 1, odometry)
        if self.noise.watches_drift:
            self.noise.add_step(step, np.reshape(odometry.covariance, (6, 6)))
            self._odometry.append((handle, odometry))
        self.solver.insert(X(index), pose)
        if self.planar:
            p = self.config.prior
            for factor in planar_prior_factors(
                X(index), p.planar_height_sigma_m, p.planar_tilt_sigma_rad
            ):
                self.solver.add(factor)
        return PosePrediction(index, X(index - 1), pose, step.inverse().AdjointMap(), covariance)

    def score(self, prediction: PosePrediction, detections: list[Detection]) -> Keyframe:
        """The keyframe's detections as measurements, at the noise scales learnt so far, and the
        landmarks each could be (none for a method that is told)."""
        use_pose = self.config.landmarks.use_relative_pose
        scale = self.noise.scales.measurement_matrix()
        measurements = [
            make_measurement(prediction.pose_index, k, d, use_pose, scale)
            for k, d in enumerate(detections)
        ]
        for m in measurements:
            self.context.space[m.kind].observe(m.vector, m.covariance)
        if not self.method.uses_candidates:
            return Keyframe(prediction, measurements, [Candidates.none() for _ in measurements])
        candidates, joint = self.scorer.score(
            prediction,
            measurements,
            is_recent=lambda j: self.context.seen_lately(j, prediction.pose_index),
        )
        return Keyframe(prediction, measurements, candidates, joint)

    def associate(self, keyframe: Keyframe) -> list[AssociationRecord]:
        """The method's factors for the keyframe's detections, pending in iSAM2."""
        records = self.method.associate_keyframe(keyframe)
        self._first_record.append(len(self.records))
        for r in records:
            self.context.register(r)
            self._reported[r.measurement.pose_index, r.measurement.detection_index] = r.landmark_id
        self.records.extend(records)
        return records

    def settle(self, marked: set[int]) -> list[AssociationRecord]:
        """After an iSAM2 update that marked `marked`: the associations the move changed
        (known association needs no revisits)."""
        if not self.method.uses_candidates:
            return []
        return self.method.refine(self.context.after_update(marked))

    def merge(self, prediction: PosePrediction) -> list[tuple[int, int]]:
        """Merge duplicated landmarks (every few keyframes); the merges stay pending in iSAM2."""
        pose_index = prediction.pose_index
        if self.merger is None or pose_index % self.config.merges.every_keyframes:
            return []
        return self._merged(self.merger.find(pose_index, prediction))

    def _merged(self, pairs: list[tuple[int, int]]) -> list[tuple[int, int]]:
        """Each (duplicate, survivor) of `pairs` merged, pending in iSAM2; the pairs."""
        for duplicate, survivor in pairs:
            self.method.merge(survivor, duplicate)
        self.merges += len(pairs)
        return pairs

    def learn_noise(self, pose_index: int) -> bool:
        """The noise scales learnt anew; whether they moved (every factor of a kind that moved
        is then reweighted, pending: the graph is to be solved anew)."""
        change = self.noise.learn(pose_index, self.solver, self.held_detections)
        if change.odometry:
            for k, (handle, odometry) in enumerate(self._odometry):
                self.solver.remove(handle)
                self._odometry[k] = (self._add_odometry(k, odometry)[0], odometry)
            if self.merger is not None:  # the loops said how far the old map was off
                self.merger.drift_belief.restart()
        if change.measurement:
            self.method.restate(self.records, self.noise.scales.measurement_matrix())
        if change:  # the whole map's uncertainty changes: the landmarks' bounds are forgotten
            for landmark in self.landmarks.landmarks.values():
                landmark.covariance_bound = None
        return bool(change)

    def held_detections(self, poses: range) -> list[HeldDetections]:
        """Each keyframe's point detections that a landmark holds with others, at the current
        estimate, for keyframes `poses` (those with none are left out)."""
        held_by: dict[int, int] = {}  # landmark: how many detections it holds

        def sightings(j: int) -> int:
            if j not in held_by:
                held_by[j] = len(self.context.held_detections(j))
            return held_by[j]

        chosen = []
        for i in poses:
            end = self._first_record[i + 1] if i + 1 < len(self._first_record) else None
            held = [
                r
                for r in self.records[self._first_record[i] : end]
                if r.landmark_id >= 0
                and r.measurement.kind is LandmarkKind.POINT
                and sightings(r.landmark_id) >= 2
            ]
            if len(held) >= 2:
                chosen.append((i, held))
        if not chosen:
            return []
        ids = sorted({r.landmark_id for _, held in chosen for r in held})
        keys = [X(i) for i, _ in chosen] + [L(j) for j in ids]
        order = np.argsort(keys)
        rows = np.empty((len(keys), 12))
        rows[order] = self.solver.flat_estimates(
            [keys[k] for k in order], np.array([k < len(chosen) for k in order])
        )
        point = {j: rows[len(chosen) + n, 9:] for n, j in enumerate(ids)}
        out = []
        for n, (_, held) in enumerate(chosen):
            ms = [r.measurement for r in held]
            out.append(
                HeldDetections(
                    rows[n, :9].reshape(3, 3),
                    rows[n, 9:],
                    np.array([point[r.landmark_id] for r in held]),
                    np.array([m.vector for m in ms]),
                    np.array([np.reshape(m.detection.covariance, (3, 3)) for m in ms]),
                    np.array([sightings(r.landmark_id) for r in held]),
                )
            )
        return out

    def report(
        self,
        keyframe: Keyframe,
        records: list[AssociationRecord],
        switched: list[AssociationRecord],
        merged: list[tuple[int, int]],
        fallbacks_before: int,
    ) -> KeyframeReport:
        """The keyframe's report; the associations it changed are counted and seen."""
        switched = self._changed(switched)
        for record in switched:
            self.context.seen(record)
        self.switches += len(switched)
        return KeyframeReport(
            keyframe.prediction.pose_index,
            records,
            keyframe.candidates,
            switched,
            merged,
            self.solver.fallbacks[fallbacks_before:],
            ReadOnlyMap(self.solver, self.landmarks, self.switches, self.merges),
            self.noise.scales,
        )

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

    def _add_odometry(self, k: int, odometry: Odometry) -> tuple[int, np.ndarray]:
        """The factor of `odometry` from pose k to k + 1, its stated covariance at the
        odometry's current scale, added to the solver: (its handle, that covariance)."""
        covariance = self.noise.scales.odometry_covariance(np.reshape(odometry.covariance, (6, 6)))
        return self.solver.add(odometry_factor(X(k), X(k + 1), odometry, covariance)), covariance

    def merge_remaining(self) -> None:
        """The log's last merge check: every point landmark a source, seen lately or not (a
        duplicate started while the odometry had drifted lies on its original once a loop
        closed elsewhere corrects the map), in as many checks as the budgets take. Each check
        merges something or leaves fewer sources waiting, so that it ends."""
        if self.merger is None or not self.config.merges.final_check or self.num_poses == 0:
            return
        k = self.num_poses - 1
        here = PosePrediction(k, X(k), self.solver.pose(X(k)), np.eye(6), np.zeros((6, 6)))
        context = self.context
        points = self.landmarks.landmarks.items()
        context.changed = {j for j, lm in points if lm.kind is LandmarkKind.POINT}
        while context.changed:
            waiting = len(context.changed)
            merged = self._merged(self.merger.find(k, here, final=True))
            if merged:
                self.settle(self.solver.update())
            elif len(context.changed) >= waiting:
                break

    def result(self) -> BackendResult:
        """The estimate at the log's end (its last merge check made first, once)."""
        if not self._finished:
            self._finished = True
            self.merge_remaining()
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
            noise=self.noise.scales,
            noise_moves=self.noise.moves,
            loop_drift=None if self.merger is None else self.merger.drift_belief.report(),
            solver_fallbacks=fallback_counts(self.solver.fallbacks),
        )
