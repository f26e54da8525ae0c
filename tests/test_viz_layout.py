"""The layout a recording opens with, read back from its blueprint, against what the run
recorded: every view draws something and names nothing that is not there, nothing recorded is
outside every view; the map's default eye sees the whole run from above; the legend names the
colours the map uses; the event log's columns; the uncertainty layer off by default. As far as
the SDK shows it without a viewer (the picture itself: README, "Watching a run in Rerun")."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.config import load_config
from pipeline.log import read_log
from pipeline.replay import replay
from pipeline.viz import draw
from pipeline.viz import entities as e
from pipeline.viz.blueprint import EYE_TILT, REPLAY_MAP_ASPECT
from pipeline.viz.rerun_sink import RerunSink
from tests.recordings import (
    blueprint,
    data_rows,
    latest,
    read_rows,
    unfed_views,
    unseen_entities,
)
from tests.synthetic import Scene, square_loop, write_scene
from tests.test_viz import write_image_log

PLOTS = {"Landmarks and switches", "Null-hypothesis rate", "Time per keyframe (ms)"}


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
    assert names == {"Map", "Legend", "Association events", "Summary", "Translation error (m)"} | (
        PLOTS
    )
    names = {v.name for v in blueprint(images)}
    assert names == {"Map", "Legend", "Association events", "Summary", "Left camera"} | PLOTS


@pytest.mark.e2e
def test_the_default_eye_sees_the_whole_run_from_above(runs):
    _, rrd = runs[0]
    (view,) = [v for v in blueprint(rrd) if v.name == "Map"]
    eye = view.properties["EyeControls3D"]
    position = np.array(eye["EyeControls3D:position"][0])
    target = np.array(eye["EyeControls3D:look_target"][0])
    assert eye["EyeControls3D:eye_up"][0] == [0.0, 0.0, 1.0]
    forward = (target - position) / np.linalg.norm(target - position)
    assert math.acos(-forward[2]) == pytest.approx(EYE_TILT, abs=1e-6)  # from straight down
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    rows = read_rows(rrd)
    points = np.vstack(
        [
            latest(rows[e.GROUND_TRUTH_TRAJECTORY], "LineStrips3D:strips")[0],
            latest(rows[e.ODOMETRY_TRAJECTORY], "LineStrips3D:strips")[0],
        ]
    )
    v = points - position
    depth = v @ forward
    half = math.tan(0.5 * draw.RERUN_FOV_Y)
    assert np.all(depth > 0)
    assert np.all(np.abs(v @ up) / depth <= half)
    assert np.all(np.abs(v @ right) / depth <= half * REPLAY_MAP_ASPECT)
    # and not from far away: the run fills at least half the view's height or width
    extent = max(np.ptp(v @ up / depth) / (2 * half), np.ptp(v @ right / depth) / (2 * half))
    assert extent > 0.5 / REPLAY_MAP_ASPECT


@pytest.mark.e2e
def test_the_legend_names_the_colours_of_the_map(runs):
    log, rrd = runs[0]
    rows = read_rows(rrd)
    lines = latest(rows[e.LEGEND_LINES], "LineStrips2D:labels")
    marks = latest(rows[e.LEGEND_MARKS], "Points2D:labels")
    items = draw.replay_legend(log.metadata.class_names, ground_truth=True)
    assert sorted(lines + marks) == sorted(item.label for item in items)
    colour = dict(
        zip(lines, latest(rows[e.LEGEND_LINES], "LineStrips2D:colors"), strict=True)
    ) | dict(zip(marks, latest(rows[e.LEGEND_MARKS], "Points2D:colors"), strict=True))
    for path, name in [
        (e.TRAJECTORY, "estimate"),
        (e.GROUND_TRUTH_TRAJECTORY, "ground truth"),
        (e.ODOMETRY_TRAJECTORY, "odometry alone"),
    ]:
        assert latest(rows[path], "LineStrips3D:colors") == [colour[name]]
    # landmark classes: the annotation context's colours, and landmarks coloured by it alone
    (context,) = rows["/"][0]["AnnotationContext:context"]
    assert [entry["class_description"]["info"]["label"] for entry in context] == list(
        log.metadata.class_names
    )
    for entry in context:
        info = entry["class_description"]["info"]
        assert colour[info["label"]] == info["color"]
    landmark = rows[e.landmark_path(0)]
    assert latest(landmark, "Points3D:class_ids") is not None
    assert latest(landmark, "Points3D:colors") is None
    # every swatch inside the legend's bounds
    (view,) = [v for v in blueprint(rrd) if v.name == "Legend"]
    bounds = view.properties["VisualBounds2D"]["VisualBounds2D:range"][0]
    swatches = np.vstack(
        [
            *latest(rows[e.LEGEND_LINES], "LineStrips2D:strips"),
            latest(rows[e.LEGEND_MARKS], "Points2D:positions"),
        ]
    )
    for axis, key in enumerate(("x_range", "y_range")):
        low, high = bounds[key]
        assert np.all((swatches[:, axis] > low) & (swatches[:, axis] < high))


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
