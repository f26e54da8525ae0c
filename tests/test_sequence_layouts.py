"""ROS 2 bags and EuRoC folders into the front-end: the same frames give the same detection
log as in mmslam's plain layout; frames without a partner are reported, never mispaired; bad
input is one line and exit 2. And the pure parts: pairing by stamps, topic names,
rectification."""

from __future__ import annotations

import functools
import logging
import tempfile
from pathlib import Path

import cv2
import numpy as np
import pytest

from pipeline.cli import main
from pipeline.datasets.camera import StereoIntrinsics
from pipeline.datasets.euroc import EurocSequence
from pipeline.datasets.kitti import KittiSequence
from pipeline.datasets.layouts import open_sequence
from pipeline.datasets.pairing import pair_stamps
from pipeline.datasets.rectification import CameraModel, Rectification, stereo_rectification
from pipeline.datasets.rosbag import (
    RosbagSequence,
    camera_info_topic,
    decode_image,
    stereo_topic_pairs,
)
from pipeline.errors import InputError
from pipeline.frontend.run import run_frontend
from pipeline.log import read_log
from tests.sequences import (
    Frames,
    assert_same_log,
    write_bag,
    write_euroc,
    write_plain,
)

FRAMES = 14
TOLERANCE_S = 0.005
# Small stamps: seconds in times.txt hold them exactly, so the plain layout's log can be
# compared stamp for stamp.
FIRST_STAMP_NS = 1_000_000_000
FRAME_NS = 100_000_000

_scratch = tempfile.TemporaryDirectory(prefix="mmslam-layout-tests-")


@functools.cache
def frames() -> Frames:
    """The first frames of the renderer's demo drive (grey, rectified), rendered once."""
    from data_tools.render import render_sequence

    root = render_sequence("demo", Path(_scratch.name) / "render", seed=0, num_frames=FRAMES)
    sequence = KittiSequence(root)
    pairs = [sequence[k] for k in range(len(sequence))]
    stamps = [FIRST_STAMP_NS + k * FRAME_NS for k in range(len(sequence))]
    return Frames([p[0] for p in pairs], [p[1] for p in pairs], stamps, sequence.intrinsics)


@functools.cache
def plain_log(drop: int | None = None):
    """The log of the frames in the plain layout (without frame `drop`)."""
    chosen = frames() if drop is None else frames().without(drop)
    root = write_plain(Path(_scratch.name) / f"plain-{drop}", chosen)
    out = Path(_scratch.name) / f"plain-{drop}.mcap"
    run_frontend(root, out, progress=False)
    return read_log(out)


def frontend_log(sequence: Path, tmp_path: Path, *args: str):
    out = tmp_path / "log.mcap"
    assert main(["frontend", str(sequence), "--out", str(out), "-q", *args]) == 0
    return read_log(out)


# --- pairing by stamps, by hand --------------------------------------------------------------


def test_pairs_by_stamp_by_hand():
    same = pair_stamps([0, 100, 200], [0, 100, 200], 5)
    assert same.pairs == [(0, 0), (1, 1), (2, 2)]
    assert same.unmatched_left == same.unmatched_right == []
    # Right frame 2 (at 200) lost: left 2 has no partner within 5; left 3 pairs with right 2.
    lost = pair_stamps([0, 100, 200, 300], [1, 99, 302], 5)
    assert lost.pairs == [(0, 0), (1, 1), (3, 2)]
    assert lost.unmatched_left == [2] and lost.unmatched_right == []
    # A left frame lost, and a right one too far from any left one.
    assert pair_stamps([0, 200], [0, 100, 203], 5).pairs == [(0, 0), (1, 2)]
    assert pair_stamps([0, 200], [0, 100, 206], 5).unmatched_right == [1, 2]


def test_a_pair_is_each_others_nearest():
    # Two left frames near one right frame: only the nearer one gets it.
    pairing = pair_stamps([0, 4], [3], 5)
    assert pairing.pairs == [(1, 0)]
    assert pairing.unmatched_left == [0]
    with pytest.raises(ValueError, match="increase"):
        pair_stamps([0, 0], [0, 1], 5)


