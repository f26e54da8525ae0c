"""The layout a recording opens with: the 3-D map on the left; the camera (when there are
images), the time series and the association events on the right; the pose timeline."""

from __future__ import annotations

import rerun.blueprint as rrb

from pipeline.viz import entities as e


def _plot(name: str, *paths: str) -> rrb.TimeSeriesView:
    return rrb.TimeSeriesView(
        name=name,
        origin=e.METRICS,
        contents=[f"+ {p}" for p in paths],
        plot_legend=rrb.PlotLegend(corner="LeftTop"),
    )


def _map_view(name: str) -> rrb.Spatial3DView:
    # The robot's neighbourhood is what matters while a run streams; `Orbital` keeps the map
    # Z-up under the mouse.
    return rrb.Spatial3DView(
        name=name,
        origin=e.WORLD,
        eye_controls=rrb.EyeControls3D(kind="Orbital"),
        line_grid=rrb.LineGrid3D(visible=True, spacing=10.0),
    )


def replay_blueprint(*, images: bool, ground_truth: bool) -> rrb.Blueprint:
    """Layout of a replay: map, camera, time series, events."""
    plots: list[rrb.View] = []
    if ground_truth:
        plots.append(_plot("Translation error (m)", e.ERROR_ONLINE, e.ERROR_FINAL))
    plots += [
        _plot("Landmarks and switches", e.LANDMARK_COUNT, e.SWITCH_COUNT),
        _plot("Null-hypothesis rate", e.NULL_RATE),
        _plot("Time per keyframe (ms)", e.STEP_MS, e.VIZ_MS),
    ]
    right: list[rrb.Container | rrb.View] = []
    if images:
        right.append(rrb.Spatial2DView(name="Left camera", origin=e.CAMERA))
    right.append(rrb.Grid(*plots, grid_columns=2))
    right.append(
        rrb.Tabs(
            rrb.TextLogView(name="Association events", origin=e.EVENTS),
            rrb.TextDocumentView(name="Summary", origin=e.SUMMARY),
        )
    )
    shares = [2, 3, 1] if images else [3, 1]
    return rrb.Blueprint(
        rrb.Horizontal(
            _map_view("Map"),
            rrb.Vertical(*right, row_shares=shares),
            column_shares=[3, 2],
        ),
        rrb.TimePanel(timeline=e.POSE_TIMELINE, state="expanded"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.BlueprintPanel(state="collapsed"),
    )


def frontend_blueprint() -> rrb.Blueprint:
    """Layout of a front-end run: visual odometry and detections, the camera, counts."""
    return rrb.Blueprint(
        rrb.Horizontal(
            _map_view("Visual odometry"),
            rrb.Vertical(
                rrb.Spatial2DView(name="Left camera", origin=e.CAMERA),
                rrb.Grid(
                    _plot("Detections per keyframe", e.TAG_COUNT, e.BOX_COUNT),
                    _plot("VO inliers", e.VO_INLIERS),
                    grid_columns=2,
                ),
                row_shares=[3, 2],
            ),
            column_shares=[1, 1],
        ),
        rrb.TimePanel(timeline=e.POSE_TIMELINE, state="expanded"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.BlueprintPanel(state="collapsed"),
    )
