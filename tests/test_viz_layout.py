"""The layout a recording opens with, read back from its blueprint, against what the run
recorded: every view draws something and names nothing that is not there, nothing recorded is
outside every view; the map's default eye sees the whole run from above, and its legend below
it; the legend names the colours the map uses, and is in every map view (so a maximised map
keeps it); plots show the whole run, or a window following the cursor; the decisions' history
is shown up to the cursor; the event log's columns; the uncertainty layer off by default. As
far as the SDK shows it without a viewer (the pictures: `make docs`)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from pipeline.config import load_config
from pipeline.log import LogMetadata, read_log
from pipeline.replay import replay
from pipeline.viz import draw, legend, plots
from pipeline.viz import entities as e
from pipeline.viz.blueprint import (
    EYE_TILT,
    FRONTEND_MAP_ASPECT,
    REPLAY_MAP_ASPECT,
    frontend_blueprint,
    replay_blueprint,
)
from pipeline.viz.rerun_sink import RerunSink
from tests.recordings import (
    blueprint,
    data_rows,
    eye_coordinates,
    latest,
    read_rows,
    unfed_views,
    unseen_entities,
)
from tests.synthetic import Scene, square_loop, write_scene
from tests.test_viz import write_image_log

# the plots of every replay; the error plot where the log has a true trajectory, the wrong
# associations where its detections name their true landmark
PLOTS = {
    "Landmarks",
    "Total: switches magenta, merges ice blue",
    "Null-hypothesis rate",
    "Noise scales in use (log10; 0: as stated): "
    + ", ".join(f"{kind} {name} {colour}" for kind, name, _, colour in plots.NOISE_SERIES),
    "Time per keyframe (ms): back-end grey, recording purple",
}
ERROR = "Translation error (m): newest pose amber, final estimate blue"
WRONG = "Wrong associations (detections)"


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """A replay of a log with ground truth and no images, and one of a log with images and no
    ground truth: (log, recording) each."""
    tmp = tmp_path_factory.mktemp("layout")
    poses = square_loop(16.0, 1.0)
    landmarks = np.array([[x, y, 0.5] for x in (-3.0, 8.0, 19.0) for y in (-3.0, 19.0)])
    scene = Scene(poses, landmarks, np.arange(len(landmarks)) % 2)
    logs = [
        write_scene(tmp / "truth.mcap", scene, seed=1),
        write_image_log(tmp / "images.mcap", num_poses=4),
    ]
    out = []
    for log_path in logs:
        rrd = log_path.with_suffix(".rrd")
        sink = RerunSink.open("test", rrd=rrd)
        replay(log_path, "mm-nh", tmp / log_path.stem, load_config(), sink=sink, progress=False)
        out.append((read_log(log_path), rrd))
    return out


@pytest.mark.e2e
def test_every_view_draws_what_the_run_recorded(runs):
    for _, rrd in runs:
        assert unfed_views(rrd) == []
        assert unseen_entities(rrd) == []


@pytest.mark.e2e
def test_the_views_follow_what_the_log_holds(runs):
    (_, truth), (_, images) = runs
    names = {v.name for v in blueprint(truth)}
    assert names == {"Map", "Association events", "Summary", ERROR, WRONG} | PLOTS
    names = {v.name for v in blueprint(images)}  # truth ids on its detections, no trajectory
    assert names == {"Map", "Association events", "Summary", "Left camera", WRONG} | PLOTS


@pytest.mark.e2e
def test_the_default_eye_sees_the_whole_run_and_its_legend_from_above(runs):
    _, rrd = runs[0]
    (view,) = [v for v in blueprint(rrd) if v.name == "Map"]
    eye = view.properties["EyeControls3D"]
    position = np.array(eye["EyeControls3D:position"][0])
    target = np.array(eye["EyeControls3D:look_target"][0])
    assert eye["EyeControls3D:eye_up"][0] == [0.0, 0.0, 1.0]
    forward = (target - position) / np.linalg.norm(target - position)
    assert math.acos(-forward[2]) == pytest.approx(EYE_TILT, abs=1e-6)  # from straight down
    rows = read_rows(rrd)
    run = np.vstack(
        [
            latest(rows[e.GROUND_TRUTH_TRAJECTORY], "LineStrips3D:strips")[0],
            latest(rows[e.ODOMETRY_TRAJECTORY], "LineStrips3D:strips")[0],
        ]
    )
    board = np.vstack(
        [
            *latest(rows[e.LEGEND_LINES], "LineStrips3D:strips"),
            latest(rows[e.LEGEND_MARKS], "Points3D:positions"),
        ]
    )
    half = math.tan(0.5 * draw.RERUN_FOV_Y)
    for points in (run, board):
        across, up, depth = eye_coordinates(view, points)
        assert np.all(depth > 0)
        assert np.all(np.abs(up) <= half)
        assert np.all(np.abs(across) <= half * REPLAY_MAP_ASPECT)
    # the legend is below the run, and the run is not seen from far away: it fills at least
    # half the view's height or width
    across, up, _ = eye_coordinates(view, run)
    assert np.max(eye_coordinates(view, board)[1]) < np.min(up)
    assert max(np.ptp(up) / (2 * half), np.ptp(across) / (2 * half)) > 0.5 / REPLAY_MAP_ASPECT


def swatch_colours(rows) -> dict[str, int]:
    """The legend's swatches in the map: label -> colour."""
    lines, marks = rows[e.LEGEND_LINES], rows[e.LEGEND_MARKS]
    return dict(
        zip(
            latest(lines, "LineStrips3D:labels"),
            latest(lines, "LineStrips3D:colors"),
            strict=True,
        )
    ) | dict(zip(latest(marks, "Points3D:labels"), latest(marks, "Points3D:colors"), strict=True))


