"""The log's codec and validator as properties (hypothesis): any valid message survives its
JSON round trip; any corruption of one is refused in one line that names the field; any
message sequence the contract allows passes the validator, and one broken at any message is
refused there, naming the topic and the message's position."""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Callable

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from pipeline.errors import LogError
from pipeline.log import codec, limits, schemas
from pipeline.log.mcap_stream import ChannelInfo
from pipeline.log.messages import (
    CompressedImage,
    Detection,
    Detections,
    GroundTruthLandmark,
    GroundTruthLandmarks,
    GroundTruthPose,
    LogMetadata,
    Odometry,
    RelativePose,
    StereoCalibration,
)
from pipeline.log.validate import LogValidator
from pipeline.settings import SHOWN_CHARS
from tests.sequences import assert_same

NUM_CLASSES = 3
METADATA = LogMetadata(
    NUM_CLASSES, ((0.8, 0.1, 0.1), (0.1, 0.8, 0.1), (0.1, 0.1, 0.8)), ("a", "b", "c"), "tests"
)
finite = st.floats(-50.0, 50.0, allow_nan=False)


@st.composite
def covariances(draw, dim: int) -> tuple[float, ...]:
    """Symmetric positive definite, variances in [1e-6, 1e2] (a random rotation of them)."""
    logs = np.array(draw(st.lists(st.floats(-6.0, 2.0), min_size=dim, max_size=dim)))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    q, _ = np.linalg.qr(rng.normal(size=(dim, dim)))
    matrix = q @ np.diag(10.0**logs) @ q.T
    return tuple(float(v) for v in ((matrix + matrix.T) / 2).ravel())


@st.composite
def quaternions(draw) -> tuple[float, float, float, float]:
    v = np.array(draw(st.lists(st.floats(-1.0, 1.0), min_size=4, max_size=4)))
    if np.linalg.norm(v) < 0.1:
        v = np.array([0.0, 0.0, 0.0, 1.0])
    return tuple(float(x) for x in v / np.linalg.norm(v))


vectors = st.tuples(finite, finite, finite)
stamps = st.integers(0, limits.MAX_STAMP_NS)


@st.composite
def detections(draw) -> Detection:
    bbox = None
    if draw(st.booleans()):
        u = sorted(draw(st.lists(st.floats(0.0, 2000.0), min_size=2, max_size=2)))
        v = sorted(draw(st.lists(st.floats(0.0, 2000.0), min_size=2, max_size=2)))
        bbox = (u[0], v[0], u[1], v[1])
    relative = None
    if draw(st.booleans()):
        relative = RelativePose(draw(vectors), draw(quaternions()), draw(covariances(6)))
    return Detection(
        class_id=draw(st.integers(0, NUM_CLASSES - 1)),
        score=draw(st.floats(0.0, 1.0)),
        bearing=draw(st.floats(-math.pi, math.pi)),
        elevation=draw(st.floats(-math.pi / 2, math.pi / 2)),
        range=draw(st.floats(limits.MIN_RANGE_M, 500.0)),
        covariance=draw(covariances(3)),
        source=draw(st.sampled_from(["apriltag", "bbox"])),
        bbox=bbox,
        relative_pose=relative,
        truth_landmark_id=draw(st.none() | st.integers(-1, 2**40)),
    )


@st.composite
def calibrations(draw) -> StereoCalibration:
    body = np.eye(4)
    q = draw(quaternions())
    x, y, z, w = q
    body[:3, :3] = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]
    body[:3, 3] = draw(vectors)
    return StereoCalibration(
        draw(stamps), draw(st.integers(1, 4000)), draw(st.integers(1, 4000)),
        draw(st.floats(1.0, 5000.0)), draw(st.floats(1.0, 5000.0)),
        draw(finite), draw(finite), draw(st.floats(0.01, 2.0)),
        tuple(float(v) for v in body.ravel()),
    )  # fmt: skip


