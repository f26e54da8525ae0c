"""The contract-v1 log: round trips, and every bad input the contract lists."""

import json
import math

import pytest
from mcap.writer import Writer

from pipeline.errors import LogError
from pipeline.log import (
    CompressedImage,
    Detection,
    Detections,
    GroundTruthLandmark,
    GroundTruthLandmarks,
    GroundTruthPose,
    LogMetadata,
    LogWriter,
    Odometry,
    RelativePose,
    StereoCalibration,
    read_log,
)
from pipeline.log import schemas as topics
from pipeline.log.limits import MAX_DETECTIONS_PER_POSE, MAX_RANGE_M
from pipeline.log.metadata import metadata_record

I3 = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
I6 = tuple(float(i == j) for i in range(6) for j in range(6))
I4 = tuple(float(i == j) for i in range(4) for j in range(4))
METADATA = LogMetadata(2, ((0.9, 0.1), (0.2, 0.8)), ("car", "van"), "tests")


def odometry(i: int) -> dict:
    return {
        "stamp_ns": 10 * (i + 1),
        "from_index": i,
        "to_index": i + 1,
        "translation": [1.0, 0.0, 0.0],
        "rotation": [0.0, 0.0, 0.0, 1.0],
        "covariance": list(I6),
    }


def detection(**changes) -> dict:
    d = {
        "class_id": 1,
        "score": 0.9,
        "bearing": 0.1,
        "elevation": 0.0,
        "range": 5.0,
        "covariance": list(I3),
        "source": "bbox",
    }
    d.update(changes)
    return d


def detections(pose: int, *dets: dict) -> dict:
    return {"stamp_ns": 10 * pose, "pose_index": pose, "detections": list(dets)}


def write_raw(path, messages, metadata=None, schema_names=None, encoding="json"):
    """An MCAP file with messages given as (topic, dict or raw bytes, log_time or None)."""
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        if metadata is not False:
            w.add_metadata("mmslam", metadata or metadata_record(METADATA))
        channels = {}
        for topic, payload, log_time in messages:
            if topic not in channels:
                name = (schema_names or {}).get(topic, topics.SCHEMAS[topic][0])
                sid = w.register_schema(name, "jsonschema", topics.schema_bytes(topic))
                channels[topic] = w.register_channel(topic, encoding, sid)
            data = payload if isinstance(payload, bytes) else json.dumps(payload).encode()
            if log_time is None:
                log_time = payload["stamp_ns"]
            w.add_message(channels[topic], log_time=log_time, data=data, publish_time=log_time)
        w.finish()
    return path


def good_messages() -> list:
    return [
        (topics.DETECTIONS, detections(0, detection()), None),
        (topics.ODOMETRY, odometry(0), None),
        (topics.DETECTIONS, detections(1, detection(), detection(class_id=0)), None),
        (topics.ODOMETRY, odometry(1), None),
    ]


def test_every_message_type_round_trips(tmp_path):
    rp = RelativePose((1.0, 2.0, 3.0), (0.0, 0.0, 0.0, 1.0), I6)
    det = Detection(1, 0.95, 0.1, -0.2, 7.5, I3, "apriltag", (1.0, 2.0, 30.0, 40.0), rp, 17)
    messages = [
        StereoCalibration(0, 1226, 370, 707.0, 707.0, 601.0, 183.0, 0.54, I4),
        GroundTruthLandmarks(0, (GroundTruthLandmark(17, 1, (1.0, 2.0, 3.0)),)),
        GroundTruthPose(0, 0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)),
        Detections(0, 0, (det,)),
        Odometry(100, 0, 1, (1.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0), I6),
        GroundTruthPose(100, 1, (1.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)),
        Detections(100, 1, ()),
    ]
    image = CompressedImage(100, "left", "png", b"\x89PNG fake bytes")
    with LogWriter(tmp_path / "a.mcap", METADATA) as w:
        for m in messages:
            w.write(m)
        w.write(image, topics.LEFT_IMAGE)
    log = read_log(tmp_path / "a.mcap", load_images=True)
    assert log.metadata == METADATA
    assert log.calibration == messages[0]
    assert log.ground_truth_landmarks == messages[1]
    assert log.ground_truth_poses == [messages[2], messages[5]]
    assert log.detections == [messages[3], messages[6]]
    assert log.odometry == [messages[4]]
    assert log.images[topics.LEFT_IMAGE] == [image]
    assert log.num_poses == 2 and log.num_detections == 1