@pytest.mark.e2e
def test_the_legend_names_the_colours_of_the_map(runs):
    log, rrd = runs[0]
    rows = read_rows(rrd)
    colour = swatch_colours(rows)
    items = legend.replay_legend(log.metadata.class_names, ground_truth=True, truth_labels=True)
    # what the run drew, and no more (the legend is logged again at the end)
    assert set(colour) <= {item.label for item in items}
    assert set(legend.ALWAYS) - {"visual odometry"} <= set(colour)
    metrics = json.loads((rrd.with_suffix("") / "metrics.json").read_text())
    assert ("switch" in colour) == (metrics["switches"] > 0)
    assert ("merge" in colour) == (metrics["merges"] > 0)
    assert "chosen" in colour and "other candidate" in colour
    if metrics["association"]["null"]:
        assert "null hypothesis" in colour
    final = np.loadtxt(rrd.with_suffix("") / "landmarks.csv", delimiter=",", skiprows=1, ndmin=2)
    mapped = {int(row[4]) for row in final}
    assert {n for c, n in enumerate(log.metadata.class_names) if c in mapped} == set(colour) & set(
        log.metadata.class_names
    )
    for path, name in [
        (e.TRAJECTORY, "estimate"),
        (e.GROUND_TRUTH_TRAJECTORY, "ground truth"),
        (e.ODOMETRY_TRAJECTORY, "odometry alone"),
    ]:
        assert latest(rows[path], "LineStrips3D:colors") == [colour[name]]
    # the marks the run made, each in its legend's colour
    assert data_rows(rows[e.MERGES], "LineStrips3D:strips")  # this run merged duplicates
    (merge,) = latest(rows[e.MERGES], "LineStrips3D:colors")
    assert merge >> 8 == colour["merge"] >> 8  # the colour, half transparent
    # landmark classes: the annotation context's colours, and landmarks coloured by it alone
    (context,) = rows["/"][0]["AnnotationContext:context"]
    assert [entry["class_description"]["info"]["label"] for entry in context] == list(
        log.metadata.class_names
    )
    for entry in context:
        info = entry["class_description"]["info"]
        assert colour.get(info["label"], info["color"]) == info["color"]
    landmark = rows[e.landmark_path(0)]
    assert latest(landmark, "Points3D:class_ids") is not None
    assert latest(landmark, "Points3D:colors") is None
    # shown with their labels, and in the map's view: maximising the map keeps the legend
    assert latest(rows[e.LEGEND_MARKS], "Points3D:show_labels") == [True]
    (view,) = [v for v in blueprint(rrd) if v.kind == "3D"]
    assert view.shows(e.LEGEND_MARKS) and view.shows(e.LEGEND_LINES)


