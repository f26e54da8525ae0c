"""What a recording draws and says, as pure functions against hand-worked values: the default
eye, the trailing median, the legend's items and its board in the map, labels and which of them
fit, hypothesis colours, the plots' titles, the event log's lines and levels, the summary."""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np
import pytest

from pipeline.backend.hypotheses import NULL
from pipeline.log import Detection
from pipeline.viz import draw, events, frame, labels, legend, plots
from pipeline.viz.summary import RunState, comparison_markdown, summary_markdown


def test_the_eye_above_a_map_sees_all_of_it():
    points = np.array([[0.0, 0.0, 0.0], [20.0, 10.0, 0.0], [5.0, 2.0, 0.0]])
    right_angle = math.radians(90.0)  # tan(45°) = 1: the distance is the half height needed
    # 2:1 view: half height max(10 / 2, 20 / 2 / 2) = 5, straight down from (10, 5)
    position, target = draw.top_down_eye(points, 2.0, 0.0, margin=1.0, fov_y=right_angle)
    np.testing.assert_allclose(target, [10.0, 5.0, 0.0])
    np.testing.assert_allclose(position, [10.0, 5.0, 5.0])
    # 1:1 view: the width decides, 10 * 1.2; tilted by 30° towards -y
    position, _ = draw.top_down_eye(points, 1.0, math.radians(30.0), 1.2, right_angle)
    np.testing.assert_allclose(position, [10.0, 5.0 - 12.0 * 0.5, 12.0 * math.sqrt(3) / 2])
    # one point: a view a metre across; height adds half the box's depth
    position, _ = draw.top_down_eye(np.array([[1.0, 2.0, 0.0], [1.0, 2.0, 4.0]]), 1.0, 0.0,
                                    1.0, right_angle)  # fmt: skip
    np.testing.assert_allclose(position, [1.0, 2.0, 2.0 + 1.0 + 2.0])


def test_trailing_median():
    assert draw.trailing_median([1.0, 100.0, 2.0, 3.0], 3) == 3.0
    assert draw.trailing_median([1.0, 100.0], 3) == pytest.approx(50.5)  # a mean of two
    assert draw.trailing_median([7.0], 25) == 7.0


def test_legend_items():
    items = legend.replay_legend(("car", "sign"), ground_truth=False)
    names = [item.label for item in items]
    assert names[:3] == ["car", "sign", "estimate"] and "ground truth" not in names
    assert "wrong association" not in names  # only where detections name their truth
    assert [item.rgb for item in items[:2]] == [tuple(c) for c in draw.class_colors(2)]
    assert len({item.rgb for item in items}) == len(items)  # every colour its own
    items = legend.replay_legend(("car",), ground_truth=True, truth_labels=True)
    by_name = {item.label: item for item in items}
    assert by_name["wrong association"].rgb == draw.WRONG_RGB and by_name["wrong association"].line
    assert {"null hypothesis", "merge", "switch", "ground truth"} <= set(by_name)
    assert len({item.rgb for item in items}) == len(items)


def test_legend_board_below_the_map():
    # a 20 x 10 map in a square view: four columns; the width decides what the eye shows
    # (20 m), so rows are 20 / 16 m apart and columns 20 / 4 m, centred under the map
    assert (legend.ROWS_PER_VIEW, legend.board_columns(1.0)) == (16, 4)
    board = legend.legend_board(5, np.array([0.0, 0.0, 1.0]), np.array([20.0, 10.0, 3.0]), 1.0)
    row, column = 20.0 / 16.0, 5.0
    np.testing.assert_allclose(
        board.centres,
        [
            [2.5, -row, 1.0],
            [7.5, -row, 1.0],
            [12.5, -row, 1.0],
            [17.5, -row, 1.0],
            [2.5, -2 * row, 1.0],
        ],
    )
    assert board.half_line == pytest.approx(0.3 * column)
    assert board.shown_height == pytest.approx(20.0)
    # the labels' room below the last row is part of what the eye must see
    assert board.extent[:, 1].min() == pytest.approx(-row * 2.8)
    # a tall map: its height and the board (3 rows, the labels' room) share what the eye
    # shows, 16 rows of it
    board = legend.legend_board(13, np.zeros(3), np.array([10.0, 100.0, 0.0]), 1.6)
    assert legend.board_columns(1.6) == 6
    shown = board.shown_height
    assert shown == pytest.approx(100.0 / (1.0 - 3.8 / 16.0))
    assert board.row_spacing == pytest.approx(shown / 16.0)


