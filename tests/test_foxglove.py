"""Foxglove's well-known messages: every one written is checked against Foxglove's official
schema (the generated classes of `foxglove-schemas-protobuf`): the schema in the file is the
official one, the message parses under it with no unknown fields, and it says what the log or
the estimate says."""

from __future__ import annotations

import importlib
import math
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
from google.protobuf import descriptor_pb2
from google.protobuf.unknown_fields import UnknownFieldSet
from mcap.reader import make_reader

from data_tools.scenarios import simulate
from pipeline import settings
from pipeline.cli import main
from pipeline.config import load_config
from pipeline.foxglove import log_topics
from pipeline.foxglove import messages as fm
from pipeline.foxglove import replay_file as rf
from pipeline.inspect import inspect_log
from pipeline.log import Detection, read_log
from pipeline.replay import replay
from pipeline.viz import TeeSink, sink_from_options
from tests.synthetic import kidnap_scene, write_scene
from tests.test_log_integrity import data_section_crc

CONTRACT_TOPICS = {
    "/odometry",
    "/detections",
    "/ground_truth/pose",
    "/ground_truth/landmarks",
    "/calibration",
}


def official_class(schema_name: str):
    short = schema_name.removeprefix("foxglove.")
    module = importlib.import_module(f"foxglove_schemas_protobuf.{short}_pb2")
    return getattr(module, short)


def without_json_names(message: descriptor_pb2.DescriptorProto) -> descriptor_pb2.DescriptorProto:
    """protoc fills json_name, CopyToProto leaves it out: compare the rest."""
    for field in message.field:
        field.ClearField("json_name")
    return message


def assert_official_schema(schema_data: bytes, name: str) -> None:
    """Every Foxglove message type in the schema (`name` and those it holds) is the official."""
    files = descriptor_pb2.FileDescriptorSet.FromString(schema_data).file
    embedded = {m.name: m for f in files if f.package == "foxglove" for m in f.message_type}
    assert name.removeprefix("foxglove.") in embedded
    for short, message in embedded.items():
        official = descriptor_pb2.DescriptorProto()
        official_class(short).DESCRIPTOR.CopyToProto(official)
        assert without_json_names(message) == without_json_names(official), short


def read_foxglove(path: Path) -> dict[str, list[tuple[int, object]]]:
    """Every protobuf message of the file, decoded with the official class after checking the
    file's schema against it: topic -> [(log_time, message)]."""
    by_topic: dict[str, list[tuple[int, object]]] = defaultdict(list)
    checked: set[int] = set()
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            if channel.message_encoding != "protobuf":
                continue
            assert schema.encoding == "protobuf" and schema.name.startswith("foxglove.")
            cls = official_class(schema.name)
            if schema.id not in checked:
                assert_official_schema(schema.data, schema.name)
                checked.add(schema.id)
            decoded = cls.FromString(message.data)
            assert len(UnknownFieldSet(decoded)) == 0
            by_topic[channel.topic].append((message.log_time, decoded))
    return by_topic


def stamp_ns(timestamp) -> int:
    return timestamp.seconds * 1_000_000_000 + timestamp.nanos


def xyz(v) -> np.ndarray:
    return np.array([v.x, v.y, v.z])


def quat(q) -> np.ndarray:
    return np.array([q.x, q.y, q.z, q.w])


# --- pure conversions, against values worked by hand -----------------------------------------


def test_timestamp_splits_nanoseconds():
    t = fm.timestamp(1_500_000_000_123)
    assert (t.sec, t.nsec) == (1500, 123)


def test_frame_transform_of_a_quarter_turn():
    T = np.eye(4)
    T[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]  # 90 degrees about z
    T[:3, 3] = [1, 2, 3]
    decoded = official_class("foxglove.FrameTransform").FromString(
        fm.frame_transform(7, "world", "body", T).encode()
    )
    assert (decoded.parent_frame_id, decoded.child_frame_id) == ("world", "body")
    np.testing.assert_allclose(xyz(decoded.translation), [1, 2, 3])
    h = math.sqrt(0.5)
    np.testing.assert_allclose(quat(decoded.rotation), [0, 0, h, h], atol=1e-12)