def test_stereo_topics_are_found_by_name():
    assert stereo_topic_pairs(["/cam/left/image_raw", "/cam/right/image_raw", "/imu"]) == [
        ("/cam/left/image_raw", "/cam/right/image_raw")
    ]
    assert stereo_topic_pairs(["/cam1/image_raw", "/cam0/image_raw"]) == [
        ("/cam0/image_raw", "/cam1/image_raw")
    ]
    assert stereo_topic_pairs(["/camera/infra1/image", "/camera/infra2/image"]) == [
        ("/camera/infra1/image", "/camera/infra2/image")
    ]
    assert stereo_topic_pairs(["/zed/Left/rect", "/zed/Right/rect"]) == [
        ("/zed/Left/rect", "/zed/Right/rect")
    ]
    # Names that differ otherwise are no pair; two pairs are two.
    assert stereo_topic_pairs(["/front/image", "/back/image"]) == []
    assert stereo_topic_pairs(["/cam0/image", "/cam1/depth"]) == []
    four = ["/a/left/raw", "/a/right/raw", "/a/left/rect", "/a/right/rect"]
    assert len(stereo_topic_pairs(four)) == 2


def test_camera_info_beside_its_image_topic():
    assert camera_info_topic("/cam/left/image_raw") == "/cam/left/camera_info"
    assert camera_info_topic("/cam/left/image_raw/compressed") == "/cam/left/camera_info"


def test_raw_images_decode_with_their_row_stride():
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    Image = ts.types["sensor_msgs/msg/Image"]
    Header = ts.types["std_msgs/msg/Header"]
    Time = ts.types["builtin_interfaces/msg/Time"]
    rgb = np.arange(2 * 3 * 3, dtype=np.uint8).reshape(2, 3, 3)
    padded = np.zeros((2, 12), np.uint8)  # rows of 12 bytes for 9 of pixels
    padded[:, :9] = rgb.reshape(2, 9)
    header = Header(stamp=Time(sec=0, nanosec=0), frame_id="")
    message = Image(header, 2, 3, "rgb8", 0, 12, padded.ravel())
    np.testing.assert_array_equal(decode_image(message, Image.__msgtype__, "x"), rgb[:, :, ::-1])
    message = Image(header, 2, 3, "16UC1", 0, 6, np.zeros(12, np.uint8))
    with pytest.raises(InputError, match="16UC1"):
        decode_image(message, Image.__msgtype__, "x")


# --- rectification ---------------------------------------------------------------------------


def raw_pair() -> tuple[CameraModel, CameraModel, np.ndarray]:
    """Two distorted cameras 0.11 m apart, the right one turned 2 degrees and a little off."""
    K_left = np.array([[458.7, 0, 367.2], [0, 457.3, 248.4], [0, 0, 1]])
    K_right = np.array([[457.6, 0, 379.9], [0, 456.1, 255.2], [0, 0, 1]])
    left = CameraModel(752, 480, K_left, np.array([-0.283, 0.074, 0.0002, 0.00002]))
    right = CameraModel(752, 480, K_right, np.array([-0.284, 0.074, -0.0001, -0.00004]))
    right_from_left = np.eye(4)
    right_from_left[:3, :3] = cv2.Rodrigues(np.radians([0.5, 2.0, 0.3]))[0]
    right_from_left[:3, 3] = [-0.110, 0.0004, -0.0009]
    return left, right, right_from_left


