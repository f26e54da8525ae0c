"""The Rerun sink: a run streamed to a recording file, a new viewer, or a running one.

What it costs is bounded per keyframe, whatever the size of the map. A keyframe logs at once
what it decided: each new detection's hypothesis lines (weights, winner), the landmarks it
touched (with ellipsoids from iSAM2's marginals), null-hypothesis wins and switches, its image.
What every keyframe adds a row to (the robot's pose, the trajectory since the last refresh, the
time series) is held back and sent as columns every `refresh_every` keyframes: one Rerun call
per entity instead of one per keyframe, since each call costs ~0.1 ms. A refresh also re-logs
the whole trajectory and the landmarks that moved; the end of the run re-logs everything from
the final estimate. Its views, each a module: the back-end's map and hypotheses
(`map_view.py`), the images (`images.py`), the recording they share with its plots' held rows
and its event log (`recording.py`), the viewer's process or file (`stream.py`). Entity paths:
`entities.py`; what is drawn and said: `draw.py`, `events.py`, `summary.py`, `marks.py` (the
legend, wrong associations, the history of decisions), `labels.py` (which labels fit); which
associations are wrong: `correctness.py`; the plots: `plots.py`; the layout: `blueprint.py`.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections import defaultdict
from typing import TYPE_CHECKING, Any

import numpy as np
import rerun as rr

from pipeline.backend.hypotheses import NULL
from pipeline.log.schemas import LEFT_IMAGE
from pipeline.viz import draw, events, legend, marks, plots
from pipeline.viz import entities as e
from pipeline.viz.blueprint import (
    FRONTEND_MAP_ASPECT,
    REPLAY_MAP_ASPECT,
    frontend_blueprint,
    replay_blueprint,
)
from pipeline.viz.config import VizConfig, load_viz_config
from pipeline.viz.correctness import WRONG, AssociationTally
from pipeline.viz.frame import board_below, replay_frame
from pipeline.viz.images import ImageView
from pipeline.viz.map_view import MapView, ShownLandmark, flat_row
from pipeline.viz.recording import HeldRows, RecordingBase
from pipeline.viz.stream import Destination
from pipeline.viz.summary import summary_markdown

if TYPE_CHECKING:
    from pipeline.backend.slam import BackendResult, KeyframeReport
    from pipeline.backend.view import ReadOnlyMap
    from pipeline.log.messages import CompressedImage, DetectionLog, LogMetadata
    from pipeline.viz.frontend import FrontendKeyframe


class RerunSink(MapView, ImageView, RecordingBase):
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
        self._held = HeldRows()
        self._class_names: tuple[str, ...] = ()
        self._colours = draw.packed_rgba(draw.class_colors(1))
        self._stamps_ns = np.zeros(0, dtype=np.int64)
        self._truth: dict[int, np.ndarray] = {}  # pose index -> aligned true position
        self._images: dict[int, CompressedImage] = {}  # stamp -> left image
        self._shown: set[str] = set()  # per-keyframe entities that hold something now
        self._refreshed_at = 0  # pose index of the last full trajectory
        self._positions: list[np.ndarray] = []  # pose positions as estimated when added
        self._landmarks: dict[int, ShownLandmark] = {}  # each landmark as last logged
        self._landmark_total = 0  # landmarks before the current keyframe
        self._winners: dict[tuple[int, int], int] = {}  # (pose, detection) -> landmark shown
        self._null_count = 0
        self._changes: dict[tuple[int, int], int] = defaultdict(int)  # per detection, as shown
        self._view: ReadOnlyMap | None = None  # the back-end's map, from the latest keyframe
        self._method = ""
        self._step_ms: list[float] = []  # per keyframe, for the trailing medians
        self._viz_ms: list[float] = []
        self._tally: AssociationTally | None = None  # where the log names true landmarks
        self._label_box = (0.0, 0.0)  # a label's size in the map (m) at the default eye
        self._drawn: set[str] = set()  # the association marks drawn so far (for the legend)

    # ----------------------------------------------------------------------------------- open
    @classmethod
    def open(
        cls,
        application: str,
        *,
        config: VizConfig | None = None,
        map_aspect: float = REPLAY_MAP_ASPECT,
        **where: Any,
    ) -> RerunSink:
        """A sink for exactly one of: a recording file, a new viewer, a running viewer, as
        `where` says (`rrd=`, `spawn=` or `connect=`, as `Destination.open` takes them)."""
        destination = Destination.open(application, **where)
        return cls(destination, config or load_viz_config(), map_aspect=map_aspect)

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
            self._trajectory(odometry, draw.ODOMETRY_RGB, "odometry alone", width=1.0),
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

    def keyframe(self, report: KeyframeReport, seconds: float) -> None:
        started = time.perf_counter()
        view = self._view = report.map
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
        self._judge(report, view.landmarks.resolve)
        # Landmark ids are never reused: ids from the next one before this keyframe are new.
        hypotheses = [
            draw.detection_hypotheses(r, c, r.landmark_id >= self._landmark_total)
            for r, c in zip(report.records, report.candidates, strict=True)
        ]
        self._landmark_total = view.landmarks.next_id
        resolve = view.landmarks.resolve
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
        poses, points = self._fetch(view, pose_indices, touched)

        row = poses[i]
        pose = np.eye(4)
        pose[:3, :3], pose[:3, 3] = row[:9].reshape(3, 3), row[9:]
        self._held.poses.append((i, stamp, pose))
        self._positions.append(row[9:].copy())
        if i - self._refreshed_at >= self.config.refresh_every:
            self._refresh(view, i)
        elif i > self._refreshed_at:
            recent = np.array(self._positions[self._refreshed_at :])
            self._held.strips[e.TRAJECTORY_RECENT].append((i, stamp, recent))

        for j in sorted(touched):
            # The association step computed the marginal of every candidate it weighed with
            # joint marginals this keyframe (before the update); otherwise its last one, an
            # upper bound. A new landmark has none yet.
            covariance = view.landmark_covariance(j)
            if self.config.keyframe_marginals or covariance is None:
                covariance = view.landmark_covariance(j, fresh=True)
            self._log_landmark(view.landmarks, j, points[j], covariance, unless_unchanged=True)

        self._log_hypotheses(report.records, hypotheses, row, points, view.landmarks)
        self._drawn |= legend.drawn_marks(hypotheses)
        # a switch is drawn for an earlier keyframe's detection only (`map_view`)
        earlier = any(r.measurement.pose_index != report.pose_index for r in report.switched)
        self._drawn |= {legend.SWITCH} if earlier else set()
        self._drawn |= {legend.MERGE} if report.merged else set()
        self._log_associations(report, poses, points)
        self._log_merges(report.merged, merged_from, points, view.landmarks.resolve)
        self._log_image(i, [(r.measurement.detection, r.landmark_id) for r in report.records])

        held = self._held.scalars
        error = float(np.linalg.norm(row[9:] - self._truth[i])) if i in self._truth else None
        if error is not None:
            held[e.ERROR_ONLINE].append((i, stamp, error))
        held[e.LANDMARK_COUNT].append((i, stamp, len(view.landmarks)))
        held[e.SWITCH_COUNT].append((i, stamp, view.switches))
        held[e.MERGE_COUNT].append((i, stamp, view.merges))
        scales = report.noise.report()
        for kind, table in (
            ("odometry", scales["odometry"]),
            ("detections", scales["measurement"]),
        ):
            for name, scale in table.items():
                held[plots.noise_path(kind, name)].append((i, stamp, math.log10(scale)))
        if self._tally is not None:
            held[e.WRONG_COUNT].append((i, stamp, self._tally.counts()[WRONG]))
        rate = self._null_count / len(self._winners) if self._winners else 0.0
        held[e.NULL_RATE].append((i, stamp, rate))
        state = self._state(i, len(view.landmarks), view.switches, error_m=error)
        self._held.markdown[e.SUMMARY].append((i, stamp, summary_markdown(state)))
        window = self.config.smoothing_window
        self._step_ms.append(1e3 * seconds)
        held[e.STEP_MS].append((i, stamp, draw.trailing_median(self._step_ms, window)))
        self._viz_ms.append(1e3 * (time.perf_counter() - started))
        held[e.VIZ_MS].append((i, stamp, draw.trailing_median(self._viz_ms, window)))

    def finish(self, result: BackendResult, metrics: dict[str, Any] | None) -> None:
        """The final estimate at the last pose: trajectory, every landmark (with fresh
        marginals if configured), every pose's error, the detections left to the null
        hypothesis, the metrics."""
        self._held.send(self.rec, e.ROBOT)
        last = len(result.poses) - 1
        self._set_time(last, self._stamp(last))
        rows = np.array([flat_row(p) for p in result.poses])
        self.rec.log(e.TRAJECTORY, self._trajectory(rows[:, 9:], draw.ESTIMATE_RGB, "estimate"))
        self.rec.log(e.TRAJECTORY_RECENT, rr.Clear(recursive=False))
        view = self._view if self.config.final_marginals else None
        for j, value in zip(result.landmark_ids, result.landmark_values, strict=True):
            covariance = view.landmark_covariance(j, fresh=True) if view is not None else None
            self._log_landmark(result.landmarks, j, flat_row(value), covariance)
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
        # The legend again (static: it replaces the first), naming only the marks drawn and
        # the classes mapped.
        if self._tally is not None and self._tally.counts()[WRONG]:
            self._drawn.add(legend.WRONG)
        if rejected:
            self._drawn.add(legend.NULL)
        self._drawn |= {self._class_names[s.class_id] for s in self._landmarks.values()}
        shown = legend.drawn_items(self._legend_items, self._drawn)
        for path, swatches in marks.legend_swatches(shown, self._board):
            self.rec.log(path, swatches, static=True)
        self._finished = True

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
