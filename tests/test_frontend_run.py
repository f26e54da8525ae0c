"""The front-end end to end: a rendered sequence in, a contract-v1 log out, checked against the
sequence's ground truth; and the plain layout, and bad input."""

from __future__ import annotations

import dataclasses
import functools
import json
import logging
import re
import shutil
import struct
import subprocess
import sys
import tempfile
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from pipeline.cli import main
from pipeline.datasets.camera import BODY_FROM_CAMERA
from pipeline.datasets.kitti import KittiSequence, camera_poses_to_body
from pipeline.datasets.plain import PlainSequence
from pipeline.errors import InputError
from pipeline.frontend import geometry as g
from pipeline.frontend.classes import tag_class_names
from pipeline.frontend.config import load_frontend_config
from pipeline.frontend.ground_truth import box_corners, projected_box, read_landmarks
from pipeline.frontend.model_files import MODELS_ENV
from pipeline.frontend.run import class_metadata, open_sequence, run_frontend, run_objects
from pipeline.log import read_log
from tests import real_data
from tests.detector import installed

DEMO_FRAMES = 40
SMALL_INDOOR = Path(__file__).resolve().parents[1] / "configs/scenarios/small-indoor-tags.toml"
CHI2_3DOF_999 = 16.27


@functools.cache
def rendered_demo() -> Path:
    """The first frames of the renderer's demo preset, rendered once a test session (~10 s)."""
    from data_tools.render import render_sequence

    root = Path(_scratch.name) / "demo"
    return render_sequence("demo", root, seed=0, num_frames=DEMO_FRAMES)


_scratch = tempfile.TemporaryDirectory(prefix="mmslam-frontend-tests-")


@pytest.fixture(scope="module")
def demo_log(tmp_path_factory):
    out = tmp_path_factory.mktemp("frontend") / "demo.mcap"
    summary = run_frontend(rendered_demo(), out, images=True, progress=False)
    return summary, read_log(out), KittiSequence(rendered_demo())


def truth_landmarks(sequence_dir: Path) -> dict[int, dict]:
    document = json.loads((sequence_dir / "landmarks.json").read_text())
    return {lm["id"]: lm for lm in document["landmarks"]}


@pytest.mark.slow
@pytest.mark.e2e
def test_log_is_valid_and_complete(demo_log):
    summary, log, sequence = demo_log
    assert log.num_poses == summary.num_poses
    assert len(log.detections) == log.num_poses  # one message a pose, empty or not
    assert DEMO_FRAMES // 10 < log.num_poses <= DEMO_FRAMES
    assert [m.pose_index for m in log.ground_truth_poses] == list(range(log.num_poses))
    assert log.image_counts == {
        "/camera/left/compressed": log.num_poses,
        "/camera/right/compressed": log.num_poses,
    }
    objects = load_frontend_config().objects.classes if summary.object_boxes else ()
    assert log.metadata.class_names == (*tag_class_names(2), *objects)
    np.testing.assert_allclose(log.metadata.confusion_matrix, np.eye(2 + len(objects)))
    calibration = log.calibration
    assert calibration is not None
    assert (calibration.width, calibration.fx) == (
        sequence.intrinsics.width,
        sequence.intrinsics.fx,
    )
    np.testing.assert_allclose(np.reshape(calibration.body_from_camera, (4, 4)), BODY_FROM_CAMERA)
    stamps = [m.stamp_ns for m in log.odometry]
    assert stamps == sorted(stamps)