def rectified_pixels(
    rectification: Rectification, point_left: np.ndarray, right_from_left: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Where a point (left camera frame) lands in the two rectified images: projected with
    distortion into each raw image, then undistorted and rectified."""
    pixels = []
    for camera, R, P, pose in (
        (rectification.left, rectification.R_left, rectification.P_left, np.eye(4)),
        (rectification.right, rectification.R_right, rectification.P_right, right_from_left),
    ):
        rvec = cv2.Rodrigues(pose[:3, :3])[0]
        raw, _ = cv2.projectPoints(point_left[None], rvec, pose[:3, 3], camera.K, camera.distortion)
        pixels.append(cv2.undistortPoints(raw, camera.K, camera.distortion, R=R, P=P).ravel())
    return pixels[0], pixels[1]


def test_stereo_rectification_aligns_rows_and_gives_the_baseline():
    left, right, right_from_left = raw_pair()
    rectification = stereo_rectification(left, right, right_from_left)
    assert rectification.needed
    intrinsics = rectification.intrinsics("test")
    assert intrinsics.baseline == pytest.approx(np.linalg.norm(right_from_left[:3, 3]), rel=1e-9)
    for point in ([1.0, -0.5, 4.0], [-2.0, 1.0, 9.0], [0.3, 0.2, 2.5]):
        point = np.array(point)
        pixel_left, pixel_right = rectified_pixels(rectification, point, right_from_left)
        assert abs(pixel_left[1] - pixel_right[1]) < 1e-3  # rows aligned
        depth = (rectification.R_left @ point)[2]
        disparity = pixel_left[0] - pixel_right[0]
        assert disparity == pytest.approx(intrinsics.fx * intrinsics.baseline / depth, rel=1e-4)
    image = np.full((480, 752), 128, np.uint8)
    warped_left, warped_right = rectification.apply(image, image)
    assert warped_left.shape == image.shape and warped_right.shape == image.shape


def test_a_rectified_pair_is_left_as_it_is():
    k = np.array([[400.0, 0, 300.0], [0, 400.0, 90.0], [0, 0, 1]])
    camera = CameraModel(600, 180, k, np.zeros(4))
    right_from_left = np.eye(4)
    right_from_left[0, 3] = -0.3
    rectification = stereo_rectification(camera, camera, right_from_left)
    assert not rectification.needed
    intrinsics = rectification.intrinsics("test")
    assert (intrinsics.fx, intrinsics.cx, intrinsics.cy) == (400.0, 300.0, 90.0)
    assert intrinsics.baseline == pytest.approx(0.3, rel=1e-12)
    image = np.arange(600 * 180, dtype=np.uint32).astype(np.uint8).reshape(180, 600)
    assert rectification.apply(image, image)[0] is image


def test_projections_of_another_pair_are_refused():
    k = np.array([[400.0, 0, 300.0], [0, 400.0, 90.0], [0, 0, 1]])
    camera = CameraModel(600, 180, k, np.zeros(5))
    P_left = np.hstack([k, np.zeros((3, 1))])
    P_right = P_left.copy()
    P_right[0, 3] = 400.0 * 0.3  # the right camera to the left
    with pytest.raises(InputError, match="baseline"):
        Rectification(camera, camera, np.eye(3), np.eye(3), P_left, P_right).intrinsics("x")
    P_right[0, 3] = -400.0 * 0.3
    P_right[0, 2] = 310.0
    with pytest.raises(InputError, match="different pinholes"):
        Rectification(camera, camera, np.eye(3), np.eye(3), P_left, P_right).intrinsics("x")


# --- ROS 2 bags ------------------------------------------------------------------------------


@pytest.mark.e2e
@pytest.mark.parametrize(
    ("storage", "compressed"), [("mcap", False), ("sqlite3", True), ("mcap", True)]
)
def test_a_bag_gives_the_log_of_the_same_frames(tmp_path, storage, compressed):
    bag = write_bag(tmp_path / "bag", frames(), storage, compressed, right_offset_ns=1_000_000)
    sequence = open_sequence(bag)
    assert isinstance(sequence, RosbagSequence)
    assert sequence.topics == ("/stereo/left/image_raw", "/stereo/right/image_raw")
    assert sequence.unmatched_left == sequence.unmatched_right == 0
    assert_same_log(frontend_log(bag, tmp_path), plain_log())


@pytest.mark.e2e
def test_a_single_mcap_file_with_a_calibration_file(tmp_path):
    bag = write_bag(tmp_path / "bag", frames(), "mcap", camera_infos=False)
    (single,) = bag.glob("*.mcap")
    calibration = write_plain(tmp_path / "plain", frames()) / "calibration.toml"
    log = frontend_log(single, tmp_path, "--calibration", str(calibration))
    assert_same_log(log, plain_log())


@pytest.mark.e2e
def test_a_dropped_right_frame_is_reported_not_mispaired(tmp_path, caplog):
    dropped = 6
    bag = write_bag(tmp_path / "bag", frames(), "sqlite3", drop_right=[dropped])
    with caplog.at_level(logging.WARNING, logger="pipeline"):
        sequence = RosbagSequence(bag, TOLERANCE_S)
    assert (sequence.unmatched_left, sequence.unmatched_right) == (1, 0)
    assert len(sequence) == FRAMES - 1
    assert "1 frames of /stereo/left/image_raw and 0 of /stereo/right/image_raw" in caplog.text
    # Frame 7's left image goes with frame 7's right one, not 6's left with 7's right.
    np.testing.assert_array_equal(sequence[dropped][1], frames().right[dropped + 1])
    np.testing.assert_array_equal(sequence[dropped][0], frames().left[dropped + 1])
    summary = run_frontend(bag, tmp_path / "log.mcap", progress=False)
    assert summary.unpaired_frames == 1
    assert "1 frames without a stereo partner left out" in summary.summary_line()
    assert_same_log(read_log(tmp_path / "log.mcap"), plain_log(dropped))


def test_frames_are_read_again_in_any_order(tmp_path):
    bag = write_bag(tmp_path / "bag", frames(), "mcap", compressed=True)
    sequence = RosbagSequence(bag, TOLERANCE_S)
    for index in (3, 9, 2, 2, 13, 0):
        left, right = sequence[index]
        np.testing.assert_array_equal(left, frames().left[index])
        np.testing.assert_array_equal(right, frames().right[index])


def test_the_topics_given_are_the_ones_read(tmp_path):
    topics = ("/a/cam0/image", "/a/cam1/image")
    bag = write_bag(tmp_path / "bag", frames(), "mcap", topics=topics)
    sequence = RosbagSequence(bag, TOLERANCE_S, *topics)
    assert sequence.topics == topics
    np.testing.assert_array_equal(sequence[4][1], frames().right[4])
    # Swapped: the flags win over the names, and the cameras' projections refuse them (the
    # right camera would sit to the left).
    with pytest.raises(InputError, match="projection"):
        RosbagSequence(bag, TOLERANCE_S, topics[1], topics[0])


def test_raw_bag_images_are_rectified_with_their_camera_info(tmp_path):
    left, right, right_from_left = raw_pair()
    expected = stereo_rectification(left, right, right_from_left)
    infos = [
        (left.K, np.r_[left.distortion, 0.0], expected.R_left, expected.P_left),
        (right.K, np.r_[right.distortion, 0.0], expected.R_right, expected.P_right),
    ]
    grey = np.tile(np.arange(752, dtype=np.uint8), (480, 1))
    small = Frames([grey] * 3, [grey] * 3, [0, 10**8, 2 * 10**8], expected.intrinsics("x"))
    sequence = RosbagSequence(write_bag(tmp_path / "bag", small, "mcap", infos=infos), 0.005)
    assert sequence.rectification is not None
    assert sequence.intrinsics.baseline == pytest.approx(0.11, rel=1e-3)
    assert sequence.intrinsics.fx == pytest.approx(expected.P_left[0, 0], rel=1e-12)
    rectified_left, _ = expected.apply(grey, grey)
    np.testing.assert_array_equal(sequence[1][0], rectified_left)
    assert not np.array_equal(sequence[1][0], grey)
    # The same camera info beside topics named rectified: the images are taken as they are.
    topics = ("/stereo/left/image_rect", "/stereo/right/image_rect")
    bag = write_bag(tmp_path / "rect", small, "sqlite3", topics=topics, infos=infos)
    assert RosbagSequence(bag, 0.005).rectification is None


def test_a_bag_without_a_stereo_pair_names_its_topics(tmp_path, capsys):
    bag = write_bag(
        tmp_path / "bag", frames(), "mcap", topics=("/front/image", "/rear/image"),
        extra_topics=["/imu/status"],
    )  # fmt: skip
    out = tmp_path / "log.mcap"
    out.write_bytes(b"an earlier log")
    assert main(["frontend", str(bag), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    for topic in ("/front/image", "/rear/image", "/imu/status", "/front/camera_info"):
        assert topic in err
    assert "--left-topic" in err
    assert out.read_bytes() == b"an earlier log"


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--left-topic", "/stereo/left/image_raw"], "give both"),
        (["--left-topic", "/x", "--right-topic", "/stereo/right/image_raw"], "no topic /x"),
        (
            [
                "--left-topic",
                "/stereo/left/camera_info",
                "--right-topic",
                "/stereo/right/image_raw",
            ],
            "not an image topic",
        ),
        (["--calibration", "missing.toml"], "missing.toml"),
    ],
)
def test_bad_bag_options_are_one_line(tmp_path, capsys, args, needle):
    bag = write_bag(tmp_path / "bag", frames(), "mcap")
    assert main(["frontend", str(bag), "--out", str(tmp_path / "log.mcap"), *args]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and needle in err
    assert not (tmp_path / "log.mcap").exists()


def test_a_broken_bag_is_one_line(tmp_path, capsys):
    bag = write_bag(tmp_path / "bag", frames(), "mcap")
    (data,) = bag.glob("*.mcap")
    data.write_bytes(data.read_bytes()[: data.stat().st_size // 2])
    assert main(["frontend", str(bag), "--out", str(tmp_path / "log.mcap")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(bag) in err and "Traceback" not in err
    not_a_bag = tmp_path / "notes.db3"
    not_a_bag.write_text("not sqlite")
    assert main(["frontend", str(not_a_bag), "--out", str(tmp_path / "log.mcap")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "notes.db3" in err


# --- EuRoC -----------------------------------------------------------------------------------


@pytest.mark.e2e
def test_a_euroc_folder_gives_the_log_of_the_same_frames(tmp_path):
    root = write_euroc(tmp_path / "MH_test", frames())
    sequence = open_sequence(root)
    assert isinstance(sequence, EurocSequence)
    assert not sequence.rectification.needed
    assert_same_log(frontend_log(root, tmp_path), plain_log())


def test_euroc_stamps_stay_exact_and_a_lost_image_is_reported(tmp_path, caplog):
    first = 1_403_636_579_763_555_584  # EuRoC MH_01's first stamp: beyond a float's ns
    stamps = [first + k * 50_000_000 for k in range(FRAMES)]
    root = write_euroc(tmp_path / "euroc", frames(), stamps_ns=stamps)
    csv = root / "mav0" / "cam1" / "data.csv"
    lines = csv.read_text().splitlines()
    csv.write_text("\n".join(lines[:4] + lines[5:]) + "\n")  # cam1 loses frame 3
    with caplog.at_level(logging.WARNING, logger="pipeline"):
        sequence = EurocSequence(root, TOLERANCE_S)
    assert sequence.stamps_ns() == stamps[:3] + stamps[4:]
    assert (sequence.unmatched_left, sequence.unmatched_right) == (1, 0)
    assert "1 cam0 and 0 cam1 images have no partner" in caplog.text
    np.testing.assert_array_equal(sequence[3][1], frames().right[4])


def test_an_unrectified_euroc_pair_is_rectified(tmp_path):
    left, right, right_from_left = raw_pair()
    body_from_left = np.eye(4)
    body_from_right = body_from_left @ np.linalg.inv(right_from_left)
    small = Frames(
        [np.full((480, 752), 100, np.uint8)] * 2,
        [np.full((480, 752), 100, np.uint8)] * 2,
        [0, 50_000_000],
        StereoIntrinsics(752, 480, 458.7, 457.3, 367.2, 248.4, 0.11),
    )
    cameras = [
        (left.K, left.distortion, body_from_left),
        (right.K, right.distortion, body_from_right),
    ]
    sequence = EurocSequence(write_euroc(tmp_path / "raw", small, cameras), TOLERANCE_S)
    assert sequence.rectification.needed
    expected = stereo_rectification(left, right, right_from_left).intrinsics("test")
    assert sequence.intrinsics.baseline == pytest.approx(expected.baseline, rel=1e-6)
    assert sequence.intrinsics.fx == pytest.approx(expected.fx, rel=1e-6)
    assert sequence[0][0].shape == (480, 752)


@pytest.mark.parametrize(
    ("damage", "needle"),
    [
        (lambda root: (root / "mav0/cam1/sensor.yaml").write_text("intrinsics: [1, 2\n"), "YAML"),
        (
            lambda root: (root / "mav0/cam0/sensor.yaml").write_text(
                (root / "mav0/cam0/sensor.yaml").read_text().replace("radial-tangential", "fov")
            ),
            "distortion_model 'fov'",
        ),
        (
            lambda root: (root / "mav0/cam0/data.csv").write_text("#t\n12,a.png\n11,b.png\n"),
            "line 3",
        ),
        (lambda root: next((root / "mav0/cam1/data").glob("*.png")).unlink(), "missing image"),
    ],
)
def test_bad_euroc_input_is_one_line(tmp_path, capsys, damage, needle):
    root = write_euroc(tmp_path / "euroc", frames())
    damage(root)
    assert main(["frontend", str(root), "--out", str(tmp_path / "log.mcap")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and needle in err and "Traceback" not in err
    assert not (tmp_path / "log.mcap").exists()


def test_frontend_help_lists_every_layout(capsys):
    with pytest.raises(SystemExit):
        main(["frontend", "--help"])
    text = capsys.readouterr().out
    for layout in ("KITTI", "plain", "EuRoC", "ROS 2 bag"):
        assert layout in text
    assert text.count("    mmslam frontend ") >= 4