ODOMETRY = st.builds(
    Odometry, stamps, st.integers(0, 10**6), st.integers(0, 10**6), vectors, quaternions(),
    covariances(6),
)  # fmt: skip
STRATEGIES = {
    Odometry: ODOMETRY,
    Detections: st.builds(
        Detections, stamps, st.integers(0, 10**6),
        st.lists(detections(), min_size=1, max_size=3).map(tuple),
    ),
    GroundTruthPose: st.builds(GroundTruthPose, stamps, st.integers(0, 10**6), vectors,
                               quaternions()),
    GroundTruthLandmarks: st.builds(
        GroundTruthLandmarks, stamps,
        st.lists(st.builds(GroundTruthLandmark, st.integers(0, 2**40),
                           st.integers(0, NUM_CLASSES - 1), vectors), min_size=1,
                 max_size=3).map(tuple),
    ),
    StereoCalibration: calibrations(),
}  # fmt: skip
messages = st.one_of(*STRATEGIES.values())


def wire(msg) -> bytes:
    return json.dumps(codec.encode(msg), separators=(",", ":"), allow_nan=False).encode()


@given(messages)
def test_every_valid_message_survives_its_round_trip(msg):
    decoded = codec.decode(type(msg), wire(msg), NUM_CLASSES)
    assert type(decoded) is type(msg)
    assert_same(decoded, msg, type(msg).__name__)


@given(stamps, st.text(max_size=20), st.binary(max_size=64))
def test_an_image_survives_its_round_trip(stamp, frame_id, data):
    image = CompressedImage(stamp, frame_id, "jpeg", data)
    decoded = codec.decode_compressed_image(wire(image))
    assert (decoded.stamp_ns, decoded.frame_id, decoded.format, decoded.data) == (
        stamp, frame_id, "jpeg", data,
    )  # fmt: skip


# --- corruptions: (applies to, what it does to the message's JSON object, the field named) ---


def _matrix(values: list[float]) -> np.ndarray:
    n = math.isqrt(len(values))
    return np.array(values).reshape(n, n)


def _asymmetric(c: list[float]) -> list[float]:
    m = _matrix(c)
    m[0, 1] += 0.5 * math.sqrt(m[0, 0] * m[1, 1]) + 1.0
    return m.ravel().tolist()


def _singular(c: list[float]) -> list[float]:
    m = _matrix(c)
    m[:, 0] = m[0, :] = 0.0
    return m.ravel().tolist()


def _tiny(c: list[float]) -> list[float]:
    m = _matrix(c)
    return (m * (0.5 * limits.MIN_VARIANCE / np.max(np.diag(m)))).ravel().tolist()


def _ill_conditioned(c: list[float]) -> list[float]:
    n = math.isqrt(len(c))
    return np.diag([1.0] * (n - 1) + [0.5 / limits.MAX_CONDITION]).ravel().tolist()


def _scaled(factor: float) -> Callable[[list[float]], list[float]]:
    return lambda q: [factor * v for v in q]


def _upside_down(box: list[float]) -> list[float]:
    u0, v0, u1, v1 = box
    return [u0, v1 + 1.0, u1, v0]


def _bottom_row(m: list[float]) -> list[float]:
    return [*m[:12], 0.0, 0.0, 0.1, 1.0]


def _sheared(m: list[float]) -> list[float]:
    out = list(m)
    out[1] += 0.5
    return out