@pytest.mark.slow
@pytest.mark.e2e
def test_odometry_matches_the_ground_truth(demo_log):
    _, log, _ = demo_log
    truth = []
    for message in log.ground_truth_poses:
        pose = np.eye(4)
        pose[:3, :3] = g.rotation_from_quaternion(message.rotation)
        pose[:3, 3] = message.translation
        truth.append(pose)
    np.testing.assert_allclose(truth[0], np.eye(4), atol=1e-9)
    estimate = np.eye(4)
    for message in log.odometry:
        step = np.eye(4)
        step[:3, :3] = g.rotation_from_quaternion(message.rotation)
        step[:3, 3] = message.translation
        true_step = np.linalg.inv(truth[message.from_index]) @ truth[message.to_index]
        delta = np.linalg.inv(step) @ true_step
        assert np.linalg.norm(delta[:3, 3]) < 0.06
        assert g.rotation_angle(delta[:3, :3]) < np.radians(0.3)
        estimate = estimate @ step
    # Dead reckoning over the whole run (~35 m): within 1 % of the distance.
    distance = sum(
        np.linalg.norm(truth[k + 1][:3, 3] - truth[k][:3, 3]) for k in range(len(truth) - 1)
    )
    assert np.linalg.norm(estimate[:3, 3] - truth[-1][:3, 3]) < 0.01 * distance


@pytest.mark.slow
@pytest.mark.e2e
def test_tag_detections_match_the_ground_truth(demo_log):
    _, log, sequence = demo_log
    landmarks = truth_landmarks(sequence.root)
    truth_classes = {lm.id: lm.class_id for lm in log.ground_truth_landmarks.landmarks}
    body = camera_poses_to_body(sequence.gt_poses)
    keyframe_of_pose = {
        m.pose_index: int(np.argmin([abs(t * 1e9 - m.stamp_ns) for t in sequence.times]))
        for m in log.detections
    }
    relative_errors = []
    count = 0
    for message in log.detections:
        pose = body[keyframe_of_pose[message.pose_index]]
        for detection in message.detections:
            if detection.source == "bbox":
                continue
            count += 1
            assert detection.source == "apriltag"
            landmark = landmarks[detection.truth_landmark_id]
            assert landmark["kind"] == "tag"
            assert detection.class_id == landmark["tag_id"] % 2
            assert truth_classes[detection.truth_landmark_id] == detection.class_id
            point = np.linalg.inv(pose) @ np.r_[landmark["position"], 1.0]
            true = g.bearing_elevation_range(point[:3])
            error = np.array([detection.bearing, detection.elevation, detection.range]) - true
            covariance = np.reshape(detection.covariance, (3, 3))
            # Within the stated noise, and within 3 % of the range.
            assert error @ np.linalg.solve(covariance, error) < CHI2_3DOF_999
            assert abs(error[2]) < 0.03 * true[2]
            assert np.abs(error[:2]).max() < np.radians(0.2)
            relative_errors.append(abs(error[2]) / true[2])
            # The tag's 6-DoF pose: its translation is the tag centre, near the point.
            assert detection.relative_pose is not None
            assert np.linalg.norm(detection.relative_pose.translation - point[:3]) < 0.05 * true[2]
    assert count >= 10
    assert np.median(relative_errors) < 0.01


@pytest.mark.slow
@pytest.mark.e2e
def test_the_default_config_boxes_the_rendered_cars(demo_log):
    # Measured: 6 boxes in the 40 frames' 21 keyframes, 5 on a car (yolov3-tiny calls these
    # cars buses, our trucks) and one on none.
    installed()
    summary, log, sequence = demo_log
    assert summary.object_boxes
    landmarks = truth_landmarks(sequence.root)
    names = log.metadata.class_names
    boxes = [d for m in log.detections for d in m.detections if d.source == "bbox"]
    on_cars = [d for d in boxes if d.truth_landmark_id in landmarks]
    assert summary.num_box_detections == len(boxes) >= 3
    assert len(on_cars) >= 0.6 * len(boxes)
    for detection in boxes:
        assert names[detection.class_id] in ("car", "van", "truck")
    for detection in on_cars:
        assert landmarks[detection.truth_landmark_id]["kind"] == "box"


KITTI_CLIP = real_data.REAL_DATA / "kitti-clip-1"


