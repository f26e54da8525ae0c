"""The Rerun sink: a run streamed to a recording file, a new viewer, or a running one.

What it costs is bounded per keyframe, whatever the size of the map. A keyframe logs at once
what it decided: each new detection's hypothesis lines (weights, winner), the landmarks it
touched (with ellipsoids from iSAM2's marginals), null-hypothesis wins and switches, its image.
What every keyframe adds a row to (the robot's pose, the trajectory since the last refresh, the
time series) is held back and sent as columns every `refresh_every` keyframes: one Rerun call
per entity instead of one per keyframe, since each call costs ~0.1 ms. A refresh also re-logs
the whole trajectory and the landmarks that moved; the end of the run re-logs everything from
the final estimate. Entity paths: `pipeline/viz/entities.py`; what is drawn and said:
`draw.py`, `events.py`, `summary.py`, `marks.py` (the legend, wrong associations, the history
of decisions), `labels.py` (which labels fit); which associations are wrong: `correctness.py`;
the plots: `plots.py`; the layout: `blueprint.py`.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import rerun as rr
from gtsam.symbol_shorthand import L, X

from pipeline.backend.hypotheses import NULL, AssociationRecord
from pipeline.backend.landmarks import LandmarkKind, LandmarkMap
from pipeline.geometry import point_from_bearing_elevation_range
from pipeline.log.schemas import LEFT_IMAGE
from pipeline.viz import draw, events, labels, legend, marks, plots
from pipeline.viz import entities as e
from pipeline.viz.blueprint import (
    FRONTEND_MAP_ASPECT,
    REPLAY_MAP_ASPECT,
    frontend_blueprint,
    replay_blueprint,
    series_styles,
)
from pipeline.viz.config import VizConfig, load_viz_config
from pipeline.viz.correctness import WRONG, AssociationTally, verdicts
from pipeline.viz.frame import board_below, replay_frame
from pipeline.viz.stream import Destination
from pipeline.viz.summary import RunState, summary_markdown

if TYPE_CHECKING:
    from pipeline.backend.slam import Backend, BackendResult, KeyframeReport
    from pipeline.log.messages import CompressedImage, Detection, DetectionLog, LogMetadata
    from pipeline.viz.frontend import FrontendKeyframe

logger = logging.getLogger(__name__)

# Relative change of a landmark's covariance worth logging again (about 2.5 % in its axes).
ELLIPSOID_TOLERANCE = 0.05
MEDIA_TYPES = {"jpeg": "image/jpeg", "jpg": "image/jpeg", "png": "image/png"}
# Every landmark's uncertainty ellipsoid: thin (hundreds of them, when shown).
ELLIPSOID_LINE_PT = 0.5
LEVELS = {events.INFO: rr.TextLogLevel.INFO, events.WARN: rr.TextLogLevel.WARN}


def _differs(covariance: np.ndarray | None, shown: np.ndarray | None) -> bool:
    """Whether an ellipsoid would visibly change: its covariance by more than a few percent."""
    if covariance is None or shown is None:
        return covariance is not shown
    scale = np.linalg.norm(shown)
    return bool(np.linalg.norm(covariance - shown) > ELLIPSOID_TOLERANCE * scale)


def _row(value: Any) -> np.ndarray:
    """A Pose3 or a point as a flat row [R (9, row-major), t (3)], as the solver gives them."""
    if hasattr(value, "translation"):
        return np.concatenate([value.rotation().matrix().ravel(), value.translation()])
    return np.concatenate([np.zeros(9), np.asarray(value, dtype=float)])


@dataclass
class _Shown:
    """A landmark as last logged."""

    position: np.ndarray
    label: str
    class_id: int
    covariance: np.ndarray | None  # world frame, of its position
    ellipsoid: tuple[np.ndarray, np.ndarray] | None  # half sizes, quaternion


class _HeldRows:
    """Rows of per-keyframe entities held back, then sent as one column per entity."""

    def __init__(self) -> None:
        self.scalars: dict[str, list[tuple[int, int, float]]] = defaultdict(list)
        self.poses: list[tuple[int, int, np.ndarray]] = []  # (pose, stamp, 4x4)
        self.strips: dict[str, list[tuple[int, int, np.ndarray]]] = defaultdict(list)
        self.markdown: dict[str, list[tuple[int, int, str]]] = defaultdict(list)

    def send(self, rec: rr.RecordingStream, robot_path: str) -> None:
        def times(rows: list) -> list[rr.TimeColumn]:
            return [
                rr.TimeColumn(e.POSE_TIMELINE, sequence=[r[0] for r in rows]),
                rr.TimeColumn(
                    e.TIME_TIMELINE, timestamp=np.array([r[1] for r in rows], "datetime64[ns]")
                ),
            ]

        for path, rows in self.scalars.items():
            if rows:
                scalars = rr.Scalars.columns(scalars=[r[2] for r in rows])
                rec.send_columns(path, indexes=times(rows), columns=scalars)
        if self.poses:
            matrices = np.array([r[2] for r in self.poses])
            rec.send_columns(
                robot_path,
                indexes=times(self.poses),
                columns=rr.Transform3D.columns(
                    translation=matrices[:, :3, 3], mat3x3=matrices[:, :3, :3]
                ),
            )
        for path, rows in self.strips.items():
            if rows:
                strips = rr.LineStrips3D.columns(strips=[r[2] for r in rows])
                rec.send_columns(
                    path, indexes=times(rows), columns=strips.partition([1] * len(rows))
                )
        for path, rows in self.markdown.items():
            if rows:
                text = rr.TextDocument.columns(
                    text=[r[2] for r in rows], media_type=["text/markdown"] * len(rows)
                )
                rec.send_columns(path, indexes=times(rows), columns=text)
        self.scalars.clear()
        self.poses.clear()
        self.strips.clear()
        self.markdown.clear()


class RerunSink:
    """Implements `pipeline.viz.sink.Sink` (replay) and `pipeline.viz.frontend.FrontendSink`."""

    def __init__(
        self,
        destination: Destination,
        config: VizConfig,
        *,
        map_aspect: float = REPLAY_MAP_ASPECT,
    ):
        self.destination = destination
        self.rec = destination.rec
        self.config = config
        self.wants_images = config.image_every > 0
        # the map view's width over height in the layout the run is shown in: its default eye
        # and its legend's board are made for it
        self.map_aspect = map_aspect
        self._started = self._finished = False
        self._held = _HeldRows()
        self._class_names: tuple[str, ...] = ()
        self._colours = draw.packed_rgba(draw.class_colors(1))
        self._stamps_ns = np.zeros(0, dtype=np.int64)
        self._truth: dict[int, np.ndarray] = {}  # pose index -> aligned true position
        self._images: dict[int, CompressedImage] = {}  # stamp -> left image
        self._shown: set[str] = set()  # per-keyframe entities that hold something now
        self._refreshed_at = 0  # pose index of the last full trajectory
        self._positions: list[np.ndarray] = []  # pose positions as estimated when added
        self._landmarks: dict[int, _Shown] = {}  # each landmark as last logged
        self._landmark_total = 0  # landmarks before the current keyframe
        self._winners: dict[tuple[int, int], int] = {}  # (pose, detection) -> landmark shown
        self._null_count = 0
        self._changes: dict[tuple[int, int], int] = defaultdict(int)  # per detection, as shown
        self._backend: Backend | None = None
        self._method = ""
        self._step_ms: list[float] = []  # per keyframe, for the trailing medians
        self._viz_ms: list[float] = []
        self._tally: AssociationTally | None = None  # where the log names true landmarks
        self._label_box = (0.0, 0.0)  # a label's size in the map (m) at the default eye

    # ----------------------------------------------------------------------------------- open
    @classmethod
    def open(
        cls,
        application: str,
        *,
        rrd: str | Path | None = None,
        spawn: bool = False,
        connect: str | None = None,
        config: VizConfig | None = None,
        map_aspect: float = REPLAY_MAP_ASPECT,
    ) -> RerunSink:
        """A sink for exactly one of: a recording file, a new viewer, a running viewer."""
        destination = Destination.open(application, rrd=rrd, spawn=spawn, connect=connect)
        return cls(destination, config or load_viz_config(), map_aspect=map_aspect)

    def _begin(
        self,
        blueprint: Any,
        name: str,
        class_names: tuple[str, ...],
        legend_items: list[legend.LegendItem],
        board: legend.Board,
        plot_list: list[plots.Plot],
    ) -> None:
        if self._started:
            raise RuntimeError("a RerunSink records one run")
        self._started = True
        self.destination.start()
        self.rec.send_blueprint(blueprint)
        self.rec.send_recording_name(name)
        self.rec.log(e.WORLD, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        self.rec.log(e.ROBOT, rr.TransformAxes3D(self.config.robot_axis_length_m), static=True)
        self._class_names = class_names
        rgb = draw.class_colors(len(class_names))
        self._colours = draw.packed_rgba(rgb)
        # Class colours and names for everything logged with class ids: hovering a landmark,
        # a detection or a box names its class.
        self.rec.log(
            "/",
            rr.AnnotationContext(
                [
                    rr.ClassDescription(info=(c, name, tuple(int(v) for v in rgb[c])))
                    for c, name in enumerate(class_names)
                ]
            ),
            static=True,
        )
        for path, swatches in marks.legend_swatches(legend_items, board):
            self.rec.log(path, swatches, static=True)
        for path, style in series_styles(plot_list):
            self.rec.log(path, style, static=True)
        # labels around the current pose are thinned to those that fit at the default eye
        self._label_box = labels.label_box(board.shown_height)

    def _set_time(self, pose_index: int, stamp_ns: int) -> None:
        self.rec.set_time(e.POSE_TIMELINE, sequence=pose_index)
        self.rec.set_time(e.TIME_TIMELINE, timestamp=np.datetime64(int(stamp_ns), "ns"))

    def _trail_style(self, path: str) -> None:
        """Colour and width of a trail whose strips are sent as columns (strips only)."""
        style = rr.LineStrips3D.from_fields(
            colors=draw.packed_rgba(draw.ESTIMATE_RGB)[None], radii=rr.Radius.ui_points(2.5)
        )
        self.rec.log(path, style, static=True)

    def _clear_unless(self, path: str, logged: bool) -> None:
        """Per-keyframe entities show this keyframe's items only: clear what an earlier one
        left when this one has nothing (once, not every keyframe)."""
        if logged:
            self._shown.add(path)
        elif path in self._shown:
            self.rec.log(path, rr.Clear(recursive=False))
            self._shown.discard(path)

    def _stamp(self, pose_index: int) -> int:
        return int(self._stamps_ns[pose_index]) if pose_index < len(self._stamps_ns) else 0

    @staticmethod
    def _trajectory(
        positions: Any, rgb: tuple[int, int, int], label: str, width: float = 2.5
    ) -> rr.LineStrips3D:
        return rr.LineStrips3D(
            [np.asarray(positions, dtype=float)],
            colors=draw.packed_rgba(rgb)[None],
            radii=rr.Radius.ui_points(width),
            labels=[label],
            show_labels=False,
        )

    # --------------------------------------------------------------------------------- replay
    def start(self, log: DetectionLog, method: str) -> None:
        left_images = log.images.get(LEFT_IMAGE, []) if self.wants_images else []
        frame = replay_frame(log, self.map_aspect)
        alignment, truth, odometry = frame.alignment, frame.truth, frame.odometry
        self._truth = {int(i): p for i, p in zip(frame.truth_indices, truth, strict=True)}
        # Wrong associations are judged where the log names each detection's true landmark.
        self._tally = AssociationTally() if frame.truth_labels else None
        items, board = frame.items, frame.board
        plot_list = plots.replay_plots(
            frame.ground_truth, frame.truth_labels, self.config.smoothing_window
        )
        blueprint = replay_blueprint(
            images=bool(left_images),
            extent=frame.extent,
            plots=plot_list,
            plot_window=self.config.plot_window,
        )
        self._begin(
            blueprint, f"mmslam replay {method}", log.metadata.class_names, items, board, plot_list
        )
        self._method = method
        self._stamps_ns = np.array(log.pose_stamps_ns(), dtype=np.int64)
        self._set_time(0, self._stamp(0))
        self._event(events.started(method, log.num_poses, log.num_detections))
        self._images = {image.stamp_ns: image for image in left_images}
        self.rec.send_property(
            "run",
            rr.AnyValues(
                method=method,
                log_source=log.metadata.source,
                poses=log.num_poses,
                detections=log.num_detections,
                classes=", ".join(log.metadata.class_names),
            ),
        )
        self.rec.log(
            e.ODOMETRY_TRAJECTORY,
            self._trajectory(odometry, draw.ODOMETRY_RGB, "odometry alone", width=1.5),
            static=True,
        )
        if alignment is not None:
            self.rec.log(
                e.GROUND_TRUTH_TRAJECTORY,
                self._trajectory(truth, draw.TRUTH_RGB, "ground truth", width=1.5),
                static=True,
            )
            landmarks = log.ground_truth_landmarks
            if landmarks is not None and landmarks.landmarks:
                self.rec.log(
                    e.GROUND_TRUTH_LANDMARKS,
                    rr.Points3D(
                        draw.aligned_points([lm.position for lm in landmarks.landmarks], alignment),
                        colors=draw.packed_rgba(draw.TRUTH_RGB)[None],
                        class_ids=[lm.class_id for lm in landmarks.landmarks],
                        labels=[f"true {lm.id}" for lm in landmarks.landmarks],
                        radii=rr.Radius.ui_points(2.0),
                        show_labels=False,
                    ),
                    static=True,
                )
        self._trail_style(e.TRAJECTORY_RECENT)

    def _fetch(
        self, backend: Backend, pose_indices: set[int], landmark_ids: set[int]
    ) -> tuple[dict[int, np.ndarray], dict[int, np.ndarray]]:
        """Estimates as rows [R (9), t (3)], in one iSAM2 call."""
        landmarks = backend.landmarks.landmarks
        keyed = {X(i): (True, i) for i in pose_indices}
        keyed.update({L(j): (False, j) for j in landmark_ids})
        keys = sorted(keyed)
        is_pose3 = np.array(
            [keyed[k][0] or landmarks[keyed[k][1]].kind is LandmarkKind.POSE for k in keys],
            dtype=bool,
        )
        rows = backend.solver.flat_estimates(keys, is_pose3)
        poses, points = {}, {}
        for key, row in zip(keys, rows, strict=True):
            is_robot, index = keyed[key]
            (poses if is_robot else points)[index] = row
        return poses, points

    def _landmark_label(self, landmarks: LandmarkMap, landmark_id: int) -> tuple[int, str]:
        landmark = landmarks.landmarks[landmark_id]
        c = landmark.map_class
        probability = float(landmark.class_probabilities[c])
        return c, draw.landmark_label(landmark_id, self._class_names[c], probability)

    def _log_landmark(
        self,
        landmarks: LandmarkMap,
        landmark_id: int,
        row: np.ndarray,
        covariance: np.ndarray | None,
        *,
        unless_unchanged: bool = False,
    ) -> None:
        """A landmark's point, coloured and labelled by its MAP class; its ellipsoid is kept for
        `CANDIDATES` and `UNCERTAINTY`. A `covariance` of None keeps the one last shown, moved
        with the landmark. Only what changed since the landmark was last shown is logged (Rerun
        keeps the rest), and with `unless_unchanged` nothing if nothing visibly changed."""
        position = row[9:].copy()
        c, label = self._landmark_label(landmarks, landmark_id)
        shown = self._landmarks.get(landmark_id)
        world = None if shown is None else shown.covariance
        if covariance is not None:
            is_pose = landmarks.landmarks[landmark_id].kind is LandmarkKind.POSE
            world = draw.position_covariance(covariance, row[:9].reshape(3, 3) if is_pose else None)
        point_changed = (
            not unless_unchanged
            or shown is None
            or shown.label != label
            or np.linalg.norm(position - shown.position) > self.config.refresh_move_m
        )
        if not point_changed and not _differs(world, shown.covariance):
            return
        if point_changed:
            point: dict[str, Any] = {"positions": position[None]}
            if shown is None or shown.class_id != c:  # coloured by the annotation context
                point["class_ids"] = [c]
            if shown is None:
                # The label is for hovering and selecting: hundreds of them hide the map. The
                # landmarks a keyframe weighs are labelled by `CANDIDATES`.
                point.update(radii=rr.Radius.ui_points(5.0), show_labels=False)
            if shown is None or shown.label != label:
                point["labels"] = [label]
            self.rec.log(e.landmark_path(landmark_id), rr.Points3D.from_fields(**point))
        else:
            position = shown.position
        ellipsoid = None if shown is None else shown.ellipsoid
        if world is not None and (covariance is not None or ellipsoid is None):
            ellipsoid = draw.ellipsoid(world, self.config.ellipsoid_confidence)
        self._landmarks[landmark_id] = _Shown(position, label, c, world, ellipsoid)

    def _log_uncertainty(self) -> None:
        """Every landmark's ellipsoid as last shown, in one entity (a layer hidden by default,
        so one call a refresh rather than one a landmark a keyframe)."""
        shown = [(j, s) for j, s in sorted(self._landmarks.items()) if s.ellipsoid is not None]
        if not shown:
            return
        self.rec.log(
            e.UNCERTAINTY,
            rr.Ellipsoids3D(
                centers=[s.position for _, s in shown],
                half_sizes=[s.ellipsoid[0] for _, s in shown],
                quaternions=[s.ellipsoid[1] for _, s in shown],
                colors=self._colours[[s.class_id for _, s in shown]],
                labels=[f"L{j}" for j, _ in shown],
                show_labels=False,
                fill_mode="MajorWireframe",
                line_radii=rr.Radius.ui_points(ELLIPSOID_LINE_PT),
            ),
        )

    def _refresh(self, backend: Backend, pose_index: int) -> None:
        """Send the held rows; then the whole trajectory, and every landmark that moved or
        changed class since it was shown."""
        self._held.send(self.rec, e.ROBOT)
        ids = set(backend.landmarks.landmarks)
        poses, points = self._fetch(backend, set(range(pose_index + 1)), ids)
        positions = [poses[i][9:] for i in range(pose_index + 1)]
        self.rec.log(e.TRAJECTORY, self._trajectory(positions, draw.ESTIMATE_RGB, "estimate"))
        self.rec.log(e.TRAJECTORY_RECENT, rr.Clear(recursive=False))
        self._positions = positions
        self._refreshed_at = pose_index
        # Class labels change only where a detection weighed the landmark, and those were
        # logged then: here only movement matters.
        shown = sorted(j for j in ids if j in self._landmarks)
        if shown:
            now = np.array([points[j][9:] for j in shown])
            before = np.array([self._landmarks[j].position for j in shown])
            moved = np.linalg.norm(now - before, axis=1) > self.config.refresh_move_m
            for j in np.array(shown)[moved]:
                self._log_landmark(backend.landmarks, int(j), points[int(j)], None)
        for j in sorted(ids - set(shown)):
            self._log_landmark(backend.landmarks, j, points[j], None)
        self._log_uncertainty()
        if self._tally is not None:
            resolve = backend.landmarks.resolve
            self._log_wrong(
                [(key, resolve(j)) for key, j in self._tally.wrong()],
                lambda k: poses[k][9:],
                lambda j: points[j][9:],
            )

    def keyframe(self, report: KeyframeReport, backend: Backend) -> None:
        started = time.perf_counter()
        self._backend = backend
        i = report.pose_index
        stamp = self._stamp(i)
        self._set_time(i, stamp)
        for fallback in report.solver_fallbacks:
            self._event(events.solver_fallback(i, fallback.kind, fallback.reason))
        merged_from = {}  # duplicate -> where it was last drawn
        for duplicate, _ in report.merged:  # drawn now as the landmark it was merged into
            self.rec.log(e.landmark_path(duplicate), rr.Clear(recursive=True))
            shown = self._landmarks.pop(duplicate, None)
            if shown is not None:
                merged_from[duplicate] = shown.position
        self._judge(report, backend.landmarks.resolve)
        # Landmark ids are never reused: ids from the next one before this keyframe are new.
        hypotheses = [
            draw.detection_hypotheses(r, c, r.landmark_id >= self._landmark_total)
            for r, c in zip(report.records, report.candidates, strict=True)
        ]
        self._landmark_total = backend.landmarks.next_id
        resolve = backend.landmarks.resolve
        hypotheses = [
            [
                dataclasses.replace(h, landmark_id=resolve(h.landmark_id))
                if h.landmark_id != NULL
                else h
                for h in hs
            ]
            for hs in hypotheses
        ]
        if self._tally is not None:  # a winner whose landmark stands for another object: red
            tally = self._tally
            hypotheses = [
                [
                    dataclasses.replace(h, wrong=tally.verdict((i, h.detection_index)) == WRONG)
                    if h.winner
                    else h
                    for h in hs
                ]
                for hs in hypotheses
            ]
        touched = {h.landmark_id for hs in hypotheses for h in hs if h.landmark_id != NULL}
        for record in report.switched:
            touched.update(record.landmark_ids)
        touched.update(survivor for _, survivor in report.merged)
        pose_indices = {i} | {r.measurement.pose_index for r in report.switched}
        poses, points = self._fetch(backend, pose_indices, touched)

        row = poses[i]
        pose = np.eye(4)
        pose[:3, :3], pose[:3, 3] = row[:9].reshape(3, 3), row[9:]
        self._held.poses.append((i, stamp, pose))
        self._positions.append(row[9:].copy())
        if i - self._refreshed_at >= self.config.refresh_every:
            self._refresh(backend, i)
        elif i > self._refreshed_at:
            recent = np.array(self._positions[self._refreshed_at :])
            self._held.strips[e.TRAJECTORY_RECENT].append((i, stamp, recent))

        for j in sorted(touched):
            # The association step computed the marginal of every candidate it weighed with
            # joint marginals this keyframe (before the update); otherwise its last one, an
            # upper bound. A new landmark has none yet.
            covariance = backend.landmarks.landmarks[j].covariance_bound
            if self.config.keyframe_marginals or covariance is None:
                covariance = backend.solver.marginal_covariance(L(j))
            self._log_landmark(backend.landmarks, j, points[j], covariance, unless_unchanged=True)

        self._log_hypotheses(report.records, hypotheses, row, points, backend.landmarks)
        self._log_associations(report, poses, points)
        self._log_merges(report.merged, merged_from, points, backend.landmarks.resolve)
        self._log_image(i, [(r.measurement.detection, r.landmark_id) for r in report.records])

        held = self._held.scalars
        error = float(np.linalg.norm(row[9:] - self._truth[i])) if i in self._truth else None
        if error is not None:
            held[e.ERROR_ONLINE].append((i, stamp, error))
        held[e.LANDMARK_COUNT].append((i, stamp, len(backend.landmarks)))
        held[e.SWITCH_COUNT].append((i, stamp, backend.switches))
        held[e.MERGE_COUNT].append((i, stamp, backend.merges))
        if self._tally is not None:
            held[e.WRONG_COUNT].append((i, stamp, self._tally.counts()[WRONG]))
        rate = self._null_count / len(self._winners) if self._winners else 0.0
        held[e.NULL_RATE].append((i, stamp, rate))
        state = self._state(i, len(backend.landmarks), backend.switches, error_m=error)
        self._held.markdown[e.SUMMARY].append((i, stamp, summary_markdown(state)))
        window = self.config.smoothing_window
        self._step_ms.append(1e3 * report.seconds)
        held[e.STEP_MS].append((i, stamp, draw.trailing_median(self._step_ms, window)))
        self._viz_ms.append(1e3 * (time.perf_counter() - started))
        held[e.VIZ_MS].append((i, stamp, draw.trailing_median(self._viz_ms, window)))

    def _judge(self, report: KeyframeReport, resolve: Any) -> None:
        """Bring the verdicts up to date with this keyframe: its detections, the earlier ones
        whose association changed, the landmarks merged."""
        if self._tally is None:
            return
        for record in [*report.records, *report.switched]:
            m = record.measurement
            j = record.landmark_id
            truth = m.detection.truth_landmark_id
            self._tally.assign(
                (m.pose_index, m.detection_index), truth, resolve(j) if j != NULL else j
            )
        for duplicate, survivor in report.merged:
            self._tally.merge(duplicate, resolve(survivor))

    def _log_wrong(
        self, wrong: list[tuple[tuple[int, int], int]], pose_at: Any, landmark_at: Any
    ) -> None:
        """Every detection judged wrong now, a red line from its pose to its landmark;
        `pose_at(k)` and `landmark_at(j)` give positions."""
        if wrong:
            self.rec.log(
                e.WRONG,
                *marks.wrong_lines(
                    np.array([pose_at(k) for (k, _), _ in wrong]),
                    np.array([landmark_at(j) for _, j in wrong]),
                    [f"p{k} d{d} → L{j}" for (k, d), j in wrong],
                ),
            )
        self._clear_unless(e.WRONG, bool(wrong))

    def _log_merges(
        self,
        merged: list[tuple[int, int]],
        merged_from: dict[int, np.ndarray],
        points: dict[int, np.ndarray],
        resolve: Any,
    ) -> None:
        """Each merge where it happened: a line from the duplicate to its survivor, kept in
        the history (shown up to the time cursor)."""
        drawn = [(d, resolve(s)) for d, s in merged if d in merged_from]
        if drawn:
            self.rec.log(
                e.MERGES,
                marks.merges(
                    np.array([merged_from[d] for d, _ in drawn]),
                    np.array([points[s][9:] for _, s in drawn]),
                    [f"L{d} → L{s}" for d, s in drawn],
                ),
            )

    def _state(
        self, pose_index: int, landmarks: int, switches: int, error_m: float | None = None
    ) -> RunState:
        return RunState(
            method=self._method,
            pose_index=pose_index,
            num_poses=len(self._stamps_ns),
            detections=len(self._winners),
            landmarks=landmarks,
            switches=switches,
            nulls=self._null_count,
            error_m=error_m,
        )

    def _log_hypotheses(
        self,
        records: list[AssociationRecord],
        hypotheses: list[list[draw.Hypothesis]],
        pose_row: np.ndarray,
        points: dict[int, np.ndarray],
        landmarks: LandmarkMap,
    ) -> None:
        """Per detection, a line from the pose to every landmark it may be, or to where it puts
        its landmark for the null hypothesis; width by weight, the winner bright (red if wrong),
        the winner's labelled with its weight. The measured points are drawn too, coloured by
        reported class, and the landmarks weighed are labelled with their id, class and its
        probability. Labels that would cover others at the default eye are left out: the
        winners' landmarks first, then the winners' lines, then the other candidates."""
        strips, colours, widths, texts, flat = [], [], [], [], []
        origin = pose_row[9:]
        measured = np.zeros((len(records), 3))
        for k, (record, hs) in enumerate(zip(records, hypotheses, strict=True)):
            measured[k] = draw.body_to_world(pose_row, record.measurement.body_point)[0]
            for h in hs:
                end = measured[k] if h.landmark_id == NULL else points[h.landmark_id][9:]
                colour, width = draw.hypothesis_style(h)
                strips.append(np.array([origin, end]))
                colours.append(colour)
                widths.append(rr.Radius.ui_points(width))
                texts.append(draw.hypothesis_label(h))
                flat.append(h)
        weighed = sorted({h.landmark_id for h in flat if h.landmark_id != NULL})
        named = [self._landmark_label(landmarks, j) for j in weighed]
        centres = [points[j][9:] for j in weighed]
        landmarks_shown, lines_shown = labels.keyframe_labels(
            flat, strips, weighed, centres, self._label_box
        )
        if flat:
            classes = [r.measurement.detection.class_id for r in records]
            self.rec.log(
                e.HYPOTHESES,
                rr.LineStrips3D(
                    strips,
                    colors=draw.packed_rgba(colours),
                    radii=widths,
                    labels=[t if ok else "" for t, ok in zip(texts, lines_shown, strict=True)],
                ),
                rr.Points3D(
                    measured,
                    class_ids=classes,
                    radii=rr.Radius.ui_points(3.0),
                    show_labels=False,  # else each would carry its class name
                ),
                # One value per line: for the selection panel, and for reading the recording.
                rr.AnyValues(
                    detection=[h.detection_index for h in flat],
                    landmark=[h.landmark_id for h in flat],
                    weight=[h.weight for h in flat],
                    winner=[h.winner for h in flat],
                ),
            )
        self._clear_unless(e.HYPOTHESES, bool(flat))
        if weighed:
            classes = [c for c, _ in named]
            parts: list[Any] = [
                rr.Points3D(
                    centres,
                    class_ids=classes,
                    labels=[
                        label if ok else ""
                        for (_, label), ok in zip(named, landmarks_shown, strict=True)
                    ],
                    radii=rr.Radius.ui_points(6.0),
                    show_labels=True,
                )
            ]
            # Their uncertainty, as the association step saw it: only these, so that the map
            # stays readable (every landmark's is in `UNCERTAINTY`, hidden by default).
            shaped = [
                (centre, self._landmarks[j].ellipsoid, c)
                for j, centre, c in zip(weighed, centres, classes, strict=True)
                if self._landmarks[j].ellipsoid is not None
            ]
            if shaped:
                parts.append(
                    rr.Ellipsoids3D(
                        centers=[centre for centre, _, _ in shaped],
                        half_sizes=[shape[0] for _, shape, _ in shaped],
                        quaternions=[shape[1] for _, shape, _ in shaped],
                        colors=self._colours[[c for _, _, c in shaped]],
                        fill_mode="MajorWireframe",
                        line_radii=rr.Radius.ui_points(1.0),
                    )
                )
            self.rec.log(e.CANDIDATES, *parts)
        self._clear_unless(e.CANDIDATES, bool(weighed))

    def _event(self, event: events.Event | None) -> None:
        if event is not None:
            self.rec.log(e.EVENTS, rr.TextLog(event.text, level=LEVELS[event.level]))

    def _log_associations(
        self,
        report: KeyframeReport,
        poses: dict[int, np.ndarray],
        points: dict[int, np.ndarray],
    ) -> None:
        """Null-hypothesis wins and switches: marked in the map and told in the event log."""
        i = report.pose_index
        null_points, null_labels = [], []
        strips, strip_labels = [], []
        earlier = 0
        # Switches first: they change what was shown for detections of earlier keyframes.
        for record in report.switched:
            m = record.measurement
            key = (m.pose_index, m.detection_index)
            winner = record.landmark_id
            previous = self._winners.get(key)  # None: the detection is this keyframe's own
            self._changes[key] += 1
            if previous is None:
                # Its hypothesis lines show where it went; one gone to the null hypothesis is
                # told below.
                if winner != NULL:
                    self._event(events.changed(i, *key, None, winner))
                continue
            earlier += 1
            self._null_count += (winner == NULL) - (previous == NULL)
            self._winners[key] = winner
            pose_row = poses[m.pose_index]
            measured = draw.body_to_world(pose_row, m.body_point)[0]
            strips.append(
                np.array([pose_row[9:], measured if winner == NULL else points[winner][9:]])
            )
            strip_labels.append(
                f"p{key[0]} d{key[1]}: {events.name(previous)}→{events.name(winner)}"
            )
            if winner == NULL:
                null_points.append(measured)
                null_labels.append(f"p{m.pose_index} d{m.detection_index}")
            self._event(events.changed(i, *key, previous, winner))
            limit = self.config.warn_changes_per_detection
            self._event(events.unsettled(i, *key, self._changes[key], limit))
        self._event(events.many_changed(i, earlier, self.config.warn_changes_at_once))
        for record in report.records:
            m = record.measurement
            self._winners[(m.pose_index, m.detection_index)] = record.landmark_id
            if record.landmark_id != NULL:
                continue
            self._null_count += 1
            null_points.append(draw.body_to_world(poses[i], m.body_point)[0])
            null_labels.append(f"p{m.pose_index} d{m.detection_index}")
            candidates = list(zip(record.landmark_ids, record.weights, strict=True))
            self._event(events.null_win(i, m.detection_index, candidates, record.null_weight))
        if null_points:
            self.rec.log(
                e.NULL_WINS,
                rr.Points3D(
                    null_points,
                    colors=draw.packed_rgba(draw.NULL_WINNER_RGB)[None],
                    radii=rr.Radius.ui_points(7.0),
                    labels=null_labels,
                    show_labels=False,  # the lines and the event log say it; hover for more
                ),
            )
        self._clear_unless(e.NULL_WINS, bool(null_points))
        if null_points:  # and kept where they happened, shown up to the time cursor
            self.rec.log(e.NULL_DECISIONS, marks.null_decisions(np.array(null_points), null_labels))
        if strips:
            self.rec.log(
                e.SWITCHES,
                rr.LineStrips3D(
                    strips,
                    colors=draw.packed_rgba(draw.SWITCH_RGB)[None],
                    radii=rr.Radius.ui_points(4.0),
                    labels=strip_labels,
                ),
            )
        self._clear_unless(e.SWITCHES, bool(strips))

    def _log_image(self, pose_index: int, detections: list[tuple[Detection, int | None]]) -> None:
        """The log's left image at this pose, each detection's box labelled with its reported
        class, score and the landmark it went to."""
        every = self.config.image_every
        if not self._images or every == 0 or pose_index % every:
            return
        image = self._images.get(self._stamp(pose_index))
        if image is None:
            return
        media_type = MEDIA_TYPES.get(image.format.lower())
        self.rec.log(e.CAMERA, rr.EncodedImage(contents=image.data, media_type=media_type))
        self._log_boxes([(d, winner) for d, winner in detections if d.bbox is not None])

    def _log_boxes(self, boxes: list[tuple[Detection, int | None]]) -> None:
        """Boxes coloured by reported class, labelled with class, score, range and (on replay)
        the landmark each went to."""
        if boxes:
            labels = [
                draw.detection_label(d, self._class_names[d.class_id], winner)
                for d, winner in boxes
            ]
            self.rec.log(
                e.CAMERA_DETECTIONS,
                rr.Boxes2D(
                    array=[d.bbox for d, _ in boxes],
                    array_format=rr.Box2DFormat.XYXY,
                    class_ids=[d.class_id for d, _ in boxes],
                    labels=labels,
                ),
            )
        self._clear_unless(e.CAMERA_DETECTIONS, bool(boxes))

    def finish(self, result: BackendResult, metrics: dict[str, Any] | None) -> None:
        """The final estimate at the last pose: trajectory, every landmark (with fresh
        marginals if configured), every pose's error, the detections left to the null
        hypothesis, the metrics."""
        self._held.send(self.rec, e.ROBOT)
        last = len(result.poses) - 1
        self._set_time(last, self._stamp(last))
        rows = np.array([_row(p) for p in result.poses])
        self.rec.log(e.TRAJECTORY, self._trajectory(rows[:, 9:], draw.ESTIMATE_RGB, "estimate"))
        self.rec.log(e.TRAJECTORY_RECENT, rr.Clear(recursive=False))
        fresh = self.config.final_marginals and self._backend is not None
        for j, value in zip(result.landmark_ids, result.landmark_values, strict=True):
            covariance = self._backend.solver.marginal_covariance(L(j)) if fresh else None
            self._log_landmark(result.landmarks, j, _row(value), covariance)
        self._log_uncertainty()

        indices = np.array(sorted(k for k in self._truth if k <= last), dtype=int)
        if len(indices):
            errors = np.linalg.norm(rows[indices, 9:] - [self._truth[k] for k in indices], axis=1)
            self.rec.send_columns(
                e.ERROR_FINAL,
                indexes=[
                    rr.TimeColumn(e.POSE_TIMELINE, sequence=indices),
                    rr.TimeColumn(
                        e.TIME_TIMELINE, timestamp=self._stamps_ns[indices].astype("datetime64[ns]")
                    ),
                ],
                columns=rr.Scalars.columns(scalars=errors),
            )

        if self._tally is not None:
            self._log_final_wrong(result, rows, last)
        rejected = [r.measurement for r in result.records if r.landmark_id == NULL]
        if rejected:
            self.rec.log(
                e.REJECTED,
                rr.Points3D(
                    [draw.body_to_world(rows[m.pose_index], m.body_point)[0] for m in rejected],
                    colors=draw.packed_rgba(draw.NULL_WINNER_RGB)[None],
                    radii=rr.Radius.ui_points(5.0),
                    labels=[f"p{m.pose_index} d{m.detection_index}" for m in rejected],
                    show_labels=False,
                ),
            )
        state = self._state(last, len(result.landmark_ids), result.switches)
        text = summary_markdown(state, metrics)
        self.rec.log(e.SUMMARY, rr.TextDocument(text, media_type="text/markdown"))
        self._finished = True

    def _log_final_wrong(self, result: BackendResult, rows: np.ndarray, last: int) -> None:
        """The final associations judged as `metrics.json` judges them: red lines, and the
        count at the last pose."""
        records = result.records
        keys = [(r.measurement.pose_index, r.measurement.detection_index) for r in records]
        resolve = result.landmarks.resolve
        chosen = [resolve(r.landmark_id) if r.landmark_id != NULL else NULL for r in records]
        judged = verdicts([r.measurement.detection.truth_landmark_id for r in records], chosen)
        where = {
            j: _row(v)[9:] for j, v in zip(result.landmark_ids, result.landmark_values, strict=True)
        }
        wrong = [(k, j) for k, j, v in zip(keys, chosen, judged, strict=True) if v == WRONG]
        self._log_wrong(wrong, lambda k: rows[k, 9:], where.__getitem__)
        self.rec.log(e.WRONG_COUNT, rr.Scalars(len(wrong)))

    # ------------------------------------------------------------------------------- frontend
    def frontend_start(self, metadata: LogMetadata, extent: np.ndarray | None = None) -> None:
        items = legend.frontend_legend(metadata.class_names)
        reference = extent if extent is not None and len(extent) else np.zeros((1, 3))
        board, seen = board_below(reference, items, FRONTEND_MAP_ASPECT)
        plot_list = plots.frontend_plots()
        blueprint = frontend_blueprint(seen, plot_list, self.config.plot_window)
        self._begin(blueprint, "mmslam frontend", metadata.class_names, items, board, plot_list)
        self._trail_style(e.VO_TRAJECTORY_RECENT)

    def frontend_keyframe(self, keyframe: FrontendKeyframe) -> None:
        i, stamp = keyframe.pose_index, keyframe.stamp_ns
        self._set_time(i, stamp)
        self._held.poses.append((i, stamp, keyframe.body_pose))
        self._positions.append(keyframe.body_pose[:3, 3].copy())
        if i - self._refreshed_at >= self.config.refresh_every:
            self._held.send(self.rec, e.ROBOT)
            self._log_vo_trajectory()
            self._refreshed_at = i
        elif i > self._refreshed_at:
            recent = np.array(self._positions[self._refreshed_at :])
            self._held.strips[e.VO_TRAJECTORY_RECENT].append((i, stamp, recent))
        self._log_body_detections(keyframe.detections)

        every = self.config.image_every
        if every and i % every == 0:
            self._log_frontend_image(keyframe)
        detections = keyframe.detections
        held = self._held.scalars
        held[e.TAG_COUNT].append((i, stamp, sum(d.source == "apriltag" for d in detections)))
        held[e.BOX_COUNT].append((i, stamp, sum(d.source == "bbox" for d in detections)))
        if keyframe.step is not None:
            held[e.VO_INLIERS].append((i, stamp, keyframe.step.inliers))

    def _log_body_detections(self, detections: list[Detection]) -> None:
        """A keyframe's detections in the body frame (children of the robot), coloured by class
        and labelled with class, score and range."""
        if detections:
            body = point_from_bearing_elevation_range(
                np.array([[d.bearing, d.elevation, d.range] for d in detections])
            )
            names = self._class_names
            self.rec.log(
                e.ROBOT_DETECTIONS,
                rr.Points3D(
                    body,
                    class_ids=[d.class_id for d in detections],
                    labels=[draw.detection_label(d, names[d.class_id]) for d in detections],
                    radii=rr.Radius.ui_points(4.0),
                ),
            )
        self._clear_unless(e.ROBOT_DETECTIONS, bool(detections))

    def _log_frontend_image(self, keyframe: FrontendKeyframe) -> None:
        import cv2

        quality = [cv2.IMWRITE_JPEG_QUALITY, self.config.jpeg_quality]
        ok, data = cv2.imencode(".jpg", keyframe.left, quality)
        if ok:
            self.rec.log(
                e.CAMERA, rr.EncodedImage(contents=data.tobytes(), media_type="image/jpeg")
            )
        tags = keyframe.tags
        if tags:
            self.rec.log(
                e.CAMERA_TAGS,
                rr.LineStrips2D(
                    [np.vstack([t.corners, t.corners[:1]]) for t in tags],
                    labels=[
                        f"tag {t.tag_id}"
                        if t.detection is None
                        else draw.detection_label(t.detection, f"tag {t.tag_id}")
                        for t in tags
                    ],
                    colors=[
                        draw.packed_rgba(draw.ESTIMATE_RGB)
                        if t.detection is None
                        else self._colours[t.detection.class_id]
                        for t in tags
                    ],
                    radii=rr.Radius.ui_points(2.0),
                ),
            )
        self._clear_unless(e.CAMERA_TAGS, bool(tags))
        # Tags are drawn by their outlines where the front-end gave them; boxes for the rest.
        outlined = {id(t.detection) for t in tags if t.detection is not None}
        self._log_boxes(
            [(d, None) for d in keyframe.detections if d.bbox is not None and id(d) not in outlined]
        )

    def frontend_finish(self) -> None:
        self._held.send(self.rec, e.ROBOT)
        if self._positions:
            self._log_vo_trajectory()
        self._finished = True

    def _log_vo_trajectory(self) -> None:
        trajectory = self._trajectory(self._positions, draw.ESTIMATE_RGB, "visual odometry")
        self.rec.log(e.VO_TRAJECTORY, trajectory)
        self.rec.log(e.VO_TRAJECTORY_RECENT, rr.Clear(recursive=False))

    # ---------------------------------------------------------------------------------- close
    def close(self) -> None:
        """Flush and disconnect; a recording file is renamed into place only if its run
        finished, so a failed run leaves an earlier recording as it was."""
        self.destination.close(self._finished)