# (message type, path to the field, change, what the message must say)
CORRUPTIONS = [
    (Odometry, ("covariance",), _asymmetric, "'covariance' is not symmetric"),
    (Odometry, ("covariance",), _singular, "'covariance' is not positive definite"),
    (Odometry, ("covariance",), _tiny, "'covariance' has a variance"),
    (Odometry, ("covariance",), _ill_conditioned, "'covariance' has condition number"),
    (Odometry, ("rotation",), _scaled(0.99), "'rotation' is not a unit quaternion"),
    (Odometry, ("rotation",), _scaled(1.01), "'rotation' is not a unit quaternion"),
    (Odometry, ("translation",), lambda t: [2e3, 0.0, 0.0], "'translation' has length"),
    (Odometry, ("stamp_ns",), lambda s: "soon", "stamp_ns"),
    (Odometry, ("rotation",), None, "rotation"),  # None: the field taken out
    (GroundTruthPose, ("rotation",), _scaled(0.98), "'rotation' is not a unit quaternion"),
    (Detections, ("detections", 0, "bbox"), _upside_down, "'detections[0].bbox' must be"),
    (Detections, ("detections", 0, "class_id"), lambda c: NUM_CLASSES, "outside 0..2"),
    (Detections, ("detections", 0, "covariance"), _singular, "'detections[0].covariance'"),
    (
        Detections,
        ("detections", 0, "relative_pose", "covariance"),
        _asymmetric,
        "'detections[0].relative_pose.covariance' is not symmetric",
    ),
    (
        Detections,
        ("detections", 0, "relative_pose", "rotation"),
        _scaled(1.1),
        "'detections[0].relative_pose.rotation' is not a unit quaternion",
    ),
    (Detections, ("detections", 0, "source"), lambda s: "x" * 500, "source"),
    (GroundTruthLandmarks, ("landmarks", 0, "class_id"), lambda c: 7, "outside 0..2"),
    (StereoCalibration, ("body_from_camera",), _bottom_row, "must end in the row [0, 0, 0, 1]"),
    (StereoCalibration, ("body_from_camera",), _sheared, "must hold a rotation"),
]


def corrupt(obj: dict, path: tuple, change: Callable | None) -> dict:
    parent = obj
    for step in path[:-1]:
        parent = parent[step]
    if change is None:
        del parent[path[-1]]
    else:
        parent[path[-1]] = change(parent[path[-1]])
    return obj


def applies(obj: dict, path: tuple) -> bool:
    here = obj
    for step in path:
        try:
            here = here[step]
        except (KeyError, IndexError, TypeError):
            return False
        if here is None:
            return False
    return True


@pytest.mark.parametrize("corruption", CORRUPTIONS, ids=[c[3] for c in CORRUPTIONS])
@settings(max_examples=15)
@given(data=st.data())
def test_any_corruption_is_refused_in_one_line_naming_the_field(corruption, data):
    kind, path, change, needle = corruption
    obj = codec.encode(data.draw(STRATEGIES[kind]))
    assume(applies(obj, path))
    data = json.dumps(corrupt(obj, path, change)).encode()
    with pytest.raises(ValueError) as caught:
        codec.decode(kind, data, NUM_CLASSES)
    text = str(caught.value)
    assert needle in text and "\n" not in text
    assert len(text) < 300  # a long bad value is cut short


@given(messages, st.sampled_from(["NaN", "Infinity", "-Infinity"]))
def test_a_non_finite_number_is_named_as_such(msg, constant):
    text = wire(msg).decode()
    first_number = text.index('"stamp_ns":') + len('"stamp_ns":')
    end = first_number
    while text[end].isdigit():
        end += 1
    bad = text[:first_number] + constant + text[end:]
    with pytest.raises(ValueError, match=f"non-finite number {constant}"):
        codec.decode(type(msg), bad.encode(), NUM_CLASSES)


def test_a_bad_value_is_shown_cut_short():
    assert codec.shown("x" * 10) == repr("x" * 10)
    long = codec.shown("y" * 1000)
    assert len(long) == SHOWN_CHARS and long.endswith("...")


# --- the validator over message sequences ----------------------------------------------------


def channel(topic: str, channel_id: int) -> ChannelInfo:
    return ChannelInfo(channel_id, topic, schemas.SCHEMAS[topic][0], "jsonschema", "json")


