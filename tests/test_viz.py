"""The Rerun recording, read back with Rerun's own reader and checked against the run that made
it: poses, landmarks, hypothesis lines per detection, null-hypothesis wins and switches, images,
the blueprint; bad options; and that a replay without Rerun options never imports Rerun."""

from __future__ import annotations

import dataclasses
import itertools
import math
import os
import signal
import socket
import subprocess
import sys
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np
import pytest

from pipeline import settings
from pipeline.backend.hypotheses import NULL, AssociationRecord
from pipeline.backend.measurements import make_measurement
from pipeline.backend.slam import BackendResult
from pipeline.config import load_config
from pipeline.errors import InputError
from pipeline.geometry import quaternion_from_rotation, rotation_from_quaternion
from pipeline.log import (
    CompressedImage,
    Detection,
    DetectionLog,
    Detections,
    LogMetadata,
    LogWriter,
    Odometry,
    read_log,
)
from pipeline.log.schemas import LEFT_IMAGE
from pipeline.replay import ReplayResult, replay
from pipeline.viz import draw, marks, plots, stream
from pipeline.viz import entities as e
from pipeline.viz.config import load_viz_config
from pipeline.viz.rerun_sink import RerunSink
from pipeline.viz.stream import rerun_executable, viewer_url
from tests.recordings import (
    blueprint_views,
    data_rows,
    latest,
    read_rows,
    unfed_views,
    unseen_entities,
)
from tests.synthetic import KIDNAP_POSE, Scene, kidnap_scene, square_loop, write_scene
from tests.waiting import wait_until

rerun_chunk = pytest.importorskip("rerun.chunk")
REPO = Path(__file__).resolve().parents[1]


class Snapshot(RerunSink):
    """A Rerun sink that also notes, per keyframe, what each detection should show: how many
    hypotheses (every candidate, or the landmark it made, plus the null hypothesis) and its
    landmark at that moment."""

    expected: dict[int, list[tuple[int, int, int]]]
    step_ms: list[float]  # the back-end's time a keyframe
    switched: dict[int, list[AssociationRecord]]

    def keyframe(self, report, seconds) -> None:
        self.expected = getattr(self, "expected", {})
        self.step_ms = getattr(self, "step_ms", [])
        self.switched = getattr(self, "switched", {})
        self.merged = getattr(self, "merged", {})
        if report.merged:  # (duplicate, survivor, whether the duplicate was drawn before)
            self.merged[report.pose_index] = [
                (d, report.map.landmarks.resolve(s), d < self._landmark_total)
                for d, s in report.merged
            ]
        self.step_ms.append(1e3 * seconds)
        self.switched[report.pose_index] = list(report.switched)
        self.expected[report.pose_index] = [
            (
                r.measurement.detection_index,
                len({*c.landmark_ids.tolist(), *r.landmark_ids}) + int(r.null_weight > 0),
                r.landmark_id,
                r.null_weight > 0,
            )
            for r, c in zip(report.records, report.candidates, strict=True)
        ]
        super().keyframe(report, seconds)

    def finish(self, result, metrics) -> None:
        self.final = result
        super().finish(result, metrics)


def viz_config(**changes):
    return dataclasses.replace(load_viz_config(), **changes)


def square_scene() -> Scene:
    poses = square_loop(20.0, 1.0, laps=1.25)
    sides = np.arange(0.0, 21.0, 5.0)
    landmarks = np.array(
        [[x, -4.0, 0.5] for x in sides]
        + [[24.0, y, 0.5] for y in sides]
        + [[x, 24.0, 0.5] for x in sides]
        + [[-4.0, y, 0.5] for y in sides]
    )
    return Scene(poses, landmarks, np.arange(len(landmarks)) % 2)


class SquareRun(NamedTuple):
    log: DetectionLog
    result: ReplayResult
    final: BackendResult
    expected: dict[int, list[tuple[int, int, int]]]
    rrd: Path
    sink: Snapshot


@pytest.fixture(scope="module")
def square_run(tmp_path_factory) -> SquareRun:
    tmp = tmp_path_factory.mktemp("viz")
    log_path = write_scene(tmp / "square.mcap", square_scene(), seed=3)
    sink = Snapshot.open("test", rrd=tmp / "run.rrd", config=viz_config(refresh_every=7))
    result = replay(log_path, "mm-nh", tmp / "out", load_config(), sink=sink, progress=False)
    return SquareRun(read_log(log_path), result, sink.final, sink.expected, tmp / "run.rrd", sink)


# ----------------------------------------------------------------------------- the replay
@pytest.mark.e2e
def test_the_noise_scales_in_use_are_plotted_every_keyframe(square_run):
    """A line per direction, a point per keyframe, log10 of the scale; the last the run's."""
    _, result, _, _, rrd, _ = square_run
    rows = read_rows(rrd)
    final = result.metrics["noise_scales"]
    for kind, key in (("odometry", "odometry"), ("detections", "measurement")):
        for name, scale in final[key].items():
            points = data_rows(rows[plots.noise_path(kind, name)], "Scalars:scalars")
            assert [r["pose"] for r in points] == list(range(result.num_poses))
            assert points[-1]["Scalars:scalars"][0] == pytest.approx(math.log10(scale), abs=1e-12)