def test_same_messages_give_the_same_bytes(tmp_path):
    for name in ("a", "b"):
        with LogWriter(tmp_path / f"{name}.mcap", METADATA) as w:
            w.write(Detections(0, 0, (Detection(0, 0.9, 0.0, 0.0, 1.0, I3, "bbox"),)))
    assert (tmp_path / "a.mcap").read_bytes() == (tmp_path / "b.mcap").read_bytes()


def test_a_failed_write_leaves_nothing_behind(tmp_path):
    with pytest.raises(RuntimeError), LogWriter(tmp_path / "x.mcap", METADATA) as w:
        w.write(Detections(0, 0, ()))
        raise RuntimeError("stop")
    assert list(tmp_path.iterdir()) == []


def test_steps_stating_one_covariance_share_it_and_others_keep_their_own(tmp_path):
    wider = dict(odometry(2), covariance=[2.0 * v for v in I6])
    messages = [*good_messages(), (topics.ODOMETRY, wider, None)]
    log = read_log(write_raw(tmp_path / "a.mcap", messages))
    first, second, third = log.odometry
    assert second.covariance is first.covariance  # equal: one tuple held
    assert third.covariance == tuple(2.0 * v for v in I6)
    assert [o.to_index for o in log.odometry] == [1, 2, 3]


def test_a_good_raw_log_reads(tmp_path):
    log = read_log(write_raw(tmp_path / "good.mcap", good_messages()))
    assert log.num_poses == 3 and log.num_detections == 3


def _with(index: int, topic: str, payload, log_time=None) -> list:
    messages = good_messages()
    messages[index] = (topic, payload, log_time)
    return messages


BAD_MESSAGES = {
    "malformed JSON": (
        _with(2, topics.DETECTIONS, b'{"stamp_ns": 10, "pose_index": 1, "detections": [', 10),
        "/detections message 1: malformed JSON",
    ),
    "NaN": (
        _with(
            2,
            topics.DETECTIONS,
            b'{"stamp_ns":10,"pose_index":1,"detections":[{"class_id":0,'
            b'"score":0.9,"bearing":NaN,"elevation":0,"range":5,"covariance":[1,0,0,0,1,0,0,0,'
            b'1],"source":"bbox"}]}',
            10,
        ),
        "/detections message 1: non-finite number NaN",
    ),
    "infinity": (
        _with(
            1,
            topics.ODOMETRY,
            b'{"stamp_ns":10,"from_index":0,"to_index":1,"translation":'
            b'[1e999,0,0],"rotation":[0,0,0,1],"covariance":['
            + ",".join(map(str, I6)).encode()
            + b"]}",
            10,
        ),
        "/odometry message 0: 'translation[0]' holds a non-finite number (inf)",
    ),
    "covariance not positive definite": (
        _with(
            2, topics.DETECTIONS, detections(1, detection(covariance=[1, 0, 0, 0, -1, 0, 0, 0, 1]))
        ),
        "/detections message 1: 'detections[0].covariance' is not positive definite",
    ),
    "odometry covariance not positive definite": (
        _with(1, topics.ODOMETRY, {**odometry(0), "covariance": [0.0] * 36}),
        "/odometry message 0: 'covariance' is not positive definite",
    ),
    "class outside 0..C-1": (
        _with(0, topics.DETECTIONS, detections(0, detection(class_id=2))),
        "/detections message 0: 'detections[0].class_id' 2 is outside 0..1",
    ),
    "odometry skips a pose": (
        _with(3, topics.ODOMETRY, {**odometry(1), "from_index": 2, "to_index": 3}),
        "/odometry message 1: links pose 2 to 3; expected 1 to 2",
    ),
    "odometry does not step by one": (
        _with(1, topics.ODOMETRY, {**odometry(0), "to_index": 2}),
        "/odometry message 0: links pose 0 to 2; expected 0 to 1",
    ),
    "detection at an unreached pose": (
        _with(2, topics.DETECTIONS, detections(7, detection())),
        "/detections message 1: pose_index 7 is not reached by odometry",
    ),
    "missing field": (
        _with(0, topics.DETECTIONS, {"stamp_ns": 0, "pose_index": 0}),
        "/detections message 0: missing field 'detections'",
    ),
    "log time differs from stamp": (
        _with(1, topics.ODOMETRY, odometry(0), 999),
        "/odometry message 0: log_time 999 differs from stamp_ns 10",
    ),
    "not a unit quaternion": (
        _with(1, topics.ODOMETRY, {**odometry(0), "rotation": [0.0, 0.0, 0.0, 2.0]}),
        "/odometry message 0: 'rotation' is not a unit quaternion",
    ),
    "unknown source": (
        _with(0, topics.DETECTIONS, detections(0, detection(source="lidar"))),
        "/detections message 0: 'detections[0].source' must be one of",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD_MESSAGES))