CHANNELS = {
    topic: channel(topic, k)
    for k, topic in enumerate(
        (schemas.ODOMETRY, schemas.DETECTIONS, schemas.GT_POSE, schemas.GT_LANDMARKS)
    )
}
I3 = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
I6 = tuple(float(i == j) for i in range(6) for j in range(6))
IDENTITY = (0.0, 0.0, 0.0, 1.0)


def step(i: int, stamp: int) -> Odometry:
    return Odometry(stamp, i, i + 1, (1.0, 0.0, 0.0), IDENTITY, I6)


def seen(pose: int, stamp: int, count: int = 1) -> Detections:
    detection = Detection(0, 0.9, 0.1, 0.0, 5.0, I3, "bbox")
    return Detections(stamp, pose, (detection,) * count)


def truth(pose: int, stamp: int) -> GroundTruthPose:
    return GroundTruthPose(stamp, pose, (float(pose), 0.0, 0.0), IDENTITY)


@st.composite
def valid_logs(draw) -> list[tuple[str, object]]:
    """A log the contract allows: odometry 0 -> 1 -> ... -> n, detections and ground truth at
    reached poses, each topic's stamps never going back, the topics interleaved at random (a
    pose's detections may come before the odometry that reaches it)."""
    n = draw(st.integers(1, 12))
    odometry = [(schemas.ODOMETRY, step(i, 100 * (i + 1))) for i in range(n)]
    poses = sorted(draw(st.lists(st.integers(0, n), max_size=10)))
    seen_at = [(schemas.DETECTIONS, seen(p, 100 * p + 50)) for p in poses]
    truths = sorted(set(draw(st.lists(st.integers(0, n), max_size=6))))
    truth_at = [(schemas.GT_POSE, truth(p, 100 * p + 10)) for p in truths]
    landmarks = GroundTruthLandmarks(
        0, (GroundTruthLandmark(1, 0, (1.0, 2.0, 0.0)), GroundTruthLandmark(2, 1, (3.0, 0.0, 0.0)))
    )
    streams = [odometry, seen_at, truth_at, [(schemas.GT_LANDMARKS, landmarks)]]
    order = draw(st.permutations([k for k, s in enumerate(streams) for _ in s]))
    cursors = [0] * len(streams)
    log = []
    for k in order:
        log.append(streams[k][cursors[k]])
        cursors[k] += 1
    return log


def validate(log: list[tuple[str, object]]) -> None:
    validator = LogValidator("test.mcap", METADATA)
    counts = dict.fromkeys(CHANNELS, 0)
    for topic, msg in log:
        validator.message(CHANNELS[topic], counts[topic], msg.stamp_ns, wire(msg))
        counts[topic] += 1
    validator.finish(CHANNELS.values())


@given(valid_logs())
def test_every_log_the_contract_allows_passes(log):
    validate(log)


def positions(log: list[tuple[str, object]]) -> list[int]:
    """Each message's position within its topic."""
    counts: dict[str, int] = {}
    out = []
    for topic, _ in log:
        out.append(counts.get(topic, 0))
        counts[topic] = out[-1] + 1
    return out


def _replace(log, at, msg):
    return [*log[:at], (log[at][0], msg), *log[at + 1 :]]


# Breaks: (topic of the message broken, how, the reason's words). Each returns the broken log
# and the index (in the log) of the message to be refused, or None where it does not apply.
def break_stamp_back(log):
    at = [k for k, (t, _) in enumerate(log) if t == schemas.DETECTIONS]
    if len(at) < 2:
        return None
    msg = log[at[1]][1]
    earlier = log[at[0]][1].stamp_ns - 1
    return _replace(log, at[1], dataclasses.replace(msg, stamp_ns=earlier)), at[1]


def break_skip_pose(log):
    at = [k for k, (t, _) in enumerate(log) if t == schemas.ODOMETRY]
    msg = log[at[-1]][1]
    return _replace(log, at[-1], dataclasses.replace(msg, to_index=msg.to_index + 1)), at[-1]