def test_the_front_end_keeps_its_legend_in_its_map_too(tmp_path):
    metadata = LogMetadata(2, ((1.0, 0.0), (0.0, 1.0)), ("tag", "box"), "test")
    sink = RerunSink.open("test", rrd=tmp_path / "frontend.rrd")
    path = np.array([[0.0, 0.0, 0.0], [30.0, 0.0, 0.0], [30.0, 50.0, 0.0]])
    sink.frontend_start(metadata, path)
    sink.frontend_finish()
    sink.close()
    rows = read_rows(tmp_path / "frontend.rrd")
    colour = swatch_colours(rows)
    assert sorted(colour) == ["box", "tag", "visual odometry"]
    (view,) = [v for v in blueprint(tmp_path / "frontend.rrd") if v.kind == "3D"]
    assert view.shows(e.LEGEND_MARKS) and view.shows(e.LEGEND_LINES)
    half = math.tan(0.5 * draw.RERUN_FOV_Y)
    board = np.vstack(
        [
            *latest(rows[e.LEGEND_LINES], "LineStrips3D:strips"),
            latest(rows[e.LEGEND_MARKS], "Points3D:positions"),
        ]
    )
    for points in (path, board):
        across, up, _ = eye_coordinates(view, points)
        assert np.all(np.abs(up) <= half) and np.all(np.abs(across) <= half * FRONTEND_MAP_ASPECT)


def time_settings(views) -> dict[str, tuple]:
    """Per plot: its time axis's range, and its time range on the pose timeline (or None)."""
    out = {}
    for view in views:
        if view.kind != "TimeSeries":
            continue
        (axis,) = view.properties["TimeAxis"]["TimeAxis:view_range"]
        ranges = view.properties.get("VisibleTimeRanges", {}).get("VisibleTimeRanges:ranges")
        pose = None
        if ranges:
            (pose,) = [r["range"] for r in ranges if r["timeline"] == e.POSE_TIMELINE]
        out[view.name] = ((axis["start"], axis["end"]), pose and (pose["start"], pose["end"]))
    return out


def test_plots_show_the_whole_run_or_a_window_that_follows_the_cursor(tmp_path):
    plot_list = plots.replay_plots(True, True, 25)
    for window in (0, 300):
        made = replay_blueprint(images=False, extent=None, plots=plot_list, plot_window=window)
        made.save("test", tmp_path / f"{window}.rbl")
    whole = time_settings(blueprint(tmp_path / "0.rbl"))
    assert sorted(whole) == sorted(p.name for p in plot_list)
    everything = (("Infinite", None), ("Infinite", None))
    assert set(whole.values()) == {(everything, None)}  # no range: every point is drawn
    following = time_settings(blueprint(tmp_path / "300.rbl"))
    window = (("CursorRelative", -300), ("CursorRelative", 0))
    assert set(following.values()) == {(window, window)}
    made = frontend_blueprint(None, plots.frontend_plots(), 0)
    made.save("test", tmp_path / "frontend.rbl")
    assert set(time_settings(blueprint(tmp_path / "frontend.rbl")).values()) == {(everything, None)}


def test_the_history_of_decisions_is_shown_up_to_the_cursor(runs):
    _, rrd = runs[0]
    (view,) = [v for v in blueprint(rrd) if v.name == "Map"]
    for path in e.HISTORY:
        ranges = view.properties[f"ViewContents/overrides{path}/visualizers"]
        assert {
            (r["timeline"], r["range"]["start"], r["range"]["end"])
            for r in ranges["VisibleTimeRanges:ranges"]
        } == {
            (timeline, ("Infinite", None), ("CursorRelative", 0))
            for timeline in (e.POSE_TIMELINE, e.TIME_TIMELINE)
        }
    # the map itself shows the latest at the cursor: its trail is the re-logged trajectory
    assert "VisibleTimeRanges" not in view.properties


@pytest.mark.e2e
def test_the_event_log_shows_level_and_text_and_the_uncertainty_layer_is_off(runs):
    _, rrd = runs[0]
    views = {v.name: v for v in blueprint(rrd)}
    columns = views["Association events"].properties["TextLogColumns"]
    shown = [c["kind"] for c in columns["TextLogColumns:text_log_columns"] if c["visible"]]
    assert shown == [2, 3]  # level and body: every event is /events, and its text names its pose
    assert not any(c["visible"] for c in columns["TextLogColumns:timeline_columns"])
    hidden = views["Map"].properties["ViewContents/overrides/world/uncertainty/visualizers"]
    assert hidden["EntityBehavior:visible"] == [False]
    assert data_rows(read_rows(rrd)[e.UNCERTAINTY], "Ellipsoids3D:half_sizes")