def test_bad_messages_are_refused_naming_topic_and_position(tmp_path, case):
    messages, expected = BAD_MESSAGES[case]
    path = write_raw(tmp_path / "bad.mcap", messages)
    with pytest.raises(LogError) as info:
        read_log(path)
    message = str(info.value)
    assert expected in message
    assert str(path) in message
    assert "\n" not in message


def test_truncated_file_is_refused(tmp_path):
    path = write_raw(tmp_path / "whole.mcap", good_messages() * 20)
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(LogError, match="truncated or corrupt"):
        read_log(cut)


@pytest.mark.parametrize(
    "metadata,expected",
    [
        (False, "no metadata record named 'mmslam'"),
        ({**metadata_record(METADATA), "format_version": "2"}, "format_version '2'"),
        (
            {**metadata_record(METADATA), "confusion_matrix": "[[0.9, 0.2], [0.2, 0.8]]"},
            "confusion_matrix row 0 sums to 1.1",
        ),
        ({**metadata_record(METADATA), "confusion_matrix": "[[1.0]]"}, "must be 2 x 2"),
        (
            {**metadata_record(METADATA), "class_names": '["car"]'},
            "class_names must be a list of 2",
        ),
        (
            {k: v for k, v in metadata_record(METADATA).items() if k != "num_classes"},
            "lacks 'num_classes'",
        ),
    ],
)
def test_bad_metadata_is_refused(tmp_path, metadata, expected):
    path = write_raw(tmp_path / "meta.mcap", good_messages(), metadata=metadata)
    with pytest.raises(LogError, match=expected.replace("[", r"\[")):
        read_log(path)


def test_wrong_schema_and_encoding_are_refused(tmp_path):
    path = write_raw(tmp_path / "s.mcap", good_messages(), schema_names={"/odometry": "nav.Odom"})
    with pytest.raises(LogError, match=r"/odometry: schema is .nav\.Odom."):
        read_log(path)
    path = write_raw(tmp_path / "e.mcap", good_messages(), encoding="cbor")
    with pytest.raises(LogError, match="message encoding is 'cbor'"):
        read_log(path)


def test_missing_file_and_directory_are_refused(tmp_path):
    with pytest.raises(LogError, match="no such file"):
        read_log(tmp_path / "nope.mcap")
    with pytest.raises(LogError, match="is a directory"):
        read_log(tmp_path)


def test_not_an_mcap_file_is_refused(tmp_path):
    path = tmp_path / "text.mcap"
    path.write_text("hello")
    with pytest.raises(LogError, match="truncated or corrupt"):
        read_log(path)


