"""The recording every view of the Rerun sink draws into: its start (layout, class colours,
legend, plot styles), the time cursor, the per-keyframe entities cleared when a keyframe has
nothing for them, the rows held back for the plots and the robot (sent as columns every
`refresh_every` keyframes), and the event log. `RerunSink` holds the state all its views share.
"""

from __future__ import annotations

from collections import defaultdict
from typing import Any

import numpy as np
import rerun as rr

from pipeline.viz import draw, events, labels, legend, marks, plots
from pipeline.viz import entities as e
from pipeline.viz.blueprint import series_styles
from pipeline.viz.summary import RunState

LEVELS = {events.INFO: rr.TextLogLevel.INFO, events.WARN: rr.TextLogLevel.WARN}


class HeldRows:
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


class RecordingBase:
    """What every view of `RerunSink` needs of the recording."""

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
        for path, mark in marks.robot_marks(board.shown_height):
            self.rec.log(path, mark, static=True)
        self._legend_items, self._board = legend_items, board
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

    def _event(self, event: events.Event | None) -> None:
        if event is not None:
            self.rec.log(e.EVENTS, rr.TextLog(event.text, level=LEVELS[event.level]))

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
