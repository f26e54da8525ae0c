"""The layout a recording opens with. A replay: the map, looked down on from above with its
legend drawn below it; the camera (when there are images), the run's summary and the
association events beside it; the time series across the bottom; the pose timeline below.
A front-end run: visual odometry and its legend; the camera and its counts. A comparison of
methods: `comparison.py`, from the same parts.

Time: plots show the whole run (`[viz] plot_window = 0`) or a window of the last poses that
follows the time cursor. The map shows each entity's latest value at the cursor (the
trajectory is re-logged whole, so its trail is the whole run so far), except the history of
decisions, shown from pose 0 to the cursor.
"""

from __future__ import annotations

import math

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from pipeline.viz import draw
from pipeline.viz import entities as e
from pipeline.viz.plots import Plot

# The map view's width over its height in these layouts at a 16:10 window: the default eye is
# placed to see the whole map at this shape (another shape only changes the margin), and the
# legend's board is laid out for it.
REPLAY_MAP_ASPECT = 1.75
FRONTEND_MAP_ASPECT = 0.9
# Tilt of the default eye from straight down (rad): a Z-up orbit needs the eye off the vertical.
EYE_TILT = math.radians(12.0)
TIMELINES = (e.POSE_TIMELINE, e.TIME_TIMELINE)


def plot_time(window: int) -> dict:
    """A plot's time axis and time range: the whole run (`window` 0), or the last `window`
    poses up to the time cursor. Without them the viewer shows a window of about 1,500 poses
    around the cursor, so a long run is never seen whole."""
    if window == 0:
        whole = rrb.TimeRange(
            start=rrb.TimeRangeBoundary.infinite(), end=rrb.TimeRangeBoundary.infinite()
        )
        return {"axis_x": rrb.TimeAxis(view_range=whole)}
    start = rrb.TimeRangeBoundary.cursor_relative(seq=-window)
    end = rrb.TimeRangeBoundary.cursor_relative(seq=0)
    return {
        "axis_x": rrb.TimeAxis(view_range=rrb.TimeRange(start=start, end=end)),
        "time_ranges": rrb.VisibleTimeRange(e.POSE_TIMELINE, start=start, end=end),
    }


def plot_view(plot: Plot, window: int, legend: bool = False) -> rrb.TimeSeriesView:
    """A plot's view: its lines, over the whole run or a following window; a legend in its
    top left corner with `legend` (else the title names the lines)."""
    return rrb.TimeSeriesView(
        name=plot.name,
        origin="/",
        contents=[f"+ {p}" for p in plot.paths],
        plot_legend=rrb.PlotLegend(rrb.Corner2D.LeftTop, visible=legend),
        **plot_time(window),
    )


def _until_cursor() -> rrb.VisibleTimeRanges:
    """From the start of the run to the time cursor, on either timeline."""
    return rrb.VisibleTimeRanges(
        [
            rrb.VisibleTimeRange(
                timeline,
                start=rrb.TimeRangeBoundary.infinite(),
                end=rrb.TimeRangeBoundary.cursor_relative(),
            )
            for timeline in TIMELINES
        ]
    )


def map_view(
    name: str, extent: np.ndarray | None, aspect: float, root: str = ""
) -> rrb.Spatial3DView:
    """A 3-D view of `root`'s world whose eye looks down on every point of `extent` (N, 3),
    if given, in a view of this `aspect`; every landmark's ellipsoid hidden (one click away in
    the blueprint panel), the history of decisions shown up to the cursor."""
    eye = rrb.EyeControls3D(kind="Orbital")
    if extent is not None and len(extent):
        position, target = draw.top_down_eye(extent, aspect, EYE_TILT)
        eye = rrb.EyeControls3D(
            kind="Orbital", position=position, look_target=target, eye_up=(0.0, 0.0, 1.0)
        )
    overrides: dict = {root + e.UNCERTAINTY: rrb.EntityBehavior(visible=False)}
    overrides.update({root + path: _until_cursor() for path in e.HISTORY})
    return rrb.Spatial3DView(
        name=name,
        origin=root + e.WORLD,
        eye_controls=eye,
        line_grid=rrb.LineGrid3D(visible=True, spacing=10.0),
        overrides=overrides,
    )


def legend_view(name: str, origin: str, extent: np.ndarray, aspect: float) -> rrb.Spatial3DView:
    """A view of a legend's board alone (`extent`: its corners), from above, without a grid."""
    position, target = draw.top_down_eye(extent, aspect, EYE_TILT)
    eye = rrb.EyeControls3D(
        kind="Orbital", position=position, look_target=target, eye_up=(0.0, 0.0, 1.0)
    )
    return rrb.Spatial3DView(
        name=name, origin=origin, eye_controls=eye, line_grid=rrb.LineGrid3D(visible=False)
    )


def events_view(name: str, origin: str, contents: list[str] | None = None) -> rrb.TextLogView:
    """An event log; with `contents` (several runs' logs), each line names its entity."""
    return rrb.TextLogView(
        name=name,
        origin=origin,
        contents=contents or "$origin/**",
        # The body names its pose: Rerun's timeline column is too narrow to read ("#2...").
        columns=rrb.TextLogColumns(
            timeline_columns=[rrb.encodings.TimelineColumn(e.POSE_TIMELINE, visible=False)],
            text_log_columns=["entitypath", "loglevel", "body"]
            if contents
            else ["loglevel", "body"],
        ),
    )


def panels() -> list:
    return [
        rrb.TimePanel(timeline=e.POSE_TIMELINE, state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.BlueprintPanel(state="collapsed"),
    ]


def series_styles(plots: list[Plot]) -> list[tuple[str, rr.SeriesLines]]:
    """(entity, its line's name, colour and width) for every line of these plots: logged
    static."""
    return [
        (s.path, rr.SeriesLines(names=s.name, colors=s.rgb, widths=s.width))
        for plot in plots
        for s in plot.series
    ]


def replay_blueprint(
    *, images: bool, extent: np.ndarray | None, plots: list[Plot], plot_window: int
) -> rrb.Blueprint:
    """Layout of a replay: the map (its legend below it) beside the camera, the summary and
    the events; the time series across the whole width below, so that a long run's curves
    get every pixel. `extent`: points the default eye should see (the reference
    trajectories, the legend)."""
    side: list[rrb.View] = []
    if images:
        side.append(rrb.Spatial2DView(name="Left camera", origin=e.CAMERA))
    side += [
        rrb.TextDocumentView(name="Summary", origin=e.SUMMARY),
        events_view("Association events", e.EVENTS),
    ]
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(
                map_view("Map", extent, REPLAY_MAP_ASPECT),
                rrb.Vertical(*side, row_shares=[2.2, 3, 2] if images else [1, 1]),
                column_shares=[3, 2],
            ),
            rrb.Grid(*[plot_view(p, plot_window) for p in plots], grid_columns=3),
            row_shares=[6, 4],
        ),
        *panels(),
    )


def frontend_blueprint(
    extent: np.ndarray | None, plots: list[Plot], plot_window: int
) -> rrb.Blueprint:
    """Layout of a front-end run: visual odometry and detections (its legend below), the
    camera, counts."""
    return rrb.Blueprint(
        rrb.Horizontal(
            map_view("Visual odometry", extent, FRONTEND_MAP_ASPECT),
            rrb.Vertical(
                rrb.Spatial2DView(name="Left camera", origin=e.CAMERA),
                rrb.Grid(*[plot_view(p, plot_window) for p in plots], grid_columns=2),
                row_shares=[1, 1],
            ),
            column_shares=[1, 1],
        ),
        *panels(),
    )
