"""The KITTI odometry layout: poses, times, calibration, the body frame, the sequence reader."""

from __future__ import annotations

import dataclasses
import shutil
import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from data_tools.data import KITTI05_DIR
from data_tools.scenarios.geometry import se3_exp
from pipeline.datasets.camera import BODY_FROM_CAMERA, StereoIntrinsics, check_intrinsics
from pipeline.datasets.kitti import (
    KittiSequence,
    body_poses_to_camera,
    camera_poses_to_body,
    read_calibration,
    read_poses,
    read_times,
    write_calibration,
    write_poses,
    write_times,
)
from pipeline.datasets.stereo import read_grey
from pipeline.errors import InputError

# calib.txt of KITTI odometry sequences 04-12, as KITTI ships it (P2, P3 and Tr left out).
KITTI_CALIB_05 = """\
P0: 7.070912000000e+02 0.000000000000e+00 6.018873000000e+02 0.000000000000e+00 \
0.000000000000e+00 7.070912000000e+02 1.831104000000e+02 0.000000000000e+00 \
0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 0.000000000000e+00
P1: 7.070912000000e+02 0.000000000000e+00 6.018873000000e+02 -3.798145000000e+02 \
0.000000000000e+00 7.070912000000e+02 1.831104000000e+02 0.000000000000e+00 \
0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 0.000000000000e+00
"""


def random_poses(n: int, seed: int, first_identity: bool = True) -> np.ndarray:
    rng = np.random.default_rng(seed)
    poses = se3_exp(rng.normal(0.0, [1, 1, 1, 20, 20, 20], (n, 6)))
    if first_identity:
        poses[0] = np.eye(4)
    return poses


def test_body_frame_axes_follow_rep_103():
    # The camera's axes in the body frame: x right, y down, z forward (its optical axis).
    right, down, forward = BODY_FROM_CAMERA[:3, :3].T
    np.testing.assert_array_equal(forward, [1, 0, 0])
    np.testing.assert_array_equal(right, [0, -1, 0])
    np.testing.assert_array_equal(down, [0, 0, -1])
    assert np.linalg.det(BODY_FROM_CAMERA[:3, :3]) == pytest.approx(1.0)


def test_camera_motion_becomes_body_motion():
    # The camera moves 2 m along its z (forward) and turns right (about its y, pointing down).
    angle = 0.3
    c, s = np.cos(angle), np.sin(angle)
    turn_right = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])  # rotation about camera y (down)
    camera = np.tile(np.eye(4), (2, 1, 1))
    camera[1, :3, :3] = turn_right
    camera[1, :3, 3] = [0.0, 0.0, 2.0]
    body = camera_poses_to_body(camera)
    np.testing.assert_allclose(body[1, :3, 3], [2.0, 0.0, 0.0], atol=1e-15)
    yaw = np.arctan2(body[1, 1, 0], body[1, 0, 0])
    assert yaw == pytest.approx(-angle)  # turning right is a negative yaw about z up


def test_pose_conversion_round_trips():
    camera = random_poses(50, seed=1)
    body = camera_poses_to_body(camera)
    np.testing.assert_allclose(body[0], np.eye(4), atol=1e-12)
    np.testing.assert_allclose(body_poses_to_camera(body), camera, atol=1e-12)
    np.testing.assert_allclose(camera_poses_to_body(body_poses_to_camera(body)), body, atol=1e-12)

    # Relative motions keep their size: the path length does not change.
    def length(p):
        return np.linalg.norm(np.diff(p[:, :3, 3], axis=0), axis=1).sum()

    assert length(body) == pytest.approx(length(camera))


def test_pose_conversion_expresses_poses_in_the_first_body_frame():
    camera = random_poses(20, seed=2, first_identity=False)
    body = camera_poses_to_body(camera)
    np.testing.assert_allclose(body[0], np.eye(4), atol=1e-12)
    # Motions between poses are the same rigid motions, seen in body axes.
    b = BODY_FROM_CAMERA
    for k in range(len(camera) - 1):
        camera_motion = np.linalg.inv(camera[k]) @ camera[k + 1]
        body_motion = np.linalg.inv(body[k]) @ body[k + 1]
        np.testing.assert_allclose(body_motion, b @ camera_motion @ np.linalg.inv(b), atol=1e-9)


def test_real_sequence_05_converts_to_a_level_body_path():
    camera = read_poses(KITTI05_DIR / "poses.txt")
    assert camera.shape == (2761, 4, 4)
    body = camera_poses_to_body(camera)
    np.testing.assert_allclose(body_poses_to_camera(body), camera, atol=1e-6)  # pose 0 ~ I
    # A car: z up stays near the world's up, and it drives forward (body x) from the start.
    assert np.all(body[:, 2, 2] > np.cos(0.15))
    assert body[20, 0, 3] > 5.0 and abs(body[20, 1, 3]) < 1.0
    # It keeps near the ground plane of its start: height varies far less than the extent.
    extent = np.ptp(body[:, :2, 3], axis=0).max()
    assert np.ptp(body[:, 2, 3]) < 0.1 * extent
    times = read_times(KITTI05_DIR / "times.txt")
    assert len(times) == 2761 and 9.0 < 1.0 / np.median(np.diff(times)) < 11.0