@pytest.mark.e2e
def test_every_pose_is_logged_once_on_both_timelines(square_run):
    log, result, _, _, rrd, _ = square_run
    robot = data_rows(read_rows(rrd)[e.ROBOT], "Transform3D:translation")
    assert [r["pose"] for r in robot] == list(range(result.num_poses))
    stamps = log.pose_stamps_ns()
    assert [r["log_time"].value for r in robot] == list(stamps)


@pytest.mark.e2e
def test_the_trajectory_grows_every_keyframe_and_ends_as_the_final_estimate(square_run):
    _, result, final, _, rrd, _ = square_run
    rows = read_rows(rrd)
    full = data_rows(rows[e.TRAJECTORY], "LineStrips3D:strips")
    recent = data_rows(rows[e.TRAJECTORY_RECENT], "LineStrips3D:strips")
    # a refresh holds every pose up to its own; between refreshes the recent strip reaches on
    for r in full[:-1]:
        assert len(r["LineStrips3D:strips"][0]) == r["pose"] + 1
    reached = {r["pose"] for r in full} | {r["pose"] for r in recent}
    assert reached == set(range(1, result.num_poses))
    # refresh_every = 7: only the poses since the last refresh are sent each keyframe
    assert max(len(r["LineStrips3D:strips"][0]) for r in recent) == 7
    final_strip = np.array(full[-1]["LineStrips3D:strips"][0])
    truth = np.array([p.translation() for p in final.poses])
    np.testing.assert_allclose(final_strip, truth, atol=1e-4)  # float32 in the recording


@pytest.mark.e2e
def test_every_landmark_has_its_entity_ending_at_the_final_estimate(square_run):
    log, _, final, _, rrd, _ = square_run
    rows = read_rows(rrd)
    prefix = e.LANDMARKS + "/"
    ids = {int(p[len(prefix) :]) for p in rows if p.startswith(prefix)}
    # a landmark merged into another was shown until then, and cleared
    assert ids - set(final.landmarks.merged_into) == set(final.landmark_ids)
    names = log.metadata.class_names
    for j, value in zip(final.landmark_ids, final.landmark_values, strict=True):
        entity = rows[e.landmark_path(j)]
        np.testing.assert_allclose(latest(entity, "Points3D:positions")[0], value, atol=1e-4)
        landmark = final.landmarks.landmarks[j]
        assert latest(entity, "Points3D:labels")[0].startswith(f"L{j} {names[landmark.map_class]}")
        assert latest(entity, "Points3D:class_ids")[0] == landmark.map_class
        assert latest(entity, "Points3D:show_labels") == [False]  # labels on hover only
    # every landmark's ellipsoid, at the final estimate, on the uncertainty layer
    shapes = rows[e.UNCERTAINTY]
    labels = latest(shapes, "Ellipsoids3D:labels")
    assert labels == [f"L{j}" for j in final.landmark_ids]
    centres = np.array(latest(shapes, "Ellipsoids3D:centers"))
    np.testing.assert_allclose(centres, np.array(final.landmark_values), atol=1e-4)
    assert np.all(np.array(latest(shapes, "Ellipsoids3D:half_sizes")) > 0)
    assert len(data_rows(shapes, "Ellipsoids3D:centers")) < len(final.poses)  # not a keyframe


@pytest.mark.e2e
def test_each_detection_shows_every_hypothesis_and_one_winner(square_run):
    _, _, _, expected, rrd, _ = square_run
    rows = data_rows(read_rows(rrd)[e.HYPOTHESES], "LineStrips3D:strips")
    by_pose = {r["pose"]: r for r in rows}
    assert len(by_pose) == len(rows)  # one row a keyframe
    assert set(by_pose) == {i for i, dets in expected.items() if dets}
    lines = 0
    for i, detections in expected.items():
        if not detections:
            continue
        row = by_pose[i]
        assert len(row["LineStrips3D:strips"]) == len(row["detection"]) == len(row["winner"])
        assert len(row["Points3D:positions"]) == len(detections)  # the measured points
        for k, count, landmark, has_null in detections:
            mine = [n for n, d in enumerate(row["detection"]) if d == k]
            assert len(mine) == count
            winners = [row["landmark"][n] for n in mine if row["winner"][n]]
            assert winners == [landmark]
            # mm-nh: a detection associated among candidates also has the null hypothesis
            assert (NULL in [row["landmark"][n] for n in mine]) == has_null
            lines += count
    assert lines > sum(len(d) for d in expected.values())  # some detections had rivals


@pytest.mark.e2e
def test_only_the_landmarks_a_keyframe_weighs_are_labelled(square_run):
    rrd = square_run.rrd
    rows = read_rows(rrd)
    hypotheses = {r["pose"]: r for r in data_rows(rows[e.HYPOTHESES], "landmark")}
    candidates = {r["pose"]: r for r in data_rows(rows[e.CANDIDATES], "Points3D:labels")}
    assert set(candidates) == set(hypotheses)
    width, height = square_run.sink._label_box
    left_out = 0
    for pose, row in hypotheses.items():
        weighed = sorted({j for j in row["landmark"] if j != NULL})
        labels = candidates[pose]["Points3D:labels"]
        assert len(labels) == len(weighed)
        for label, j in zip(labels, weighed, strict=True):  # "L57 class 0.90", or left out
            assert label == "" or int(label.split()[0][1:]) == j
        assert candidates[pose]["Points3D:show_labels"] == [True]
        assert len(candidates[pose]["Ellipsoids3D:half_sizes"]) <= len(weighed)
        # the labels shown cover none of each other at the default eye
        positions = candidates[pose]["Points3D:positions"]
        shown = [p for p, label in zip(positions, labels, strict=True) if label]
        assert shown or not weighed
        for a, b in itertools.combinations(shown, 2):
            assert abs(a[0] - b[0]) >= width or abs(a[1] - b[1]) >= height
        left_out += len(labels) - len(shown)
        # only the winners' lines carry their weight
        lines = row["LineStrips3D:labels"]
        assert all(label == "" for label, won in zip(lines, row["winner"], strict=True) if not won)
    assert row["Points3D:show_labels"] == [False]  # measured points: no class name each
    assert left_out > 0  # the square's landmarks are close enough, seen whole, to crowd