def test_image_annotations_outline_each_box():
    boxed = Detection(1, 0.75, 0.0, 0.0, 5.0, (1,) * 9, "bbox", bbox=(10.0, 20.0, 50.0, 80.0))
    unboxed = Detection(0, 0.9, 0.0, 0.0, 5.0, (1,) * 9, "apriltag")
    message = fm.image_annotations(3, [boxed, unboxed], ("tag", "car"))
    decoded = official_class("foxglove.ImageAnnotations").FromString(message.encode())
    assert len(decoded.points) == 1 and len(decoded.texts) == 1
    corners = [(p.x, p.y) for p in decoded.points[0].points]
    assert corners == [(10, 20), (50, 20), (50, 80), (10, 80)]
    assert decoded.texts[0].text == "bbox car 0.75"


# --- a simulated log: what the front-end and `simulate` write -----------------------------


@pytest.fixture(scope="module")
def kitti_log(tmp_path_factory) -> Path:
    """kitti05-cars: calibration, boxes and ground truth, so every log topic is there."""
    path = tmp_path_factory.mktemp("fox") / "kitti.mcap"
    simulate("kitti05-cars", path, seed=3, odom_noise_scale=1.0)
    return path


@pytest.mark.slow
def test_a_simulated_log_carries_foxglove_topics_that_match_it(kitti_log):
    log = read_log(kitti_log)  # the contract's reader still reads it, topics and all
    fox = read_foxglove(kitti_log)
    stamps = log.pose_stamps_ns()
    n = log.num_poses
    assert set(fox) == {
        log_topics.TF,
        log_topics.ODOMETRY,
        log_topics.ODOMETRY_PATH,
        log_topics.TRUTH_POSE,
        log_topics.TRUTH_PATH,
        log_topics.TRUTH_LANDMARKS,
        log_topics.DETECTIONS,
        log_topics.ANNOTATIONS,
        log_topics.CALIBRATION,
    }
    # Ground truth: the same poses, at the same times.
    truth = fox[log_topics.TRUTH_POSE]
    assert [t for t, _ in truth] == [stamps[m.pose_index] for m in log.ground_truth_poses]
    for (_, message), gt in zip(truth, log.ground_truth_poses, strict=True):
        assert message.frame_id == "world" and stamp_ns(message.timestamp) == gt.stamp_ns
        np.testing.assert_allclose(xyz(message.pose.position), gt.translation)
        np.testing.assert_allclose(quat(message.pose.orientation), gt.rotation)
    ((_, path),) = fox[log_topics.TRUTH_PATH]
    assert len(path.poses) == n
    # Odometry dead-reckoned: the last pose is the product of every step.
    world_from_body = np.eye(4)
    for odometry in log.odometry:
        world_from_body = world_from_body @ log_topics.matrix(
            odometry.translation, odometry.rotation
        )
    odometry_poses = fox[log_topics.ODOMETRY]
    assert [t for t, _ in odometry_poses] == stamps
    np.testing.assert_allclose(xyz(odometry_poses[-1][1].pose.position), world_from_body[:3, 3])
    tf = [m for _, m in fox[log_topics.TF]]
    body = [m for m in tf if m.child_frame_id == "body"]
    camera = [m for m in tf if m.child_frame_id == "camera_left"]
    assert len(body) == n and len(camera) == 1
    np.testing.assert_allclose(xyz(body[-1].translation), world_from_body[:3, 3])
    body_from_camera = np.reshape(log.calibration.body_from_camera, (4, 4))
    np.testing.assert_allclose(xyz(camera[0].translation), body_from_camera[:3, 3])
    # Landmarks: a sphere each, where the truth puts it.
    ((_, update),) = fox[log_topics.TRUTH_LANDMARKS]
    truth_landmarks = {f"truth {lm.id}": lm.position for lm in log.ground_truth_landmarks.landmarks}
    assert {e.id for e in update.entities} == set(truth_landmarks)
    for entity in update.entities:
        np.testing.assert_allclose(xyz(entity.spheres[0].pose.position), truth_landmarks[entity.id])
    # The camera: calibration as logged, a box for every detection that has one.
    ((_, calibration),) = fox[log_topics.CALIBRATION]
    c = log.calibration
    assert (calibration.width, calibration.height) == (c.width, c.height)
    assert list(calibration.K) == [c.fx, 0, c.cx, 0, c.fy, c.cy, 0, 0, 1]
    boxes = sum(d.bbox is not None for m in log.detections for d in m.detections)
    assert sum(len(m.points) for _, m in fox[log_topics.ANNOTATIONS]) == boxes
    assert sum(len(m.entities[0].spheres) for _, m in fox[log_topics.DETECTIONS]) == (
        log.num_detections
    )