def test_poses_times_and_calibration_round_trip(tmp_path):
    poses = random_poses(30, seed=3)
    write_poses(tmp_path / "poses.txt", poses)
    np.testing.assert_allclose(read_poses(tmp_path / "poses.txt"), poses, rtol=1e-8, atol=1e-8)
    # KITTI-like stamps a few minutes in: microseconds must survive the text file.
    times = np.cumsum(np.random.default_rng(6).uniform(0.09, 0.11, 30)) + 280.0
    write_times(tmp_path / "times.txt", times)
    np.testing.assert_allclose(read_times(tmp_path / "times.txt"), times, rtol=0, atol=1e-6)
    intrinsics = StereoIntrinsics(1226, 370, 707.0912, 707.0912, 601.8873, 183.1104, 0.5372)
    write_calibration(tmp_path / "calib.txt", intrinsics)
    assert read_calibration(tmp_path / "calib.txt", 1226, 370) == pytest.approx(intrinsics)


def test_reads_kittis_own_calibration_text(tmp_path):
    (tmp_path / "calib.txt").write_text(KITTI_CALIB_05)
    k = read_calibration(tmp_path / "calib.txt", 1226, 370)
    assert (k.fx, k.fy, k.cx, k.cy) == (707.0912, 707.0912, 601.8873, 183.1104)
    assert k.baseline == pytest.approx(379.8145 / 707.0912)
    np.testing.assert_allclose(k.camera_matrix[:2, 2], [601.8873, 183.1104])


@pytest.mark.parametrize(
    ("name", "text"),
    [
        ("poses.txt", "1 0 0 0 0 1 0 0 0 0 1\n"),
        ("poses.txt", "1 0 0 0 0 1 0 0 0 0 1 nan\n"),
        ("times.txt", "0.0\n0.2\n0.1\n"),
        ("calib.txt", "P0: 1 2 3\n"),
    ],
)
def test_bad_files_are_input_errors(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    reader = {
        "poses.txt": read_poses,
        "times.txt": read_times,
        "calib.txt": lambda p: read_calibration(p, 10, 10),
    }[name]
    with pytest.raises(InputError, match=name):
        reader(path)


def make_sequence(root: Path, frames: int, with_poses: bool = True) -> Path:
    """A KITTI layout: dataset/sequences/05/{image_0,image_1,calib.txt,times.txt}, poses/05.txt."""
    sequence = root / "sequences" / "05"
    for side in ("image_0", "image_1"):
        (sequence / side).mkdir(parents=True)
        for k in range(frames):
            image = np.full((370, 1226), (k * 10 + (side == "image_1")) % 256, dtype=np.uint8)
            assert cv2.imwrite(str(sequence / side / f"{k:06d}.png"), image)
    (sequence / "calib.txt").write_text(KITTI_CALIB_05)
    write_times(sequence / "times.txt", np.arange(frames) * 0.1)
    if with_poses:
        (root / "poses").mkdir()
        write_poses(root / "poses" / "05.txt", random_poses(frames, seed=4))
    return sequence


def test_sequence_reader_gives_frames_intrinsics_and_ground_truth(tmp_path):
    sequence = KittiSequence(make_sequence(tmp_path, 4))
    assert len(sequence) == 4
    assert (sequence.intrinsics.width, sequence.intrinsics.height) == (1226, 370)
    assert sequence.intrinsics.baseline == pytest.approx(0.5372, abs=1e-4)
    left, right = sequence[2]
    assert left.shape == right.shape == (370, 1226)
    assert left[0, 0] == 20 and right[0, 0] == 21
    assert sequence.gt_poses is not None and sequence.gt_poses.shape == (4, 4, 4)
    np.testing.assert_allclose(sequence.times, np.arange(4) * 0.1)


def test_sequence_reader_without_ground_truth(tmp_path):
    sequence = KittiSequence(make_sequence(tmp_path, 3, with_poses=False))
    assert sequence.gt_poses is None


@pytest.mark.parametrize("broken", ["no-dir", "calib.txt", "image_1", "times", "poses"])
def test_sequence_reader_rejects_broken_layouts(tmp_path, broken):
    root = make_sequence(tmp_path, 3)
    if broken == "no-dir":
        root = tmp_path / "missing"
    elif broken == "calib.txt":
        (root / "calib.txt").unlink()
    elif broken == "image_1":
        (root / "image_1" / "000002.png").unlink()
    elif broken == "times":
        write_times(root / "times.txt", np.arange(5) * 0.1)
    else:
        write_poses(tmp_path / "poses" / "05.txt", random_poses(2, seed=5))
    with pytest.raises(InputError):
        KittiSequence(root)


# --- real-input faults -----------------------------------------------------------------------


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda t: t.replace("7.070912000000e+02", "nan", 1), r"calib\.txt: P0 holds a number"),
        (lambda t: t.replace("-3.798145000000e+02", "inf"), r"calib\.txt: P1 holds a number"),
        # KITTI's calibration on images of about half its size: cx = 602 lies outside 600 px.
        (lambda t: t, r"principal point \(601\.887, 183\.11\) lies outside the 600x180"),
    ],
)
def test_calibration_that_cannot_be_that_of_the_images_is_refused(tmp_path, change, message):
    path = tmp_path / "calib.txt"
    path.write_text(change(KITTI_CALIB_05))
    size = (600, 180) if "outside" in message else (1226, 370)
    with pytest.raises(InputError, match=message):
        read_calibration(path, *size)