@pytest.mark.e2e
def test_time_series_follow_the_run(square_run):
    log, result, final, _, rrd, _ = square_run
    rows = read_rows(rrd)
    errors = data_rows(rows[e.ERROR_FINAL], "Scalars:scalars")
    assert [r["pose"] for r in errors] == list(range(result.num_poses))
    truth = {m.pose_index: np.array(m.translation) for m in log.ground_truth_poses}
    for r in errors:  # ground-truth pose 0 is the origin: no alignment to undo
        estimate = final.poses[r["pose"]].translation()
        assert r["Scalars:scalars"][0] == pytest.approx(np.linalg.norm(estimate - truth[r["pose"]]))
    online = data_rows(rows[e.ERROR_ONLINE], "Scalars:scalars")
    assert len(online) == result.num_poses
    counts = data_rows(rows[e.LANDMARK_COUNT], "Scalars:scalars")
    assert counts[-1]["Scalars:scalars"] == [len(final.landmark_ids)]
    # the count falls only where landmarks were merged
    values = np.array([r["Scalars:scalars"][0] for r in counts])
    assert np.clip(-np.diff(values), 0, None).sum() <= final.merges
    for path in (e.NULL_RATE, e.STEP_MS, e.VIZ_MS, e.SWITCH_COUNT):
        assert [r["pose"] for r in data_rows(rows[path], "Scalars:scalars")] == list(
            range(result.num_poses)
        )


@pytest.mark.e2e
def test_keyframe_times_are_plotted_as_trailing_medians(square_run):
    rrd, step_ms = square_run.rrd, square_run.sink.step_ms
    plotted = [r["Scalars:scalars"][0] for r in data_rows(read_rows(rrd)[e.STEP_MS], "pose")]
    window = load_viz_config().smoothing_window
    expected = [np.median(step_ms[max(0, i + 1 - window) : i + 1]) for i in range(len(step_ms))]
    np.testing.assert_allclose(plotted, expected, rtol=1e-9)
    assert np.std(np.diff(plotted)) < np.std(np.diff(step_ms))  # smoother than the raw times


@pytest.mark.e2e
def test_the_summary_follows_the_run(square_run):
    _, result, final, _, rrd, _ = square_run
    rows = data_rows(read_rows(rrd)[e.SUMMARY], "TextDocument:text")
    last = result.num_poses - 1
    assert sorted({r["pose"] for r in rows}) == list(range(result.num_poses))
    texts = {r["pose"]: r["TextDocument:text"][0] for r in rows}  # the last row of each pose
    assert texts[0].startswith(f"**mm-nh**: pose 0 of {last}")
    assert "Newest pose: " in texts[7]
    assert texts[last].startswith(f"**mm-nh**: {result.num_poses} poses, done")
    assert f"| {len(final.records)} | {len(final.landmark_ids)} | {final.switches} |" in texts[last]
    t = result.metrics["translation_error_m"]
    assert f"| translation (m) | {t['max']:.3f} |" in texts[last]
    assert all(r["TextDocument:media_type"] == ["text/markdown"] for r in rows)


@pytest.mark.e2e
def test_the_null_rate_starts_at_pose_zero(tmp_path):
    log_path = write_image_log(tmp_path / "late.mcap", num_poses=5, first_detection=3)
    sink = RerunSink.open("test", rrd=tmp_path / "late.rrd", config=viz_config(image_every=0))
    replay(log_path, "mm-nh", tmp_path / "out", load_config(), sink=sink, progress=False)
    rates = data_rows(read_rows(tmp_path / "late.rrd")[e.NULL_RATE], "Scalars:scalars")
    assert [r["pose"] for r in rates] == list(range(5))
    # a rate of no nulls: 0 to round-off
    np.testing.assert_allclose([r["Scalars:scalars"][0] for r in rates], 0.0, rtol=0, atol=1e-12)


@pytest.mark.e2e
@pytest.mark.filterwarnings("error::rerun.error_utils.RerunWarning")
def test_the_recording_opens_with_its_layout(square_run):
    rrd = square_run.rrd
    assert len(rerun_chunk.RrdReader(rrd).store()) > 0  # complete: its footer was written
    views = blueprint_views(rrd)
    kinds = [kind for kind, _ in views]
    assert ("3D", e.WORLD) in views
    # error, wrong associations, landmarks, switches and merges, null rate, noise scales, time
    assert kinds.count("TimeSeries") == 7
    assert "TextLog" in kinds
    assert "2D" not in kinds  # the log has no images; the legend is in the map
    rows = read_rows(rrd)
    assert rows[e.WORLD][0]["ViewCoordinates:xyz"] is not None
    assert data_rows(rows[e.GROUND_TRUTH_TRAJECTORY], "LineStrips3D:strips")
    assert data_rows(rows[e.ODOMETRY_TRAJECTORY], "LineStrips3D:strips")