def break_repeat_stamp(log):
    at = [k for k, (t, _) in enumerate(log) if t == schemas.ODOMETRY]
    if len(at) < 2:
        return None
    previous = log[at[-2]][1].stamp_ns
    return _replace(log, at[-1], dataclasses.replace(log[at[-1]][1], stamp_ns=previous)), at[-1]


def break_truth_twice(log):
    at = [k for k, (t, _) in enumerate(log) if t == schemas.GT_POSE]
    if not at:
        return None
    msg = log[at[-1]][1]
    return [*log, (schemas.GT_POSE, dataclasses.replace(msg, stamp_ns=10**6))], len(log)


def break_landmarks_twice(log):
    at = next(k for k, (t, _) in enumerate(log) if t == schemas.GT_LANDMARKS)
    return [*log, log[at]], len(log)


def break_landmark_ids(log):
    at = next(k for k, (t, _) in enumerate(log) if t == schemas.GT_LANDMARKS)
    msg = log[at][1]
    twice = (msg.landmarks[0], dataclasses.replace(msg.landmarks[1], id=msg.landmarks[0].id))
    return _replace(log, at, dataclasses.replace(msg, landmarks=twice)), at


def break_unreached(log):
    last = max(m.to_index for t, m in log if t == schemas.ODOMETRY)
    return [*log, (schemas.DETECTIONS, seen(last + 1, 10**7))], len(log)


BREAKS = [
    (break_stamp_back, "is before the previous message's"),
    (break_skip_pose, "links pose"),
    (break_repeat_stamp, "repeats the previous pose's"),
    (break_truth_twice, "given twice"),
    (break_landmarks_twice, "only one ground-truth landmark message"),
    (break_landmark_ids, "landmark ids are not unique"),
    (break_unreached, "is not reached by odometry"),
]


@pytest.mark.parametrize("broken", BREAKS, ids=lambda b: b[0].__name__)
@settings(max_examples=20)
@given(log=valid_logs())
def test_a_log_broken_at_any_message_is_refused_there(broken, log):
    make, reason = broken
    result = make(log)
    assume(result is not None)
    bad, at = result
    topic, position = bad[at][0], positions(bad)[at]
    with pytest.raises(LogError) as caught:
        validate(bad)
    error = caught.value
    assert reason in error.reason and "\n" not in str(error)
    assert (error.topic, error.index) == (topic, position)


def test_log_time_must_be_the_stamp_and_a_message_at_the_cap_is_read():
    validator = LogValidator("test.mcap", METADATA)
    with pytest.raises(LogError, match="log_time 5 differs from stamp_ns 100"):
        validator.message(CHANNELS[schemas.ODOMETRY], 0, 5, wire(step(0, 100)))
    validator = LogValidator("test.mcap", METADATA)
    data = wire(step(0, 100))
    padded = data + b" " * (limits.MAX_JSON_MESSAGE_BYTES - len(data))
    validator.message(CHANNELS[schemas.ODOMETRY], 0, 100, padded)
    with pytest.raises(LogError, match="more than the"):
        validator.message(CHANNELS[schemas.ODOMETRY], 1, 200, padded + b" ")


def test_a_channel_without_messages_is_checked_too():
    validator = LogValidator("test.mcap", METADATA)
    wrong = ChannelInfo(9, schemas.CALIBRATION, "mmslam.Calibration", "jsonschema", "json")
    with pytest.raises(LogError, match=r"schema is 'mmslam\.Calibration'"):
        validator.finish([*CHANNELS.values(), wrong])
    wrong = dataclasses.replace(channel(schemas.ODOMETRY, 9), schema_encoding="protobuf")
    with pytest.raises(LogError, match="schema encoding is 'protobuf'"):
        LogValidator("test.mcap", METADATA).finish([wrong])
