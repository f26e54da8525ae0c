"""What a recording draws and says, as pure functions against hand-worked values: the default
eye, the trailing median, the legend's layout, labels, the event log's lines and levels, the
summary."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.backend.hypotheses import NULL
from pipeline.log import Detection
from pipeline.viz import draw, events
from pipeline.viz.blueprint import legend_per_row
from pipeline.viz.summary import RunState, summary_markdown


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


def test_legend_layout():
    assert [legend_per_row(n) for n in (1, 2, 4, 5, 8, 11, 13)] == [1, 2, 4, 3, 4, 6, 6]
    np.testing.assert_array_equal(
        draw.legend_positions(5, 3, 2.0), [[0, 0], [2, 0], [4, 0], [0, 1], [2, 1]]
    )
    items = draw.replay_legend(("car", "sign"), ground_truth=False)
    labels = [item.label for item in items]
    assert labels[:3] == ["car", "sign", "estimate"] and "ground truth" not in labels
    assert [item.rgb for item in items[:2]] == [tuple(c) for c in draw.class_colors(2)]
    assert len({item.rgb for item in items}) == len(items)  # every colour its own


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


METRICS = {
    "translation_error_m": {"max": 18.5775, "mean": 5.8395, "median": 4.8316, "rmse": 6.6027},
    "rotation_error_rad": {"max": 0.55706, "mean": 0.12761, "median": 0.02568, "rmse": 0.21609},
    "association": {"correct": 686, "wrong": 8, "null": 13},
}


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