def kidnap_run(tmp_path: Path, **config):
    scene, _, _ = kidnap_scene(alias_seen_before=False)
    log_path = write_scene(tmp_path / "kidnap.mcap", scene, odom_noise=0.0, meas_noise=0.0)
    sink = Snapshot.open("test", rrd=tmp_path / "kidnap.rrd", config=viz_config(**config))
    paper = load_config(settings.config_path("paper.toml"))
    result = replay(log_path, "mm-nh", tmp_path / "out", paper, sink=sink, progress=False)
    return log_path, result, sink


def event_rows(rows) -> list[tuple[int, str, str]]:
    return [
        (r["pose"], r["TextLog:level"][0], r["TextLog:text"][0])
        for r in data_rows(rows[e.EVENTS], "TextLog:text")
    ]


@pytest.mark.e2e
def test_null_hypothesis_win_and_switch_are_marked(tmp_path):
    """The kidnap scene with the paper's settings: mm-nh first closes the loop on the
    lookalike, then switches the detection to the null hypothesis once the other landmarks
    have moved the pose."""
    log_path, result, sink = kidnap_run(tmp_path)
    final = sink.final
    assert final.switches >= 1 and result.metrics["association"]["null"] == 1
    rows = read_rows(tmp_path / "kidnap.rrd")
    alias = f"p{KIDNAP_POSE} d0"

    # a strip a switch of an earlier keyframe's detection (a keyframe's own show in its lines)
    switches = data_rows(rows[e.SWITCHES], "LineStrips3D:strips")
    own = sum(r.measurement.pose_index == i for i, rs in sink.switched.items() for r in rs)
    assert sum(len(r["LineStrips3D:strips"]) for r in switches) == final.switches - own
    assert any(label.startswith(f"{alias}: L") and label.endswith("→null")
               for r in switches for label in r["LineStrips3D:labels"])  # fmt: skip
    nulls = data_rows(rows[e.NULL_WINS], "Points3D:positions")
    assert [label for r in nulls for label in r["Points3D:labels"]] == [alias]
    # one event a switch of an earlier detection, when it happened, as the method at work
    events = event_rows(rows)
    changes = [(pose, level) for pose, level, text in events if " of pose " in text]
    assert changes == [(r["pose"], "INFO") for r in switches for _ in r["LineStrips3D:labels"]]
    (pose,) = [r["pose"] for r in nulls]
    assert [text for p, _, text in events if p == pose and f"of pose {KIDNAP_POSE}," in text]
    for _, _, text in events:  # never "from L25 to L25"
        if " of pose " in text:
            before, after = text.rsplit(", ", 1)[1].split(" → ")
            assert before != after
    assert all(r["Points3D:show_labels"] == [False] for r in nulls)  # the lines say it
    assert all(level == "INFO" for _, level, _ in events)
    rejected = latest(rows[e.REJECTED], "Points3D:labels")
    assert rejected == [alias]
    # and kept where it happened, never cleared: the map shows it from then on
    (history,) = data_rows(rows[e.NULL_DECISIONS], "Points3D:positions")
    assert history["pose"] == pose and history["Points3D:labels"] == [alias]
    assert latest(rows[e.NULL_DECISIONS], "Points3D:labels") == [alias]
    assert history["Points3D:colors"] == [int(draw.packed_rgba(draw.NULL_WINNER_RGB))]
    # the per-keyframe marks are cleared on the next keyframe
    assert latest(rows[e.NULL_WINS], "Points3D:positions") is None
    rate = data_rows(rows[e.NULL_RATE], "Scalars:scalars")[-1]["Scalars:scalars"][0]
    assert rate == pytest.approx(1 / read_log(log_path).num_detections)
    # at the kidnapped pose the alias weighed the lookalike against the null hypothesis
    (row,) = [r for r in data_rows(rows[e.HYPOTHESES], "detection") if r["pose"] == KIDNAP_POSE]
    mine = [n for n, d in enumerate(row["detection"]) if d == 0]
    assert NULL in [row["landmark"][n] for n in mine] and len(mine) >= 2


