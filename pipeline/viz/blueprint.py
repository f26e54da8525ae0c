"""The layout a recording opens with. A replay: the map, looked down on from above, with its
legend and the association events below it; the camera (when there are images), the time
series and the run's summary on the right; the pose timeline at the bottom. A front-end run:
visual odometry and its legend; the camera and its counts."""

from __future__ import annotations

import math

import numpy as np
import rerun.blueprint as rrb

from pipeline.viz import draw
from pipeline.viz import entities as e

# The map view's width over its height in these layouts at a 16:10 window: the default eye is
# placed to see the whole map at this shape (another shape only changes the margin).
REPLAY_MAP_ASPECT = 1.6
FRONTEND_MAP_ASPECT = 0.95
# Tilt of the default eye from straight down (rad): a Z-up orbit needs the eye off the vertical.
EYE_TILT = math.radians(12.0)
# Legend swatches: at most this many a row, this far apart (in the legend view's units, rows
# one unit apart: about 150 px between swatches at the view's default height).
LEGEND_PER_ROW = 6
LEGEND_SPACING = 5.0


def _plot(name: str, *paths: str) -> rrb.TimeSeriesView:
    return rrb.TimeSeriesView(
        name=name,
        origin=e.METRICS,
        contents=[f"+ {p}" for p in paths],
        plot_legend=rrb.PlotLegend(corner="LeftTop"),
    )


def _map_view(name: str, extent: np.ndarray | None, aspect: float) -> rrb.Spatial3DView:
    """A 3-D view whose eye looks down on every point of `extent` (N, 3), if given, in a view
    of this `aspect`."""
    eye = rrb.EyeControls3D(kind="Orbital")
    if extent is not None and len(extent):
        position, target = draw.top_down_eye(extent, aspect, EYE_TILT)
        eye = rrb.EyeControls3D(
            kind="Orbital", position=position, look_target=target, eye_up=(0.0, 0.0, 1.0)
        )
    return rrb.Spatial3DView(
        name=name,
        origin=e.WORLD,
        eye_controls=eye,
        line_grid=rrb.LineGrid3D(visible=True, spacing=10.0),
        # Every landmark's ellipsoid: one click away in the blueprint panel, off by default.
        overrides={e.UNCERTAINTY: rrb.EntityBehavior(visible=False)},
    )


def legend_per_row(count: int) -> int:
    """Swatches a row: two rows when one would be crowded, never more than LEGEND_PER_ROW."""
    return min(LEGEND_PER_ROW, max(1, math.ceil(count / 2) if count > 4 else count))


def _legend_view(count: int) -> tuple[rrb.Spatial2DView, float]:
    """The legend's view, and its share of the map's column (the map's is 10)."""
    per_row = legend_per_row(count)
    rows = math.ceil(count / per_row)
    view = rrb.Spatial2DView(
        name="Legend",
        origin=e.LEGEND,
        titlebar=False,
        visual_bounds=rrb.VisualBounds2D(
            x_range=[-0.5 * LEGEND_SPACING, (per_row - 0.5) * LEGEND_SPACING],
            y_range=[-0.5, rows + 0.2],  # room for the labels below the last row
        ),
    )
    return view, 0.2 + 0.6 * rows


def _panels() -> list:
    return [
        rrb.TimePanel(timeline=e.POSE_TIMELINE, state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.BlueprintPanel(state="collapsed"),
    ]


def replay_blueprint(
    *, images: bool, ground_truth: bool, extent: np.ndarray | None, legend_items: int
) -> rrb.Blueprint:
    """Layout of a replay: map, legend, events; camera, time series, summary. `extent`: points
    the default eye should see (the reference trajectories)."""
    plots: list[rrb.View] = []
    if ground_truth:
        plots.append(_plot("Translation error (m)", e.ERROR_ONLINE, e.ERROR_FINAL))
    plots += [
        _plot("Landmarks and switches", e.LANDMARK_COUNT, e.SWITCH_COUNT),
        _plot("Null-hypothesis rate", e.NULL_RATE),
        _plot("Time per keyframe (ms)", e.STEP_MS, e.VIZ_MS),
    ]
    events = rrb.TextLogView(
        name="Association events",
        origin=e.EVENTS,
        # The body names its pose: Rerun's timeline column is too narrow to read ("#2...").
        columns=rrb.TextLogColumns(
            timeline_columns=[rrb.encodings.TimelineColumn(e.POSE_TIMELINE, visible=False)],
            text_log_columns=["loglevel", "body"],
        ),
    )
    right: list[rrb.Container | rrb.View] = []
    if images:
        right.append(rrb.Spatial2DView(name="Left camera", origin=e.CAMERA))
    right += [
        rrb.Grid(*plots, grid_columns=2),
        rrb.TextDocumentView(name="Summary", origin=e.SUMMARY),
    ]
    legend, legend_share = _legend_view(legend_items)
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                _map_view("Map", extent, REPLAY_MAP_ASPECT),
                legend,
                events,
                row_shares=[10, legend_share, 3.5],
            ),
            rrb.Vertical(*right, row_shares=[2.2, 4, 2] if images else [4, 1.6]),
            column_shares=[3, 2],
        ),
        *_panels(),
    )


def frontend_blueprint(extent: np.ndarray | None, legend_items: int) -> rrb.Blueprint:
    """Layout of a front-end run: visual odometry and detections, the camera, counts."""
    legend, legend_share = _legend_view(legend_items)
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                _map_view("Visual odometry", extent, FRONTEND_MAP_ASPECT),
                legend,
                row_shares=[10, legend_share],
            ),
            rrb.Vertical(
                rrb.Spatial2DView(name="Left camera", origin=e.CAMERA),
                rrb.Grid(
                    _plot("Detections per keyframe", e.TAG_COUNT, e.BOX_COUNT),
                    _plot("VO inliers", e.VO_INLIERS),
                    grid_columns=2,
                ),
                row_shares=[1, 1],
            ),
            column_shares=[1, 1],
        ),
        *_panels(),
    )