def test_calibration_for_another_image_size_is_refused():
    # KITTI's calibration on images twice its size: cx = 602 is inside 2452 px, but a quarter
    # of the width from the centre.
    k = StereoIntrinsics(2452, 740, 707.0912, 707.0912, 601.8873, 183.1104, 0.5372)
    with pytest.raises(InputError, match="far from the centre of the 2452x740 images"):
        check_intrinsics(k, "calib.txt")
    check_intrinsics(dataclasses.replace(k, width=1226, height=370), "calib.txt")


def test_frames_are_paired_by_name(tmp_path):
    root = make_sequence(tmp_path, 4, with_poses=False)
    # One right image lost: pairing by position would put frames 3 and 2 together.
    (root / "image_1" / "000002.png").unlink()
    with pytest.raises(InputError, match=r"image_0/000002\.png has no image of the same name"):
        KittiSequence(root)
    # The same name with another suffix is the same frame.
    write_image(root / "image_1" / "000002.jpg", np.full((370, 1226), 21, np.uint8))
    sequence = KittiSequence(root)
    assert [p.stem for p in sequence.right_files] == ["000000", "000001", "000002", "000003"]
    assert sequence[2][1][0, 0] == pytest.approx(21, abs=2)


def test_an_image_of_another_size_mid_sequence_is_named(tmp_path):
    root = make_sequence(tmp_path, 4, with_poses=False)
    write_image(root / "image_1" / "000002.png", np.zeros((185, 613), np.uint8))
    sequence = KittiSequence(root)
    sequence[1]
    with pytest.raises(InputError, match=r"frame 2 \(image_1/000002\.png\) is 613x185, the "):
        sequence[2]


def test_the_colour_pair_is_read_in_colour(tmp_path):
    root = make_sequence(tmp_path, 3, with_poses=False)
    # KITTI's colour cameras: image_2, image_3 and P2, P3 (here with P0's numbers).
    calib = KITTI_CALIB_05 + KITTI_CALIB_05.replace("P0:", "P2:").replace("P1:", "P3:")
    (root / "calib.txt").write_text(calib)
    for side in ("image_2", "image_3"):
        (root / side).mkdir()
        for k in range(3):
            colour = np.zeros((370, 1226, 3), np.uint8)
            colour[..., 2] = 200  # red (BGR)
            write_image(root / side / f"{k:06d}.png", colour)
    grey = KittiSequence(root)
    assert not grey.colour and grey.images(0)[0].ndim == 2
    colour = KittiSequence(root, prefer_colour=True)
    assert colour.colour
    left, right = colour.images(1)
    assert left.shape == right.shape == (370, 1226, 3) and left[0, 0].tolist() == [0, 0, 200]
    assert colour[1][0].shape == (370, 1226)  # [] stays grey, for the other stages
    shutil.rmtree(root / "image_0")
    assert KittiSequence(root).colour  # the only pair there


def test_decoder_warnings_do_not_reach_stderr(tmp_path, capfd):
    # A PNG whose text chunk fails its CRC: libpng warns on stderr from C ("libpng warning:
    # tEXt: CRC error") and decodes the image.
    path = tmp_path / "frame.png"
    write_image(path, np.full((20, 30), 77, np.uint8))
    data = path.read_bytes()
    text = b"Comment\x00hello"
    chunk = struct.pack(">I", len(text)) + b"tEXt" + text
    chunk += struct.pack(">I", (zlib.crc32(b"tEXt" + text) ^ 1) & 0xFFFFFFFF)
    path.write_bytes(data[:33] + chunk + data[33:])  # after the 8-byte signature and IHDR
    capfd.readouterr()
    assert read_grey(path)[0, 0] == 77
    assert capfd.readouterr().err == ""


def write_image(path: Path, image: np.ndarray) -> None:
    assert cv2.imwrite(str(path), image)