@pytest.mark.e2e
def test_wrong_associations_are_red_and_counted(tmp_path):
    """Maximum likelihood takes the kidnap's alias for the lookalike: that detection's line is
    red at its keyframe, a red line at the end, and the count the metrics give."""
    scene, lookalike, _ = kidnap_scene(alias_seen_before=False)
    log_path = write_scene(tmp_path / "kidnap.mcap", scene, odom_noise=0.0, meas_noise=0.0)
    sink = Snapshot.open("test", rrd=tmp_path / "ml.rrd")
    paper = load_config(settings.config_path("paper.toml"))
    result = replay(log_path, "ml", tmp_path / "out", paper, sink=sink, progress=False)
    assert result.metrics["association"]["wrong"] == 1
    rows = read_rows(tmp_path / "ml.rrd")
    red = int(draw.packed_rgba(draw.WRONG_RGB))
    # at the kidnap, the alias (detection 0) went to the lookalike: its winning line red
    lines = {
        r["pose"]: list(zip(r["landmark"], r["winner"], r["LineStrips3D:colors"], strict=True))
        for r in data_rows(rows[e.HYPOTHESES], "landmark")
    }
    reds = [(pose, j) for pose, ls in lines.items() for j, won, c in ls if c == red]
    assert reds == [(KIDNAP_POSE, lookalike)]
    assert all(won for ls in lines.values() for _, won, c in ls if c == red)
    # at the end, one red line from the kidnapped pose to the lookalike, and the count
    assert latest(rows[e.WRONG], "LineStrips3D:labels") == [f"p{KIDNAP_POSE} d0 → L{lookalike}"]
    (strip,) = latest(rows[e.WRONG], "LineStrips3D:strips")
    final = sink.final
    np.testing.assert_allclose(strip[0], final.poses[KIDNAP_POSE].translation(), atol=1e-6)
    np.testing.assert_allclose(strip[1], final.landmark_values[lookalike], atol=1e-6)
    assert latest(rows[e.WRONG], "LineStrips3D:colors") == [red]
    (ring,) = latest(rows[e.WRONG], "Points3D:positions")  # round the landmark, just below
    np.testing.assert_allclose(ring, np.subtract(strip[1], [0, 0, marks.RING_DEPTH_M]), atol=1e-6)
    assert latest(rows[e.WRONG], "Points3D:colors") == [red]
    counts = [
        (r["pose"], r["Scalars:scalars"][0])
        for r in data_rows(rows[e.WRONG_COUNT], "Scalars:scalars")
    ]
    assert [c for pose, c in counts if pose < KIDNAP_POSE] == [0.0] * KIDNAP_POSE
    assert counts[-1] == (len(final.poses) - 1, 1.0)


def test_merges_are_marked_where_they_happen(square_run):
    rows = read_rows(square_run.rrd)
    merged = square_run.sink.merged
    assert square_run.final.merges == sum(len(m) for m in merged.values()) > 0
    marks = {r["pose"]: r for r in data_rows(rows[e.MERGES], "LineStrips3D:strips")}
    drawn = {pose: [f"L{d} → L{s}" for d, s, shown in m if shown] for pose, m in merged.items()}
    assert {pose: r["LineStrips3D:labels"] for pose, r in marks.items()} == {
        pose: labels for pose, labels in drawn.items() if labels
    }
    for pose, row in marks.items():  # each line ends at its survivor as it stood then
        for strip, label in zip(
            row["LineStrips3D:strips"], row["LineStrips3D:labels"], strict=True
        ):
            survivor = int(label.rsplit("L", 1)[1])
            at = [
                r
                for r in data_rows(rows[e.landmark_path(survivor)], "Points3D:positions")
                if r["pose"] <= pose
            ][-1]
            np.testing.assert_allclose(strip[1], at["Points3D:positions"][0], atol=0.1)
    (colour,) = latest(rows[e.MERGES], "LineStrips3D:colors")
    assert colour >> 8 == int(draw.packed_rgba(draw.MERGE_RGB)) >> 8  # half transparent
    totals = data_rows(rows[e.MERGE_COUNT], "Scalars:scalars")
    assert totals[-1]["Scalars:scalars"] == [square_run.final.merges]


@pytest.mark.e2e
def test_what_needs_a_look_is_a_warning(tmp_path):
    """With thresholds of one, the kidnap's switch is both a large correction and an
    unsettled detection; the null-hypothesis win stays the method at work."""
    kidnap_run(tmp_path, warn_changes_at_once=1, warn_changes_per_detection=1)
    events = event_rows(read_rows(tmp_path / "kidnap.rrd"))
    warnings = [(pose, text) for pose, level, text in events if level == "WARN"]
    changes = [(pose, text) for pose, level, text in events if " of pose " in text]
    assert {pose for pose, _ in warnings} == {pose for pose, _ in changes}
    assert any("earlier associations changed: a large correction" in t for _, t in warnings)
    assert any(f"detection 0 of pose {KIDNAP_POSE} has changed 1 times" in t for _, t in warnings)
    assert all(level == "INFO" for _, level, text in events if "null hypothesis (" in text)


def write_image_log(path: Path, num_poses: int = 3, first_detection: int = 0) -> Path:
    """A hand-made log with a left image at every pose and, from `first_detection` on, a
    detection with a box."""
    metadata = LogMetadata(2, ((1.0, 0.0), (0.0, 1.0)), ("car", "sign"), "tests/test_viz.py")
    cov = tuple(np.diag([0.01, 0.01, 0.1]).ravel() ** 1)
    odom_cov = tuple(np.diag([1e-4] * 3 + [1e-3] * 3).ravel())
    with LogWriter(path, metadata) as writer:
        for i in range(num_poses):
            stamp = 1_000_000_000 + i * 100_000_000
            if i:
                writer.write(Odometry(stamp, i - 1, i, (1.0, 0.0, 0.0), (0, 0, 0, 1.0), odom_cov))
            detection = Detection(
                class_id=1,
                score=0.9,
                bearing=0.1,
                elevation=0.0,
                range=10.0 - i,
                covariance=cov,
                source="bbox",
                bbox=(10.0, 12.0, 30.0, 40.0),
                truth_landmark_id=0,
            )
            writer.write(Detections(stamp, i, (detection,) if i >= first_detection else ()))
            image = np.full((48, 64), 40 * i, dtype=np.uint8)
            ok, data = cv2.imencode(".png", image)
            assert ok
            writer.write(CompressedImage(stamp, "camera_left", "png", data.tobytes()), LEFT_IMAGE)
    return path