@pytest.mark.slow
@pytest.mark.e2e
@real_data.needs(KITTI_CLIP)
def test_the_default_config_boxes_the_cars_of_a_real_kitti_clip(tmp_path):
    # 51 real frames of a street with parked cars: measured 93 boxes, every one a car
    installed()
    out = tmp_path / "k.mcap"
    assert main(["frontend", str(KITTI_CLIP), "--out", str(out), "-q"]) == 0
    log = read_log(out)
    boxes = [d for m in log.detections for d in m.detections if d.source == "bbox"]
    assert len(boxes) >= 50
    assert {log.metadata.class_names[d.class_id] for d in boxes} == {"car"}
    ranges = [d.range for d in boxes]  # measured: 5.6-157 m, most of them parked near
    assert min(ranges) > 2.0 and 5.0 < float(np.median(ranges)) < 40.0


def test_without_a_model_boxes_are_off_with_a_note_unless_required(tmp_path, monkeypatch, caplog):
    monkeypatch.setenv(MODELS_ENV, str(tmp_path / "no-models"))
    root = plain_sequence(tmp_path / "seq", frames=3)
    with caplog.at_level(logging.WARNING, logger="pipeline"):
        summary = run_frontend(root, tmp_path / "out.mcap", progress=False)
    assert not summary.object_boxes
    assert "no box detections (object boxes off)" in summary.summary_line()
    notes = [r.getMessage() for r in caplog.records if "object boxes off" in r.getMessage()]
    assert len(notes) == 1 and "make models" in notes[0] and "\n" not in notes[0]
    assert read_log(tmp_path / "out.mcap").metadata.class_names == tuple(tag_class_names(2))
    required = tmp_path / "required.toml"
    required.write_text("[objects]\nrequire_model = true\n")
    with pytest.raises(InputError, match="no model at"):
        run_frontend(root, tmp_path / "other.mcap", required, progress=False)
    # a bad sequence is the one line: no note about the model before it
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="pipeline"), pytest.raises(InputError):
        run_frontend(tmp_path / "no-such-sequence", tmp_path / "x.mcap", progress=False)
    assert not caplog.records


def test_simulate_and_the_frontend_name_the_tag_classes_alike(tmp_path):
    from data_tools.scenarios import simulate

    simulate("indoor-tags", tmp_path / "tags.mcap", config_path=SMALL_INDOOR)
    simulated = read_log(tmp_path / "tags.mcap").metadata.class_names
    config = dataclasses.replace(
        load_frontend_config(),
        objects=dataclasses.replace(load_frontend_config().objects, enabled=False),
    )
    assert class_metadata(config, None, "test").class_names == simulated


def plain_sequence(root: Path, frames: int = 6, swapped: bool = False, **camera) -> Path:
    """The first frames of the rendered demo in the plain layout; `camera` changes its
    calibration, `swapped` puts the left images in right/ and the right ones in left/."""
    source = KittiSequence(rendered_demo())
    (root / "left").mkdir(parents=True)
    (root / "right").mkdir()
    sides = ("right", "left") if swapped else ("left", "right")
    for index in range(frames):
        shutil.copy(source.left_files[index], root / sides[0] / f"frame{index:03d}.png")
        shutil.copy(source.right_files[index], root / sides[1] / f"frame{index:03d}.png")
    k = dataclasses.asdict(source.intrinsics) | camera
    (root / "calibration.toml").write_text(
        "[camera]\n"
        + "".join(f"{key} = {k[key]}\n" for key in ("fx", "fy", "cx", "cy", "baseline"))
        + "[sequence]\nframe_rate = 5.0\n"
    )
    return root


@pytest.mark.slow
@pytest.mark.e2e
def test_same_sequence_in_the_plain_layout(tmp_path):
    root = plain_sequence(tmp_path / "plain")
    k = KittiSequence(rendered_demo()).intrinsics
    sequence = open_sequence(root)
    assert isinstance(sequence, PlainSequence)
    assert sequence.intrinsics == k
    np.testing.assert_allclose(sequence.times, np.arange(6) / 5.0)
    assert sequence.gt_poses is None
    summary = run_frontend(root, tmp_path / "plain.mcap", progress=False)
    log = read_log(tmp_path / "plain.mcap")
    assert log.num_poses == summary.num_poses >= 2
    assert not log.has_ground_truth
    frame_stamps = {round(t * 1e9) for t in sequence.times}
    assert all(m.stamp_ns in frame_stamps for m in log.odometry)