def test_reader_accepts_what_the_writer_writes_for_every_float(tmp_path):
    tiny = 1e-300
    with LogWriter(tmp_path / "f.mcap", METADATA) as w:
        w.write(Detections(0, 0, (Detection(0, 0.0, -math.pi, tiny, MAX_RANGE_M, I3, "bbox"),)))
    (det,) = read_log(tmp_path / "f.mcap").detections[0].detections
    assert det.bearing == -math.pi and det.elevation == tiny and det.range == MAX_RANGE_M


def test_written_messages_follow_the_json_schemas_in_the_file(tmp_path):
    """Each channel carries a JSON Schema; every message of a written log validates against it."""
    import jsonschema
    from mcap.reader import make_reader

    rp = RelativePose((1.0, 2.0, 3.0), (0.0, 0.0, 0.0, 1.0), I6)
    det = Detection(1, 0.95, 0.1, -0.2, 7.5, I3, "apriltag", (1.0, 2.0, 30.0, 40.0), rp, 17)
    with LogWriter(tmp_path / "s.mcap", METADATA) as w:
        w.write(StereoCalibration(0, 1226, 370, 707.0, 707.0, 601.0, 183.0, 0.54, I4))
        w.write(GroundTruthLandmarks(0, (GroundTruthLandmark(17, 1, (1.0, 2.0, 3.0)),)))
        w.write(Detections(0, 0, (det,)))
        w.write(Odometry(100, 0, 1, (1.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0), I6))
        w.write(GroundTruthPose(100, 1, (1.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)))
        w.write(CompressedImage(100, "left", "png", b"png"), topics.LEFT_IMAGE)
    seen = set()
    with open(tmp_path / "s.mcap", "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            if channel.topic.startswith("/foxglove/"):
                continue  # Foxglove's protobuf messages: tests/test_foxglove.py checks those
            jsonschema.validate(json.loads(message.data), json.loads(schema.data))
            seen.add(channel.topic)
    assert len(seen) == 6
    bad = json.loads(json.dumps({"stamp_ns": 0, "pose_index": 0, "detections": [{"range": -1}]}))
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(bad, json.loads(topics.schema_bytes(topics.DETECTIONS)))


def test_a_pose_holds_at_most_the_detections_a_keyframe_may(tmp_path):
    """MAX_DETECTIONS_PER_POSE over all of a pose's messages: at the bound a log reads; one
    more, even split over two messages, is refused naming the pose and the message."""
    half = MAX_DETECTIONS_PER_POSE // 2
    batch = [detection(bearing=0.001 * k) for k in range(half)]
    at_bound = [
        (topics.DETECTIONS, detections(0, *batch), None),
        (topics.DETECTIONS, detections(0, *batch), None),
        (topics.ODOMETRY, odometry(0), None),
    ]
    assert read_log(write_raw(tmp_path / "full.mcap", at_bound)).num_detections == 2 * half
    over = [*at_bound[:2], (topics.DETECTIONS, detections(0, detection()), None), at_bound[2]]
    with pytest.raises(LogError) as info:
        read_log(write_raw(tmp_path / "over.mcap", over))
    assert f"/detections message 2: pose 0 holds {2 * half + 1} detections" in str(info.value)


def test_inspect_and_replay_name_the_same_first_problem(tmp_path):
    """Issue 53: 300 messages of 1,000 detections of pose 100 (30 KB that inflate 1,500 times):
    the reader stops at the second message, over the detections a pose may hold; `inspect`,
    which reads on to count the topics, called it a decompression bomb."""
    from pipeline.inspect import inspect_log

    batch = [detection(bearing=0.0) for _ in range(MAX_DETECTIONS_PER_POSE)]
    messages = [(topics.ODOMETRY, odometry(k), None) for k in range(101)]
    messages += [(topics.DETECTIONS, detections(100, *batch), None)] * 300
    path = write_raw(tmp_path / "many.mcap", messages)
    with pytest.raises(LogError) as info:
        read_log(path)
    assert "/detections message 1: pose 100 holds 2000 detections, more than the 1000" in str(
        info.value
    )
    assert inspect_log(path)["problem"] == str(info.value)