@pytest.mark.e2e
def test_images_are_shown_with_their_labelled_boxes(tmp_path):
    log_path = write_image_log(tmp_path / "images.mcap")
    sink = RerunSink.open("test", rrd=tmp_path / "images.rrd")
    replay(log_path, "known", tmp_path / "out", load_config(), sink=sink, progress=False)
    rows = read_rows(tmp_path / "images.rrd")
    images = data_rows(rows[e.CAMERA], "EncodedImage:blob")
    assert [r["pose"] for r in images] == [0, 1, 2]
    assert images[0]["EncodedImage:media_type"] == ["image/png"]
    decoded = cv2.imdecode(np.frombuffer(bytes(images[2]["EncodedImage:blob"][0]), np.uint8), 0)
    assert decoded.shape == (48, 64) and decoded[0, 0] == 80
    boxes = data_rows(rows[e.CAMERA_DETECTIONS], "Boxes2D:half_sizes")
    assert len(boxes) == 3
    assert boxes[0]["Boxes2D:labels"] == ["sign 0.90 10.0 m → L0"]  # class, score, range, landmark
    assert ("2D", e.CAMERA) in blueprint_views(tmp_path / "images.rrd")


@pytest.mark.e2e
def test_no_images_are_read_when_none_are_wanted(tmp_path):
    log_path = write_image_log(tmp_path / "images.mcap")
    sink = RerunSink.open("test", rrd=tmp_path / "none.rrd", config=viz_config(image_every=0))
    assert not sink.wants_images
    replay(log_path, "known", tmp_path / "out", load_config(), sink=sink, progress=False)
    rows = read_rows(tmp_path / "none.rrd")
    assert e.CAMERA not in rows
    assert ("2D", e.CAMERA) not in blueprint_views(tmp_path / "none.rrd")


@pytest.mark.slow
@pytest.mark.e2e
def test_frontend_keyframes_are_shown(tmp_path):
    from data_tools.render import render_sequence
    from pipeline.frontend.run import run_frontend

    sequence = render_sequence("demo", tmp_path / "seq", seed=0, num_frames=8)
    sink = RerunSink.open("test", rrd=tmp_path / "frontend.rrd")
    try:
        run_frontend(sequence, tmp_path / "seq.mcap", progress=False, sink=sink)
    finally:
        sink.close()
    log = read_log(tmp_path / "seq.mcap")
    rows = read_rows(tmp_path / "frontend.rrd")
    robot = data_rows(rows[e.ROBOT], "Transform3D:translation")
    assert [r["pose"] for r in robot] == list(range(log.num_poses))
    vo = latest(rows[e.VO_TRAJECTORY], "LineStrips3D:strips")[0]
    np.testing.assert_allclose(vo, draw.dead_reckoning(log.odometry), atol=1e-4)
    images = data_rows(rows[e.CAMERA], "EncodedImage:blob")
    assert [r["pose"] for r in images] == list(range(log.num_poses))
    assert sum(d.source == "apriltag" for m in log.detections for d in m.detections) > 0
    outlines = {r["pose"]: r for r in data_rows(rows[e.CAMERA_TAGS], "LineStrips2D:strips")}
    for message in log.detections:
        tags = [d for d in message.detections if d.source == "apriltag"]
        if tags:
            row = outlines[message.pose_index]
            assert len(row["LineStrips2D:strips"]) == len(tags)
            assert all(len(s) == 5 for s in row["LineStrips2D:strips"])  # closed
            # each outline with its detection's score and range ("tag 12 0.87 4.3 m")
            said = sorted(label.split(" ", 2)[2] for label in row["LineStrips2D:labels"])
            assert said == sorted(f"{d.score:.2f} {d.range:.1f} m" for d in tags)
    assert ("2D", e.CAMERA) in blueprint_views(tmp_path / "frontend.rrd")
    assert unfed_views(tmp_path / "frontend.rrd") == []
    assert unseen_entities(tmp_path / "frontend.rrd") == []


# ----------------------------------------------------------------------- cost, bad input
@pytest.mark.e2e
def test_a_plain_replay_never_imports_rerun(tmp_path):
    log_path = write_image_log(tmp_path / "plain.mcap")
    script = (
        "import sys\n"
        "from pipeline.config import load_config\n"
        "from pipeline.replay import replay\n"
        "from pipeline.viz import sink_from_options\n"
        "sink = sink_from_options(None, False, None)\n"
        f"replay({str(log_path)!r}, 'known', {str(tmp_path / 'out')!r}, load_config(), sink=sink,"
        " progress=False)\n"
        "assert (tmp := sorted(m for m in sys.modules if 'rerun' in m)) == [], tmp\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", script], cwd=REPO, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "out" / "trajectory.tum").exists()


@pytest.mark.parametrize(
    "options",
    [{}, {"spawn": True, "connect": "9876"}, {"rrd": "x.rrd", "connect": "9876"}],
)
def test_exactly_one_destination(options):
    with pytest.raises(InputError, match="choose one of"):
        RerunSink.open("test", **options)


def test_unwritable_recording_paths_are_bad_input(tmp_path):
    with pytest.raises(InputError, match="is a directory"):
        RerunSink.open("test", rrd=tmp_path)
    (tmp_path / "file").write_text("")
    with pytest.raises(InputError, match="cannot be written"):
        RerunSink.open("test", rrd=tmp_path / "file" / "run.rrd")


def test_rerun_turned_off_is_bad_input(tmp_path, monkeypatch):
    monkeypatch.setenv("RERUN", "off")
    with pytest.raises(InputError, match="RERUN"):
        RerunSink.open("test", rrd=tmp_path / "run.rrd")
    assert list(tmp_path.iterdir()) == []