def test_plain_layout_errors_name_what_is_wrong(tmp_path):
    root = tmp_path / "plain"
    (root / "left").mkdir(parents=True)
    (root / "right").mkdir()
    source = KittiSequence(rendered_demo())
    shutil.copy(source.left_files[0], root / "left" / "a.png")
    shutil.copy(source.right_files[0], root / "right" / "a.png")
    (root / "calibration.toml").write_text("[camera]\nfx = 1.0\nfy = 1.0\ncx = 0\ncy = 0\n")
    with pytest.raises(InputError, match=r"camera\.baseline"):
        PlainSequence(root)
    (root / "calibration.toml").write_text(
        "[camera]\nfx = 1.0\nfy = 1.0\ncx = 0\ncy = 0\nbaseline = 0.5\nwidth = 99\n"
    )
    with pytest.raises(InputError, match=r"camera\.width is 99"):
        PlainSequence(root)


def test_bad_input_leaves_no_log(tmp_path):
    out = tmp_path / "out.mcap"
    with pytest.raises(InputError, match="no such file or directory"):
        run_frontend(tmp_path / "missing", out, progress=False)
    with pytest.raises(InputError, match="none of the layouts"):
        run_frontend(tmp_path, out, progress=False)
    config = tmp_path / "bad.toml"
    config.write_text("[vo]\nmax_featurez = 10\n")
    with pytest.raises(InputError, match=r"unknown key 'vo\.max_featurez'"):
        run_frontend(rendered_demo(), out, config, progress=False)
    config.write_text("[apriltags]\nsize = -1.0\n")
    with pytest.raises(InputError, match=r"apriltags\.size"):
        run_frontend(rendered_demo(), out, config, progress=False)
    assert list(tmp_path.glob("*.mcap*")) == []


@dataclasses.dataclass(frozen=True)
class BoxRecord:
    """What the object stage reports a box as: its class, score, image box, camera point."""

    class_id: int
    score: float
    bbox: tuple[float, float, float, float]
    point: np.ndarray
    covariance: np.ndarray
    landmark_id: int  # the test's own record of which car it is; the pipeline does not read it


class TrueBoxes:
    """An object stage that reports the rendered cars where they truly are, frame after frame."""

    def __init__(self, landmarks, body_poses, reported=("car",)):
        self.class_names = reported  # the first is every box's class
        self.landmarks = [lm for lm in landmarks if lm.kind == "box"]
        self.poses = iter(body_poses)

    def detect(self, left, right, intrinsics):
        pose = next(self.poses)
        camera_from_body0 = np.linalg.inv(pose @ BODY_FROM_CAMERA)
        records = []
        for landmark in self.landmarks:
            box = projected_box(box_corners(landmark), pose, intrinsics)
            if box is None or (box[2] - box[0]) * (box[3] - box[1]) < 100:
                continue
            point = camera_from_body0[:3, :3] @ landmark.position + camera_from_body0[:3, 3]
            covariance = np.diag([0.1, 0.1, 0.5])
            records.append(BoxRecord(0, 0.9, box, point, covariance, landmark.id))
        return records