@pytest.mark.parametrize("aspect", [0.8, 1.0, 1.75, 2.5])
@pytest.mark.parametrize("size", [(300.0, 200.0), (40.0, 400.0), (1.0, 1.0)])
def test_the_default_eye_sees_the_map_and_its_legend(aspect, size):
    """Every swatch and its label's room inside the view of the eye placed over map and board,
    rows a fixed share of the view's height apart (the labels stay legible)."""
    low, high = np.zeros(3), np.array([size[0], size[1], 0.0])
    board = legend.legend_board(14, low, high, aspect)
    points = np.vstack([low, high, board.extent])
    position, target = draw.top_down_eye(points, aspect, 0.0, margin=1.0)
    half_height = math.tan(0.5 * draw.RERUN_FOV_Y) * (position[2] - target[2])
    for corner in [*board.extent, *board.centres]:
        assert abs(corner[1] - target[1]) <= half_height * (1 + 1e-9)
        assert abs(corner[0] - target[0]) <= half_height * aspect * (1 + 1e-9)
    assert board.row_spacing == pytest.approx(2 * half_height / legend.ROWS_PER_VIEW)
    assert np.all(board.centres[:, 1] < low[1])  # below the map


def test_the_map_is_laid_out_round_what_the_detections_saw():
    # pose 0 at the origin; pose 1 ten metres on, turned left a quarter
    turned = np.eye(4)
    turned[:3, :3] = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    turned[:3, 3] = [10.0, 0.0, 0.0]
    poses = np.array([np.eye(4), turned])
    # 5 m ahead of pose 0; 2 m ahead of pose 1 (its ahead is +y); 3 m to pose 1's left; a
    # false detection 900 m off
    measured = [(0.0, 0.0, 5.0), (0.0, 0.0, 2.0), (math.pi / 2, 0.0, 3.0), (0.0, 0.0, 900.0)]
    points = frame.seen_points(np.array([0, 1, 1, 0]), np.array(measured), poses, share=0.75)
    np.testing.assert_allclose(points, [[5.0, 0.0, 0.0], [10.0, 2.0, 0.0], [7.0, 0.0, 0.0]],
                               atol=1e-12)  # fmt: skip
    assert frame.seen_points(np.zeros(0, int), np.zeros((0, 3)), poses).shape == (0, 3)


def test_the_map_is_framed_on_the_truth_not_on_drifting_odometry(tmp_path):
    from pipeline.log import read_log
    from tests.synthetic import Scene, square_loop, write_scene

    landmarks = np.array([[5.0, 3.0, 0.0], [9.0, -3.0, 0.0]])
    scene = Scene(square_loop(10.0, 1.0), landmarks, np.array([0, 1]))
    log = read_log(write_scene(tmp_path / "drift.mcap", scene, seed=3, odom_noise=30.0))
    framed = frame.replay_frame(log, 1.5)
    truth_box = np.ptp(np.vstack([framed.truth, landmarks]), axis=0)
    np.testing.assert_allclose(np.ptp(framed.map_extent, axis=0), truth_box)
    low, high = np.min(framed.map_extent, axis=0), np.max(framed.map_extent, axis=0)
    outside = np.any(
        (framed.odometry[:, :2] < low[:2] - 1.0) | (framed.odometry[:, :2] > high[:2] + 1.0), axis=1
    )
    assert outside.any()  # the odometry drifts out of the frame
    # without ground truth, the odometry is all there is to frame
    log = read_log(write_scene(tmp_path / "bare.mcap", scene, seed=3, odom_noise=30.0,
                               ground_truth=False))  # fmt: skip
    framed = frame.replay_frame(log, 1.5)
    assert np.all(np.ptp(framed.map_extent, axis=0) >= np.ptp(framed.odometry, axis=0) - 1e-9)


def test_the_legend_names_what_a_run_drew():
    hypotheses = [
        [draw.Hypothesis(0, 4, 0.9, True, False), draw.Hypothesis(0, 5, 0.1, False, False)],
        [draw.Hypothesis(1, NULL, 0.6, True, False)],
        [draw.Hypothesis(2, 7, 1.0, True, True)],
    ]
    drawn = legend.drawn_marks(hypotheses)
    assert drawn == {legend.CHOSEN, legend.OTHER, legend.NULL, legend.NEW}
    wrong = [[draw.Hypothesis(0, 4, 0.9, True, False, wrong=True)]]
    assert legend.drawn_marks(wrong) == {legend.WRONG}
    items = legend.replay_legend(["car", "truck"], ground_truth=True, truth_labels=True)
    shown = [i.label for i in legend.drawn_items(items, drawn | {"truck"})]
    assert shown == [
        "truck", "estimate", "ground truth", "odometry alone", "robot", "chosen",
        "new landmark", "other candidate", "null hypothesis",
    ]  # fmt: skip