def test_connect_needs_a_viewer(tmp_path, monkeypatch):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    timeouts = []
    connect = socket.create_connection

    def spy(address, timeout=None, *args, **kwargs):
        timeouts.append(timeout)
        return connect(address, timeout, *args, **kwargs)

    monkeypatch.setattr(socket, "create_connection", spy)
    with pytest.raises(InputError, match="no Rerun viewer listening"):
        RerunSink.open("test", connect=f"127.0.0.1:{port}")
    # one look, bounded: without a viewer the answer comes, whatever the machine's load
    assert timeouts == [stream.VIEWER_WAIT_S] and 0 < stream.VIEWER_WAIT_S <= 10


@pytest.mark.parametrize(
    ("address", "url"),
    [
        ("9877", "rerun+http://127.0.0.1:9877/proxy"),
        ("viewer.local:9000", "rerun+http://viewer.local:9000/proxy"),
        ("rerun+https://host/proxy", "rerun+https://host/proxy"),
    ],
)
def test_viewer_addresses(address, url):
    assert viewer_url(address) == url


@pytest.mark.parametrize("address", ["ftp://host:1/proxy", "host:port", "rerun+http:///proxy"])
def test_bad_viewer_addresses(address):
    with pytest.raises(InputError):
        viewer_url(address)


class Failing(RerunSink):
    def keyframe(self, report, seconds) -> None:
        if report.pose_index == 2:
            raise RuntimeError("boom")
        super().keyframe(report, seconds)


@pytest.mark.e2e
def test_a_failed_run_leaves_the_earlier_recording(tmp_path):
    log_path = write_image_log(tmp_path / "log.mcap")
    target = tmp_path / "run.rrd"
    target.write_bytes(b"earlier")
    sink = Failing.open("test", rrd=target)
    with pytest.raises(RuntimeError, match="boom"):
        replay(log_path, "known", tmp_path / "out", load_config(), sink=sink, progress=False)
    assert target.read_bytes() == b"earlier"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["log.mcap", "run.rrd"]