def test_object_boxes_get_classes_after_the_tags_and_their_true_ids():
    sequence = KittiSequence(rendered_demo())
    landmarks = read_landmarks(sequence.root / "landmarks.json")
    body = camera_poses_to_body(sequence.gt_poses)
    frames = [0, 10, 20]
    config = load_frontend_config()
    stage = TrueBoxes(landmarks, body[frames])
    detections = run_objects(sequence, frames, stage, 2, landmarks, body, config, progress=False)
    seen = [d for per_frame in detections for d in per_frame]
    assert len(seen) >= 2
    stage = TrueBoxes(landmarks, body[frames])
    for per_frame in detections:
        expected = stage.detect(None, None, sequence.intrinsics)
        for detection, record in zip(per_frame, expected, strict=True):
            assert detection.source == "bbox"
            assert detection.class_id == 2  # after the two tag classes
            assert detection.truth_landmark_id == record.landmark_id  # by projection and IoU
            body_point = g.BODY_FROM_CAMERA_ROTATION @ record.point
            assert detection.range == pytest.approx(np.linalg.norm(body_point))
    metadata = class_metadata(config, stage, "test")
    assert metadata.class_names == ("tag_mod2_0", "tag_mod2_1", "car")
    np.testing.assert_allclose(metadata.confusion_matrix, np.eye(3))


def test_a_box_of_another_class_still_names_the_object_it_sees():
    # The truth is the object seen: a rendered car boxed as a truck is that car.
    sequence = KittiSequence(rendered_demo())
    landmarks = read_landmarks(sequence.root / "landmarks.json")
    body = camera_poses_to_body(sequence.gt_poses)
    frames = [0, 10, 20]
    stage = TrueBoxes(landmarks, body[frames], reported=("truck", "car"))
    detections = run_objects(
        sequence, frames, stage, 2, landmarks, body, load_frontend_config(), progress=False
    )
    stage = TrueBoxes(landmarks, body[frames])
    seen = 0
    for per_frame in detections:
        expected = stage.detect(None, None, sequence.intrinsics)
        for detection, record in zip(per_frame, expected, strict=True):
            assert detection.class_id == 2  # "truck", the stage's first class
            assert detection.truth_landmark_id == record.landmark_id
            seen += 1
    assert seen >= 2


# --- bad input, as the command line reports it -----------------------------------------------


def damage_size(root: Path) -> str:
    image = cv2.imread(str(root / "right" / "frame002.png"))
    cv2.imwrite(str(root / "right" / "frame002.png"), cv2.resize(image, (306, 92)))
    return r"frame 2 \(right/frame002\.png\) is 306x92, the sequence's images are 613x185"


def tiny_images(root: Path) -> str:
    for path in sorted(root.glob("*/*.png")):
        cv2.imwrite(str(path), cv2.resize(cv2.imread(str(path)), (24, 8)))
    (root / "calibration.toml").write_text(
        "[camera]\nfx = 14.0\nfy = 14.0\ncx = 12.0\ncy = 4.0\nbaseline = 0.5\n"
    )
    return r"visual odometry lost every frame \(too few corners \(\d\) in the first 24x8 left"


BAD_SEQUENCES = {
    "size changes": (plain_sequence, damage_size),
    "nan in the calibration": (
        lambda root: plain_sequence(root, fx="nan"),
        lambda root: r"calibration.toml: 'camera.fx' must be a number, got nan",
    ),
    "principal point outside": (
        lambda root: plain_sequence(root, cx=700.0),
        lambda root: r"principal point \(700, 91\.3052\) lies outside the 613x185 images",
    ),
    "missing right image": (
        plain_sequence,
        lambda root: (
            (root / "right" / "frame003.png").unlink()
            or r"left/frame003\.png has no image of the same name in right/"
        ),
    ),
    "swapped folders": (
        lambda root: plain_sequence(root, swapped=True),
        lambda root: r"lost every frame \(the left and right images look swapped\)",
    ),
    "tiny images": (plain_sequence, tiny_images),
}


@pytest.mark.e2e
@pytest.mark.parametrize("case", BAD_SEQUENCES)
def test_bad_sequences_exit_2_with_one_line_and_keep_the_earlier_log(tmp_path, capfd, case):
    make, damage = BAD_SEQUENCES[case]
    root = make(tmp_path / "seq")
    needle = damage(root)
    out = tmp_path / "out.mcap"
    out.write_bytes(b"an earlier log")
    capfd.readouterr()
    assert main(["frontend", str(root), "--out", str(out), "--quiet"]) == 2
    captured = capfd.readouterr()
    lines = captured.err.splitlines()
    assert len(lines) == 1, captured.err
    assert re.search(needle, lines[0]), lines[0]
    assert lines[0].startswith("mmslam frontend: error: ")
    assert out.read_bytes() == b"an earlier log"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.mcap", "seq"]