def test_the_robot_is_marked_to_be_seen_at_the_default_eye():
    from pipeline.viz import marks

    (_, dot), (_, arrow) = marks.robot_marks(200.0)
    assert arrow.vectors.as_arrow_array().to_pylist() == [[10.0, 0.0, 0.0]]  # 5 % of the view
    positions = dot.positions.as_arrow_array().to_pylist()
    assert positions[0][2] == pytest.approx(4.0) and positions[1][2] < positions[0][2]


def test_labels_that_would_cover_others_are_left_out():
    box = (4.0, 1.0)  # a label 4 m wide, 1 m high
    anchors = np.array([[0.0, 0.0], [3.0, 0.5], [0.0, 1.5], [10.0, 0.0], [3.9, -0.9]])
    # 1 covers 0 (3 < 4 across, 0.5 < 1 down); 2 is a row below; 3 far; 4 covers 0
    assert labels.spaced(anchors, [0, 1, 2, 3, 4], box).tolist() == [
        True, False, True, True, False
    ]  # fmt: skip
    # the order decides who stays: 1 first pushes 0 out; 4 is 1.4 m below 1, clear of it
    assert labels.spaced(anchors, [1, 0, 4], box).tolist() == [False, True, False, False, True]
    assert labels.spaced(anchors, [3], box).tolist() == [False, False, False, True, False]
    # 600 px showing 300 m: half a metre a pixel
    assert labels.label_box(300.0) == (labels.LABEL_PX[0] / 2, labels.LABEL_PX[1] / 2)


def test_a_keyframes_labels_winners_first():
    # detection 0 chose L1 over L2; detection 1 chose L3; the pose at the origin
    H = draw.Hypothesis
    hypotheses = [H(0, 1, 0.7, True, False), H(0, 2, 0.3, False, False), H(1, 3, 0.9, True, False)]
    centres = [np.array([10.0, 0.0, 0.0]), np.array([10.0, 0.5, 0.0]), np.array([0.0, 10.0, 0.0])]
    strips = [np.array([np.zeros(3), centres[j]]) for j in (0, 1, 2)]
    # labels 4 m by 1 m: L2 is under L1's label, the lines' middles (5, 0), (5, 0.25), (0, 5)
    # are clear of the landmarks; L1's line and L2's line cover each other, L2's is a loser's
    landmarks, lines = labels.keyframe_labels(hypotheses, strips, [1, 2, 3], centres, (4.0, 1.0))
    assert landmarks.tolist() == [True, False, True]
    assert lines.tolist() == [True, False, True]
    # a larger box: L3's line (0, 5) and L3 (0, 10) are 5 m apart, under a 6 m label: the
    # landmark is kept, the line left out
    landmarks, lines = labels.keyframe_labels(hypotheses, strips, [1, 2, 3], centres, (7.0, 6.0))
    assert landmarks.tolist() == [True, False, True] and lines.tolist() == [False, False, False]


def test_a_wrong_winner_is_red_and_the_null_hypothesis_is_not():
    right = draw.Hypothesis(0, 4, 0.9, winner=True, new_landmark=False)
    wrong = draw.Hypothesis(0, 4, 0.9, winner=True, new_landmark=False, wrong=True)
    null = draw.Hypothesis(0, NULL, 0.9, winner=True, new_landmark=False)
    assert draw.hypothesis_style(right)[0] == draw.WINNER_RGB
    assert draw.hypothesis_style(wrong) == (draw.WRONG_RGB, draw.hypothesis_style(right)[1])
    assert draw.hypothesis_style(null)[0] == draw.NULL_WINNER_RGB != draw.WRONG_RGB


def test_plot_titles_name_their_lines():
    titles = [p.name for p in plots.replay_plots(True, True, 25)]
    assert titles[0] == "Translation error (m): newest pose amber, final estimate blue"
    assert titles[1] == "Wrong associations (detections)"
    assert "Time per keyframe (ms): back-end grey, recording purple" in titles
    without = [p.name for p in plots.replay_plots(False, False, 25)]
    assert not any("error" in t or "Wrong" in t for t in without)
    for plot in plots.replay_plots(True, True, 25):  # a colour word for one colour
        assert len({s.rgb for s in plot.series}) == len({s.colour for s in plot.series})


def test_labels():
    detection = Detection(1, 0.9, 0.1, 0.0, 10.04, tuple(np.eye(3).ravel()), "bbox")
    assert draw.detection_label(detection, "sign") == "sign 0.90 10.0 m"
    assert draw.detection_label(detection, "sign", 3) == "sign 0.90 10.0 m → L3"
    assert draw.detection_label(detection, "tag 12", NULL) == "tag 12 0.90 10.0 m → null"
    assert draw.landmark_label(57, "car", 0.904) == "L57 car 0.90"