def test_the_command_line_leaves_nothing_behind_on_bad_input(tmp_path):
    target = tmp_path / "run.rrd"
    done = subprocess.run(
        [sys.executable, "-m", "pipeline.cli", "replay", str(tmp_path / "missing.mcap"),
         "--method", "mm", "--out", str(tmp_path / "out"), "--rrd", str(target)],
        cwd=REPO, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr
    assert len(done.stderr.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []


def accepting(port: int) -> bool:
    try:
        socket.create_connection(("127.0.0.1", port), 0.2).close()
    except OSError:
        return False
    return True


def received_robot_rows(path: Path, num_poses: int) -> list[dict] | None:
    """The robot's transforms in the recording a server is saving, once all `num_poses` are
    in (None before: the file may be missing yet, or end within a message)."""
    if not path.exists():
        return None
    try:
        rows = read_rows(path)
    except Exception:  # a recording still being written; Rerun's reader says so in several ways
        return None
    robot = data_rows(rows.get(e.ROBOT, []), "Transform3D:translation")
    return robot if len(robot) >= num_poses else None


@pytest.mark.e2e
@pytest.mark.filterwarnings("ignore:RRD file has no footer")
def test_streams_to_a_running_viewer(tmp_path):
    """`--connect`: a headless Rerun server saving what it receives stands in for a viewer."""
    executable = Path(sys.executable).parent / "rerun"
    if not executable.exists():
        pytest.skip("no rerun executable beside python")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    saved = tmp_path / "received.rrd"
    # its own process group: `rerun` here is a Python script that starts the real binary
    server = subprocess.Popen(
        [str(executable), "--serve-grpc", "--port", str(port), "--save", str(saved)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env={**os.environ, "RERUN_APP_ONLY": "true"},
        start_new_session=True,
    )
    try:
        wait_until(lambda: accepting(port), "the Rerun server to listen")
        log_path = write_image_log(tmp_path / "log.mcap")
        sink = RerunSink.open("test", connect=str(port))
        result = replay(log_path, "known", tmp_path / "out", load_config(), sink=sink,
                        progress=False)  # fmt: skip
        # the server saves what it receives as it comes: wait until every pose is in
        robot = wait_until(
            lambda: received_robot_rows(saved, result.num_poses), "the server to save every pose"
        )
    finally:
        os.killpg(server.pid, signal.SIGTERM)
        server.wait(timeout=30)
    assert [r["pose"] for r in robot] == list(range(result.num_poses))


# ------------------------------------------------------------------------- pure helpers
def test_class_colours_are_distinct_and_stable():
    colours = draw.class_colors(20)
    assert colours.shape == (20, 3) and colours.dtype == np.uint8
    assert len({tuple(c) for c in colours}) == 20
    np.testing.assert_array_equal(colours[:5], draw.class_colors(5))
    assert draw.packed_rgba((1, 2, 3)) == 0x010203FF


def test_ellipsoid_holds_the_chosen_probability():
    rng = np.random.default_rng(0)
    for _ in range(20):
        A = rng.normal(size=(3, 3))
        covariance = A @ A.T + 0.01 * np.eye(3)
        half_sizes, q = draw.ellipsoid(covariance, 0.95)
        R = rotation_from_quaternion(q)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-9)
        assert np.linalg.det(R) == pytest.approx(1.0)
        # R diag(h^2) R^T = k^2 covariance, k^2 = chi-square(3 dof) at 0.95 = 7.8147
        np.testing.assert_allclose(
            R @ np.diag(half_sizes**2) @ R.T, 7.814727903 * covariance, rtol=1e-6, atol=1e-9
        )


def test_ellipsoid_quaternions_match_scipy():
    from scipy.spatial.transform import Rotation

    matrices = [*Rotation.random(200, random_state=1).as_matrix(), np.diag([1.0, -1, -1])]
    for R in matrices:
        q = quaternion_from_rotation(R)
        np.testing.assert_allclose(Rotation.from_quat(q).as_matrix(), R, atol=1e-9)
        assert q[3] >= 0


def test_position_covariance_of_a_pose_landmark_is_rotated_into_the_world():
    R = rotation_from_quaternion(np.array([0.0, 0.0, np.sin(0.4), np.cos(0.4)]))
    covariance = np.diag([1.0, 1.0, 1.0, 4.0, 1.0, 0.25])
    world = draw.position_covariance(covariance, R)
    np.testing.assert_allclose(world, R @ np.diag([4.0, 1.0, 0.25]) @ R.T)
    np.testing.assert_array_equal(draw.position_covariance(np.eye(3)), np.eye(3))
    with pytest.raises(ValueError):
        draw.position_covariance(covariance)


def _record(landmark_ids, weights, **fields) -> AssociationRecord:
    detection = Detection(0, 0.9, 0.0, 0.0, 5.0, tuple(np.eye(3).ravel() * 0.01), "bbox")
    m = make_measurement(4, 2, detection, use_relative_pose=False)
    return AssociationRecord(m, list(landmark_ids), np.asarray(weights, float), **fields)


def _candidates(ids, weights):
    from pipeline.backend.candidates import Candidates

    n = len(ids)
    return Candidates(np.array(ids), np.array(weights), np.ones(n), np.zeros(n), n)


def test_hypotheses_of_each_method():
    from pipeline.backend.candidates import Candidates

    # ml: one landmark committed to, three weighed
    ml = draw.detection_hypotheses(
        _record([7], [0.6]), _candidates([3, 7, 9], [0.3, 0.6, 0.1]), created=False
    )
    assert [(h.landmark_id, h.weight, h.winner) for h in ml] == [
        (3, 0.3, False), (7, 0.6, True), (9, 0.1, False)]  # fmt: skip
    # mm-nh: components, then the null hypothesis, which won
    mm = draw.detection_hypotheses(
        _record([3, 7], [0.5, 0.4], null_weight=0.1, active=NULL),
        _candidates([3, 7], [0.55, 0.45]),
        created=False,
    )
    assert [(h.landmark_id, h.winner) for h in mm] == [(3, False), (7, False), (NULL, True)]
    assert mm[0].weight == 0.5 and mm[2].weight == 0.1
    # gpda: the current EM weights decide
    gpda = draw.detection_hypotheses(
        _record([3, 7], [1.0, 1.0], graph_weights=np.array([0.2, 0.8])),
        _candidates([3, 7], [0.6, 0.4]),
        created=False,
    )
    assert [(h.weight, h.winner) for h in gpda] == [(0.2, False), (0.8, True)]
    # a new landmark: no candidates
    (new,) = draw.detection_hypotheses(_record([12], [1.0]), Candidates.none(), created=True)
    assert new.new_landmark and new.winner and new.detection_index == 2
    assert draw.hypothesis_label(new) == "new"
    assert [draw.hypothesis_label(h) for h in mm] == ["0.50", "0.40", "null 0.10"]
    assert draw.hypothesis_style(new)[0] == draw.NEW_LANDMARK_RGB
    assert draw.hypothesis_style(mm[2])[0] == draw.NULL_WINNER_RGB
    assert draw.hypothesis_style(mm[0])[1] < draw.hypothesis_style(mm[2])[1]


def test_viz_config_defaults_and_overrides(tmp_path):
    config = load_viz_config()
    assert config.refresh_every >= 1 and config.image_every >= 0
    override = tmp_path / "viz.toml"
    override.write_text("[viz]\nrefresh_every = 3\nkeyframe_marginals = false\n")
    changed = load_viz_config(override)
    assert (changed.refresh_every, changed.keyframe_marginals) == (3, False)
    assert changed.ellipsoid_confidence == config.ellipsoid_confidence
    for text, message in [
        ("[viz]\nrefresh_evry = 3\n", "unknown key"),
        ("[viz]\nrefresh_every = 2.5\n", "must be int"),
        ("[viz]\nrefresh_every = 0\n", "refresh_every"),
        ("[viz]\nkeyframe_marginals = 1\n", "must be bool"),
        ("[viz]\nsmoothing_window = 0\n", "'viz.smoothing_window' must be in \\[1, 1e6\\]"),
        (
            "[viz]\nwarn_changes_at_once = -1\n",
            "'viz.warn_changes_at_once' must be in \\[1, 1e6\\]",
        ),
        ("[other]\n", "unknown key 'other'"),
    ]:
        override.write_text(text)
        with pytest.raises(InputError, match=message):
            load_viz_config(override)


@pytest.mark.skipif(rerun_executable() is None, reason="no rerun executable")
def test_rerun_verifies_a_run_recording(square_run):
    done = subprocess.run(
        [rerun_executable(), "rrd", "verify", str(square_run.rrd)],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