@pytest.mark.e2e
def test_decoder_warnings_stay_off_stderr(tmp_path, capfd):
    # Every PNG with a text chunk that fails its CRC: libpng warns for each on stderr, from C.
    root = plain_sequence(tmp_path / "seq", frames=3)
    for path in root.glob("*/*.png"):
        data = path.read_bytes()
        text = b"Comment\x00x"
        crc = (zlib.crc32(b"tEXt" + text) ^ 1) & 0xFFFFFFFF
        chunk = struct.pack(">I", len(text)) + b"tEXt" + text + struct.pack(">I", crc)
        path.write_bytes(data[:33] + chunk + data[33:])
    capfd.readouterr()
    assert main(["frontend", str(root), "--out", str(tmp_path / "out.mcap"), "--quiet"]) == 0
    assert "libpng" not in capfd.readouterr().err


@pytest.mark.e2e
def test_the_installed_command_says_one_line_when_every_frame_is_lost(tmp_path):
    # Logging reaches the real stderr here (in-process, pytest captures it): no warning per
    # lost frame may come before the error.
    root = plain_sequence(tmp_path / "seq", frames=4, swapped=True)
    command = Path(sys.executable).with_name("mmslam")
    done = subprocess.run(
        [str(command), "frontend", str(root), "--out", str(tmp_path / "out.mcap")],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 2
    assert done.stderr.count("\n") == 1 and "look swapped" in done.stderr, done.stderr


@pytest.mark.e2e
def test_verbose_frontend_says_its_summary_once(tmp_path):
    root = plain_sequence(tmp_path / "seq", frames=4)
    command = Path(sys.executable).with_name("mmslam")
    done = subprocess.run(
        [str(command), "frontend", str(root), "--out", str(tmp_path / "out.mcap"), "-v"],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr
    assert (done.stdout + done.stderr).count("poses from 4 frames") == 1


class RecordingStage:
    """An object stage that finds nothing and records the images it was given."""

    class_names = ("car",)

    def __init__(self):
        self.shapes = []

    def detect(self, left, right, intrinsics):
        self.shapes.append((left.shape, right.shape))
        return []


def test_colour_images_reach_the_object_stage(tmp_path):
    root = plain_sequence(tmp_path / "seq", frames=3)
    for path in root.glob("*/*.png"):
        grey = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        cv2.imwrite(str(path), cv2.merge([grey // 2, grey, grey]))  # channels that differ
    sequence = open_sequence(root)
    assert sequence.colour
    stage = RecordingStage()
    config = load_frontend_config()
    run_objects(sequence, [0, 2], stage, 2, None, None, config, progress=False)
    assert stage.shapes == [((185, 613, 3), (185, 613, 3))] * 2
    assert sequence[0][0].shape == (185, 613)  # odometry and tags get grey


def test_a_run_without_a_viewer_reads_no_image_again_to_show():
    """The front-end always hands its keyframes to a sink; with none given, the null sink, which
    wants no images, so none is read again."""
    from pipeline.frontend.run import Keyframes
    from pipeline.frontend.stereo_vo import KeyframeStep
    from pipeline.log import LogMetadata
    from pipeline.viz.frontend import show_keyframes
    from pipeline.viz.sink import NullSink

    class Unreadable:
        def __getitem__(self, frame: int):
            raise AssertionError(f"frame {frame} read again")

    step = KeyframeStep(3, np.eye(4), np.eye(6), 50, False)
    keyframes = Keyframes([0, 3], [step], 0)
    metadata = LogMetadata(1, ((1.0,),), ("tag",))
    show_keyframes(NullSink(), Unreadable(), keyframes, [0, 10, 20, 30], [], [[], []], metadata)