def test_events_say_what_happened_at_which_level():
    assert events.null_win(289, 0, [(7, 0.9)], 0.1) == events.Event(
        "INFO", "pose 289: detection 0 → null hypothesis (candidates L7 0.90; null 0.10)"
    )
    assert events.null_win(3, 1, [], 0.1).text.endswith("(candidates none; null 0.10)")
    assert events.changed(289, 77, 0, 28, NULL) == events.Event(
        "INFO", "pose 289: detection 0 of pose 77, L28 → null"
    )
    assert events.changed(289, 289, 1, None, 5) == events.Event(
        "INFO", "pose 289: detection 1 → L5 after the update"
    )
    assert events.many_changed(289, 4, 5) is None
    assert events.many_changed(289, 5, 5) == events.Event(
        "WARN", "pose 289: 5 earlier associations changed: a large correction"
    )
    said = [events.unsettled(515, 488, 0, n, 3) for n in (1, 2, 3, 4)]
    assert said[:2] == [None, None] and said[3] is None  # once, when it reaches the threshold
    assert said[2] == events.Event(
        "WARN", "pose 515: detection 0 of pose 488 has changed 3 times: ambiguous"
    )
    assert events.started("mm-nh", 10, 4).text.startswith("pose 0: mm-nh over 10 poses")


ERRORS = {
    "translation_error_m": {"max": 18.5775, "mean": 5.8395, "median": 4.8316, "rmse": 6.6027},
    "rotation_error_rad": {"max": 0.55706, "mean": 0.12761, "median": 0.02568, "rmse": 0.21609},
}
COUNTS_ONLY = {"nulls": 13, "solver_fallbacks": {"batch": 0, "qr": 0}, "runtime_s": 2.84}
METRICS = {**COUNTS_ONLY, **ERRORS, "association": {"correct": 686, "wrong": 8, "null": 13}}


def test_summary_while_running_and_at_the_end():
    running = RunState("mm-nh", 289, 1501, 150, 95, 4, 3, error_m=4.213)
    text = summary_markdown(running)
    assert text.splitlines()[0] == "**mm-nh**: pose 289 of 1500"
    assert "| 150 | 95 | 4 | 3 |" in text
    assert text.endswith("Newest pose: 4.21 m from ground truth.")
    final = RunState("mm-nh", 1500, 1501, 707, 436, 26, 13)
    text = summary_markdown(final, METRICS)
    assert text.splitlines()[0] == "**mm-nh**: 1501 poses, done"
    assert "| translation (m) | 18.578 | 5.840 | 4.832 | 6.603 |" in text
    assert "| rotation (rad) | 0.5571 | 0.1276 | 0.0257 | 0.2161 |" in text
    assert text.endswith("Associations: 686 correct, 8 wrong, 13 null.")
    assert "error" not in summary_markdown(final)  # no ground truth: counts only
    # metrics.json is always written: counts only, or errors without truth labels
    assert "error" not in summary_markdown(final, COUNTS_ONLY)
    poses_only = summary_markdown(final, {**COUNTS_ONLY, **ERRORS})
    assert "| translation (m) | 18.578" in poses_only and "Associations" not in poses_only


def test_the_table_of_a_comparison():
    Run = namedtuple("Run", "method num_landmarks runtime_s metrics")
    rows = [Run("ml", 553, 2.84, METRICS), Run("mm-nh", 265, 49.46, None)]
    assert comparison_markdown(rows).splitlines() == [
        "| method | RMSE (m) | max (m) | wrong | null | correct | landmarks | time (s) |",
        "|---|---|---|---|---|---|---|---|",
        "| **ml** | 6.603 | 18.578 | 8 | 13 | 686 | 553 | 2.8 |",
        "| **mm-nh** | – | – | – | – | – | 265 | 49.5 |",
    ]
    # without ground truth: what every run has
    for metrics in (None, COUNTS_ONLY):
        assert comparison_markdown([Run("ml", 9, 1.0, metrics)]).splitlines() == [
            "| method | landmarks | time (s) |",
            "|---|---|---|",
            "| **ml** | 9 | 1.0 |",
        ]
    # ground-truth poses, no truth labels: errors without association counts
    assert comparison_markdown([Run("ml", 9, 1.0, {**COUNTS_ONLY, **ERRORS})]).splitlines() == [
        "| method | RMSE (m) | max (m) | landmarks | time (s) |",
        "|---|---|---|---|---|",
        "| **ml** | 6.603 | 18.578 | 9 | 1.0 |",
    ]
