"""`mmslam compare`: each method's outputs in its own folder, and one recording of every run,
read back with Rerun's own reader: each run under its own root on the shared pose timeline,
its final estimate the one its folder holds, a map a method with its legend, a line a method
in each plot, the table of results; the recording verified by `rerun rrd verify`; nothing
written when a run fails; the same outputs whatever the number of worker processes."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest

from pipeline.backend.methods import METHODS as ALL_METHODS
from pipeline.cli import main
from pipeline.compare import compare
from pipeline.viz import entities as e
from pipeline.viz.comparison import LEGEND_ROOT, METHOD_COLOURS, SUMMARY, moved_path, run_root
from pipeline.viz.draw import WRONG_RGB, class_colors, packed_rgba
from pipeline.viz.stream import rerun_executable
from tests.recordings import (
    blueprint,
    containers,
    data_rows,
    latest,
    read_rows,
    unfed_views,
    unseen_entities,
)
from tests.synthetic import Scene, square_loop, write_scene

METHODS = ["known", "ml", "mm-nh"]


def small_log(path: Path, truth_ids: bool = True) -> Path:
    poses = square_loop(12.0, 1.0)
    landmarks = np.array([[x, y, 0.5] for x in (-3.0, 6.0, 15.0) for y in (-3.0, 15.0)])
    scene = Scene(poses, landmarks, np.arange(len(landmarks)) % 2)
    return write_scene(path, scene, seed=2, odom_noise=3.0, truth_ids=truth_ids)


@pytest.fixture(scope="module")
def compared(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("compare")
    log_path = small_log(tmp / "log.mcap")
    results = compare(log_path, METHODS, tmp / "runs", rrd=tmp / "all.rrd", progress=False)
    return tmp, results


def tum_positions(path: Path) -> np.ndarray:
    return np.loadtxt(path)[:, 1:4]


def test_each_method_writes_what_replay_writes_in_its_own_folder(compared):
    tmp, results = compared
    assert [r.method for r in results] == METHODS
    for result in results:
        folder = tmp / "runs" / result.method
        assert result.out_dir == folder
        names = {p.name for p in folder.iterdir()}
        assert {"trajectory.tum", "landmarks.csv", "associations.csv", "metrics.json"} <= names
        assert json.loads((folder / "metrics.json").read_text())["method"] == result.method


def test_every_run_is_under_its_own_root_on_the_same_timeline(compared):
    tmp, results = compared
    rows = read_rows(tmp / "all.rrd")
    roots = {path.split("/")[2] for path in rows if path.startswith("/runs/")}
    assert roots == set(METHODS)
    outside = {p for p in rows if not p.startswith(("/runs/", "/__properties"))}
    assert outside == {SUMMARY, LEGEND_ROOT, LEGEND_ROOT + "/lines", LEGEND_ROOT + "/marks"}
    for result in results:
        root = run_root(result.method)
        # the final estimate drawn is the one the run's folder holds
        estimate = latest(rows[root + e.TRAJECTORY], "LineStrips3D:strips")[0]
        expected = tum_positions(result.out_dir / "trajectory.tum")
        np.testing.assert_allclose(estimate, expected, atol=1e-5)
        # the robot at every pose of the log's timeline
        robot = data_rows(rows[root + e.ROBOT], "Transform3D:translation")
        assert [r["pose"] for r in robot] == list(range(result.num_poses))
        # no legend of its own: one beside the maps names what every run drew
        assert root + e.LEGEND_MARKS not in rows and root + e.LEGEND_LINES not in rows
        # the plotted lines named and coloured by method
        rgb, _ = METHOD_COLOURS[result.method]
        for path in (e.LANDMARK_COUNT, e.NULL_RATE, e.WRONG_COUNT, e.ERROR_ONLINE):
            style = rows[root + path]  # static: the last one logged is the one shown
            assert latest(style, "SeriesLines:names") == [result.method], path
            assert latest(style, "SeriesLines:colors") == [int(packed_rgba(rgb))], path
        # each run's description, a property of the comparison named after its method
        assert rows[f"/__properties/{result.method}"][0]["method"] == [result.method]


def test_the_maps_side_by_side_one_legend_and_a_line_a_method_in_each_plot(compared):
    tmp, results = compared
    rrd = tmp / "all.rrd"
    views = blueprint(rrd)
    spatial = {v.id: v for v in views if v.kind == "3D"}
    (row,) = [c for c in containers(rrd) if set(c) == set(spatial)]  # side by side, in order
    *maps, key = [spatial[i] for i in row]
    assert [v.origin for v in maps] == [run_root(m) + e.WORLD for m in METHODS]
    for view, method in zip(maps, METHODS, strict=True):
        assert view.name.startswith(method)
        assert not view.shows(run_root("ml" if method != "ml" else "known") + e.TRAJECTORY)
    assert (key.name, key.origin) == ("Legend", LEGEND_ROOT)
    # the legend names what any run drew: known weighs no candidates, the others do
    rows = read_rows(rrd)
    named = latest(rows[LEGEND_ROOT + "/lines"], "LineStrips3D:labels")
    named += latest(rows[LEGEND_ROOT + "/marks"], "Points3D:labels")
    assert {"estimate", "ground truth", "odometry alone", "robot", "other candidate"} <= set(named)
    # a switch is drawn where an earlier keyframe's detection changed landmark (one that changes
    # at its own keyframe, counted in metrics.json's switches, is drawn as its keyframe's)
    drawn = [
        data_rows(rows.get(run_root(m) + e.SWITCHES, []), "LineStrips3D:strips") for m in METHODS
    ]
    assert ("switch" in named) == any(drawn)
    assert ("merge" in named) == any(r.metrics["merges"] for r in results)
    plots = [v for v in views if v.kind == "TimeSeries"]
    # errors newest and final, wrong, landmarks, null rate, time, switches, merges
    assert len(plots) == 8
    for view in plots:
        lines = [q.removeprefix("+ ") for q in view.query]
        # known, the reference, first: drawn beneath the others
        assert [line.split("/")[2] for line in lines] == METHODS
        assert len({line.split("/", 3)[3] for line in lines}) == 1  # the same metric
        assert view.properties["PlotLegend"]["PlotLegend:visible"] == [True]
    assert unfed_views(rrd) == []
    assert unseen_entities(rrd) == []


def test_the_table_of_results(compared):
    tmp, results = compared
    (text,) = latest(read_rows(tmp / "all.rrd")[SUMMARY], "TextDocument:text")
    rows = [line for line in text.splitlines() if line.startswith("| **")]
    assert len(rows) == len(METHODS)
    for row, result in zip(rows, results, strict=True):
        cells = [c.strip() for c in row.strip("|").split("|")]
        assert cells[0] == f"**{result.method}**"
        rmse = result.metrics["translation_error_m"]["rmse"]
        assert float(cells[1]) == pytest.approx(rmse, abs=5e-4)
        association = result.metrics["association"]
        assert float(cells[2]) == pytest.approx(
            result.metrics["translation_error_m"]["max"], abs=5e-4
        )
        assert [int(c) for c in cells[3:6]] == [
            association["wrong"],
            association["null"],
            association["correct"],
        ]
        assert int(cells[6]) == result.num_landmarks


@pytest.mark.skipif(rerun_executable() is None, reason="no rerun executable")
def test_rerun_verifies_the_recording(compared):
    tmp, _ = compared
    done = subprocess.run(
        [rerun_executable(), "rrd", "verify", str(tmp / "all.rrd")],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr


def test_runs_in_worker_processes_give_the_same_outputs(tmp_path, compared):
    tmp, _ = compared
    compare(tmp / "log.mcap", ["ml", "mm-nh"], tmp_path / "runs", workers=2, progress=False)
    for method in ("ml", "mm-nh"):
        mine = (tmp_path / "runs" / method / "associations.csv").read_text()
        assert mine == (tmp / "runs" / method / "associations.csv").read_text()


def test_a_failed_run_writes_no_recording(tmp_path, capsys):
    log_path = small_log(tmp_path / "log.mcap", truth_ids=False)
    target = tmp_path / "all.rrd"
    status = main(["compare", str(log_path), "--methods", "ml,known", "--out",
                   str(tmp_path / "runs"), "--rrd", str(target), "-q"])  # fmt: skip
    err = capsys.readouterr().err
    assert status == 2 and "truth_landmark_id" in err and len(err.strip().splitlines()) == 1
    assert not target.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".all.rrd")]


@pytest.mark.parametrize(
    ("methods", "needle"), [("ml,ml", "twice"), ("ml,bogus", "expected methods"), (",", "expected")]
)
def test_bad_method_lists_are_usage_errors(tmp_path, capsys, methods, needle):
    with pytest.raises(SystemExit) as info:
        main(["compare", "x.mcap", "--methods", methods, "--out", str(tmp_path)])
    assert info.value.code == 2
    assert needle in capsys.readouterr().err


def test_where_a_run_entity_goes():
    assert moved_path("/world/robot", "ml") == "/runs/ml/world/robot"
    assert moved_path("/", "mm-nh") == "/runs/mm-nh"  # the class colours, for its subtree
    assert moved_path("/__properties/run", "ml") == "/__properties/ml"
    assert moved_path("/__properties", "ml") is None  # the comparison names itself
    assert moved_path(e.VIZ_MS, "ml") is None  # what recording cost: nothing of the method
    assert moved_path(e.LEGEND_MARKS, "ml") is None  # the comparison has one legend


def test_every_method_has_a_colour_of_its_own_none_red_nor_a_class_colour():
    assert set(METHOD_COLOURS) == set(ALL_METHODS)
    colours = [rgb for rgb, _ in METHOD_COLOURS.values()]
    names = [name for _, name in METHOD_COLOURS.values()]
    assert len(set(colours)) == len(colours) and len(set(names)) == len(names)
    assert WRONG_RGB not in colours
    classes = {tuple(int(v) for v in rgb) for rgb in class_colors(len(ALL_METHODS) + 4)}
    assert not classes & set(colours)