def test_foxglove_topics_leave_the_contract_topics_as_they_were(tmp_path):
    scene, _, _ = kidnap_scene(alias_seen_before=False)
    plain = write_scene(tmp_path / "plain.mcap", scene)
    from pipeline.log import writer as log_writer

    with_fox = read_foxglove(plain)
    assert with_fox, "LogWriter writes Foxglove topics by default"

    def contract_messages(path):
        with open(path, "rb") as f:
            return [
                (c.topic, m.log_time, m.data)
                for _, c, m in make_reader(f).iter_messages()
                if c.topic in CONTRACT_TOPICS
            ]

    original = log_writer.LogWriter.__init__

    def without_foxglove(self, path, metadata, mirror=None):
        original(self, path, metadata)

    log_writer.LogWriter.__init__ = without_foxglove
    try:
        bare = write_scene(tmp_path / "bare.mcap", scene)
    finally:
        log_writer.LogWriter.__init__ = original
    assert read_foxglove(bare) == {}
    assert contract_messages(plain) == contract_messages(bare)


# --- the estimate: `replay --mcap FILE` -------------------------------------------------------


@pytest.mark.e2e
def test_replay_writes_the_estimate_with_null_wins_and_switches(tmp_path, capsys):
    scene, _, _ = kidnap_scene(alias_seen_before=False)
    log_path = write_scene(tmp_path / "alias.mcap", scene, odom_noise=0.0, meas_noise=0.0)
    estimate = tmp_path / "estimate.mcap"
    sink = sink_from_options(None, False, None, mcap=estimate)
    paper = load_config(settings.config_path("paper.toml"))  # a null win, then a switch
    result = replay(log_path, "mm-nh", tmp_path / "run", paper, sink=sink, progress=False)
    fox = read_foxglove(estimate)
    stated, computed = data_section_crc(estimate.read_bytes())
    assert stated == computed != 0  # every byte of it protected, as the logs' are
    log = read_log(log_path)
    stamps = log.pose_stamps_ns()

    trajectory = np.loadtxt(tmp_path / "run" / "trajectory.tum")
    poses = fox[rf.POSE]
    assert [t for t, _ in poses] == stamps
    for row, (_, message) in zip(trajectory, poses, strict=True):
        np.testing.assert_allclose(xyz(message.pose.position), row[1:4], atol=1e-6)
    landmarks = np.loadtxt(tmp_path / "run" / "landmarks.csv", delimiter=",", skiprows=1, ndmin=2)
    drawn = {e.id: e for _, m in fox[rf.LANDMARKS] for e in m.entities}
    assert set(drawn) == {f"landmark {int(i)}" for i in landmarks[:, 0]}
    for row in landmarks:
        entity = drawn[f"landmark {int(row[0])}"]
        np.testing.assert_allclose(xyz(entity.spheres[0].pose.position), row[1:4], atol=1e-5)
        assert entity.texts[0].text.startswith(f"L{int(row[0])} class{int(row[4])} ")

    associations = np.loadtxt(
        tmp_path / "run" / "associations.csv", delimiter=",", skiprows=1, ndmin=2
    )
    lines = [m.entities[0].lines for _, m in fox[rf.ASSOCIATIONS]]
    segments = sum(len(line[0].points) // 2 for line in lines if line)
    assert segments == len(associations)
    red = fm.NULL_COLOUR
    null_segments = sum(
        1
        for line in lines
        if line
        for colour in line[0].colors[::2]
        if np.allclose([colour.r, colour.g, colour.b], red, atol=1e-6)
    )
    assert null_segments == int((associations[:, 2] == -1).sum()) == 1
    events = [m.message for _, m in fox[rf.EVENTS]]
    assert any("switched from landmark" in e and "to the null hypothesis" in e for e in events)
    assert events[-1].startswith("mm-nh: translation error rmse")
    assert result.metrics["association"]["null"] == 1
    switches = sum(" switched " in e or " moved off " in e for e in events)
    assert switches == result.metrics["switches"]

    # `mmslam inspect` says what the file is and sums it up
    report = inspect_log(estimate)
    assert (report["kind"], report["valid"]) == ("estimate", True)
    assert report["estimate"] == {
        "method": "mm-nh",
        "poses": result.metrics["num_poses"],
        "keyframes": len(fox[rf.ASSOCIATIONS]),
        "landmarks": result.metrics["num_landmarks"],
        "switches": result.metrics["switches"],
        "null_wins": sum(e.endswith("left to the null hypothesis") for e in events),
        "result": events[-1],
    }
    assert main(["inspect", str(estimate)]) == 0
    assert "an estimate: `mmslam replay --mcap` with method mm-nh" in capsys.readouterr().out


@pytest.mark.e2e
def test_a_switch_in_the_detections_own_keyframe_is_an_event(tmp_path):
    # The alias is first put on the lookalike at the drifted prediction; the keyframe's own
    # update moves the pose and it switches to the alias, before any later keyframe.
    scene, _, _ = kidnap_scene(alias_seen_before=True, shift=3.0)
    log_path = write_scene(tmp_path / "switch.mcap", scene, odom_noise=0.0, meas_noise=0.0)
    estimate = tmp_path / "estimate.mcap"
    sink = sink_from_options(None, False, None, mcap=estimate)
    result = replay(log_path, "mm", tmp_path / "run", load_config(), sink=sink, progress=False)
    events = [m.message for _, m in read_foxglove(estimate)[rf.EVENTS]]
    own = [e for e in events if "moved off its first choice" in e]
    assert result.metrics["switches"] >= 1
    assert len(own) == result.metrics["switches"], events


@pytest.mark.e2e
def test_two_sinks_get_the_same_run(tmp_path):
    """--mcap beside a Rerun option: the sinks are teed, each sees the whole run."""
    scene, _, _ = kidnap_scene(alias_seen_before=True)
    log_path = write_scene(tmp_path / "log.mcap", scene, seed=2)
    first, second = tmp_path / "first.mcap", tmp_path / "second.mcap"
    sink = TeeSink([rf.FoxgloveSink(first), rf.FoxgloveSink(second)])
    replay(log_path, "mm", tmp_path / "run", load_config(), sink=sink, progress=False)
    one, two = read_foxglove(first), read_foxglove(second)
    assert one.keys() == two.keys() and len(one[rf.POSE]) == read_log(log_path).num_poses
    assert all(a == b for topic in one for a, b in zip(one[topic], two[topic], strict=True))


def test_the_last_event_says_what_the_log_could_measure():
    errors = {"translation_error_m": {"rmse": 0.5, "max": 1.25}}
    counts = {"association": {"correct": 7, "wrong": 1, "null": 2}}
    assert rf.metrics_summary("ml", {"nulls": 2}) is None  # no ground truth at all
    assert rf.metrics_summary("ml", errors) == "ml: translation error rmse 0.500 m, max 1.250 m"
    assert rf.metrics_summary("ml", counts) == "ml: associations 7 correct, 1 wrong, 2 null"
    both = rf.metrics_summary("ml", {**errors, **counts})
    assert both == "ml: translation error rmse 0.500 m, max 1.250 m; " + (
        "associations 7 correct, 1 wrong, 2 null"
    )
