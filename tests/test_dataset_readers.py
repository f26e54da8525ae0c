"""The sequence readers where the layouts' own tests do not reach: distorted cameras of every
model (radial-tangential, equidistant as TUM-VI's, ROS's 8-coefficient rational polynomial)
rectified as the images show it, ROS 1 bags, header stamps that do not increase, every raw
encoding, EuRoC's variants; and pairing by stamps as a property against a brute-force
reference.

The rectification checks are independent of the code under test: a bright dot is drawn where
OpenCV's projection (with the camera's distortion) puts a known point in each raw image; after
the reader, the two dots must lie on one row, and the point triangulated from them with the
reader's intrinsics must lie at the point's distance from the left camera (a rotation of the
rectified frame keeps distances)."""

from __future__ import annotations

import dataclasses
import itertools
import logging
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from pipeline.cli import main
from pipeline.datasets.camera import StereoIntrinsics
from pipeline.datasets.euroc import EurocSequence, read_sensor_yaml
from pipeline.datasets.layouts import open_sequence
from pipeline.datasets.pairing import pair_stamps
from pipeline.datasets.rectification import CameraModel, Rectification
from pipeline.datasets.rosbag import (
    RosbagSequence,
    camera_model_from_info,
    decode_image,
    stereo_topic_pairs,
)
from pipeline.errors import InputError
from tests.sequences import (
    Frames,
    rectified_projections,
    write_bag,
    write_euroc,
    write_ros1_bag,
)

TOLERANCE_S = 0.005
BACKGROUND = 60  # grey of the scene around the dots: a black pixel is one that sees nothing
# Points in the left camera's frame (x right, y down, z forward), one per frame.
POINTS = np.array([[0.3, -0.2, 3.0], [-0.8, 0.4, 5.0], [0.1, 0.05, 2.0], [1.0, 0.5, 6.0]])
STAMPS = [10**9 + k * 10**8 for k in range(len(POINTS))]


@dataclasses.dataclass(frozen=True)
class RawPair:
    """Two calibrated, unrectified cameras and the pose between them."""

    model: str  # "radtan" or "equidistant"
    size: tuple[int, int]
    K: tuple[np.ndarray, np.ndarray]
    D: tuple[np.ndarray, np.ndarray]
    right_from_left: np.ndarray

    def project(self, point: np.ndarray, side: int) -> np.ndarray:
        """Where OpenCV's camera model puts `point` (left camera frame) in raw image `side`."""
        pose = np.eye(4) if side == 0 else self.right_from_left
        rvec = cv2.Rodrigues(pose[:3, :3])[0]
        tvec = np.ascontiguousarray(pose[:3, 3]).reshape(3, 1)
        K, D = self.K[side], self.D[side]
        if self.model == "equidistant":
            pixels, _ = cv2.fisheye.projectPoints(point.reshape(1, 1, 3), rvec, tvec, K, D)
        else:
            pixels, _ = cv2.projectPoints(point.reshape(1, 3), rvec, tvec, K, D)
        return pixels.ravel()

    def frames(self) -> Frames:
        """A frame per point: each raw image a grey scene with a dot where the point shows."""
        images = [[dot_image(self.project(p, side), self.size) for p in POINTS] for side in (0, 1)]
        fake = StereoIntrinsics(self.size[0], self.size[1], 1.0, 1.0, 0.0, 0.0, 1.0)
        return Frames(images[0], images[1], STAMPS, fake)

    def rectified_by_opencv(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """R and P of each camera as a calibration tool publishes them (ROS's CameraInfo)."""
        rotation = self.right_from_left[:3, :3]
        translation = np.ascontiguousarray(self.right_from_left[:3, 3]).reshape(3, 1)
        if self.model == "equidistant":
            R1, R2, P1, P2, _ = cv2.fisheye.stereoRectify(
                self.K[0], self.D[0], self.K[1], self.D[1], self.size, rotation, translation,
                flags=cv2.CALIB_ZERO_DISPARITY, balance=0.0,
            )  # fmt: skip
        else:
            R1, R2, P1, P2, *_ = cv2.stereoRectify(
                self.K[0], self.D[0], self.K[1], self.D[1], self.size, rotation, translation,
                flags=cv2.CALIB_ZERO_DISPARITY, alpha=0.0,
            )  # fmt: skip
        return R1, R2, P1, P2

    def infos(self) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
        R1, R2, P1, P2 = self.rectified_by_opencv()
        return [(self.K[0], self.D[0], R1, P1), (self.K[1], self.D[1], R2, P2)]

    def euroc_cameras(self) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Each camera's (K, D, T_BS), the body frame an arbitrary rigid pose of the left one."""
        body_from_left = np.eye(4)
        body_from_left[:3, :3] = cv2.Rodrigues(np.array([0.1, -0.4, 0.2]))[0]
        body_from_left[:3, 3] = [0.05, -0.1, 0.02]
        body_from_right = body_from_left @ np.linalg.inv(self.right_from_left)
        return [(self.K[0], self.D[0], body_from_left), (self.K[1], self.D[1], body_from_right)]


def right_from_left(rotation_deg: list[float], translation: list[float]) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = cv2.Rodrigues(np.radians(rotation_deg))[0]
    pose[:3, 3] = translation
    return pose


def radtan_pair() -> RawPair:
    """EuRoC MH_01's cameras (radial-tangential), the right one turned by 2 degrees."""
    K = (
        np.array([[458.7, 0, 367.2], [0, 457.3, 248.4], [0, 0, 1]]),
        np.array([[457.6, 0, 379.9], [0, 456.1, 255.2], [0, 0, 1]]),
    )
    D = (np.array([-0.283, 0.074, 0.0002, 0.00002]), np.array([-0.284, 0.074, -0.0001, -0.00004]))
    return RawPair(
        "radtan", (752, 480), K, D, right_from_left([0.5, 2.0, 0.3], [-0.11, 4e-4, -9e-4])
    )


def equidistant_pair() -> RawPair:
    """TUM-VI's fisheye cameras (equidistant, Kannala-Brandt k1..k4), 512 x 512."""
    K = (
        np.array([[190.98, 0, 254.93], [0, 190.97, 256.90], [0, 0, 1]]),
        np.array([[190.44, 0, 252.60], [0, 190.46, 254.94], [0, 0, 1]]),
    )
    D = (
        np.array([0.00348, 0.00072, -0.00205, 0.00020]),
        np.array([0.00340, 0.00078, -0.00206, 0.00020]),
    )
    return RawPair(
        "equidistant", (512, 512), K, D, right_from_left([-0.6, 0.9, 0.2], [-0.101, 0.002, 6e-4])
    )


def rational_pair() -> RawPair:
    """ROS's rational_polynomial: OpenCV's 8 coefficients k1 k2 p1 p2 k3 k4 k5 k6."""
    K = (
        np.array([[520.0, 0, 322.0], [0, 519.0, 238.0], [0, 0, 1]]),
        np.array([[521.0, 0, 318.0], [0, 520.0, 241.0], [0, 0, 1]]),
    )
    D = (
        np.array([0.45, -0.05, 3e-4, -2e-4, 0.002, 0.78, 0.02, 0.006]),
        np.array([0.44, -0.04, -1e-4, 1e-4, 0.001, 0.77, 0.03, 0.005]),
    )
    return RawPair(
        "radtan", (640, 480), K, D, right_from_left([0.3, -1.5, 0.4], [-0.12, 0.001, 0.0])
    )


def dot_image(pixel: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """A grey image with a Gaussian dot (sigma 2 px) centred at `pixel` (sub-pixel)."""
    v, u = np.indices((size[1], size[0]), dtype=float)
    dot = np.exp(-((u - pixel[0]) ** 2 + (v - pixel[1]) ** 2) / (2 * 2.0**2))
    return np.round(BACKGROUND + 180 * dot).astype(np.uint8)


def dot_centre(image: np.ndarray) -> np.ndarray:
    """The (u, v) centroid of the bright dot, the background left out."""
    weights = np.clip(image.astype(float) - BACKGROUND - 20, 0, None)
    assert weights.sum() > 0, "no dot in the image"
    v, u = np.indices(image.shape)
    return np.array([(u * weights).sum(), (v * weights).sum()]) / weights.sum()


def assert_rectified_as_seen(sequence, pair: RawPair) -> None:
    """Rows aligned, the triangulated points at their true distances, the baseline the
    cameras' distance, and no pixel of the rectified images outside the scene."""
    k = sequence.intrinsics
    assert k.baseline == pytest.approx(np.linalg.norm(pair.right_from_left[:3, 3]), rel=1e-6)
    assert (k.width, k.height) == pair.size
    for index, point in enumerate(POINTS):
        left, right = sequence[index]
        assert left.shape == right.shape == (pair.size[1], pair.size[0])
        (u_left, v_left), (u_right, v_right) = dot_centre(left), dot_centre(right)
        assert abs(v_left - v_right) < 0.25, f"frame {index}: rows {v_left:.2f} != {v_right:.2f}"
        depth = k.fx * k.baseline / (u_left - u_right)
        seen = [(u_left - k.cx) * depth / k.fx, (v_left - k.cy) * depth / k.fy, depth]
        assert np.linalg.norm(seen) == pytest.approx(np.linalg.norm(point), rel=0.01)
        # every rectified pixel sees the scene (alpha / balance 0): no black border
        for image in (left, right):
            assert np.mean(image < BACKGROUND // 2) < 0.002


# --- EuRoC / TUM-VI folders ------------------------------------------------------------------


@pytest.mark.parametrize(
    ("pair", "yaml_model"),
    [(radtan_pair(), "radial-tangential"), (equidistant_pair(), "equidistant")],
    ids=["radtan", "equidistant"],
)
def test_a_euroc_pair_is_rectified_as_its_images_show(tmp_path, pair, yaml_model):
    root = write_euroc(
        tmp_path / "raw", pair.frames(), pair.euroc_cameras(), distortion_model=yaml_model
    )
    sequence = EurocSequence(root, TOLERANCE_S)
    assert sequence.rectification.needed
    assert sequence.stamps_ns() == STAMPS
    assert_rectified_as_seen(sequence, pair)


def test_euroc_sensor_yaml_in_opencv_form_and_a_folder_without_mav0(tmp_path):
    pair = radtan_pair()
    root = write_euroc(tmp_path / "seq", pair.frames(), pair.euroc_cameras())
    for camera in ("cam0", "cam1"):  # OpenCV writes its YAML with a %YAML:1.0 first line
        path = root / "mav0" / camera / "sensor.yaml"
        path.write_text("%YAML:1.0\n" + path.read_text())
    (root / "mav0").rename(tmp_path / "cams")  # cam0/ and cam1/ right in the folder given
    sequence = open_sequence(tmp_path / "cams")
    assert isinstance(sequence, EurocSequence)
    assert_rectified_as_seen(sequence, pair)


def rectified_euroc(tmp_path: Path, k: StereoIntrinsics, images=None) -> Path:
    """A rectified EuRoC pair of `k`: cam1 at +baseline along cam0's x."""
    left_from_right = np.eye(4)
    left_from_right[0, 3] = k.baseline
    cameras = [
        (k.camera_matrix, np.zeros(4), np.eye(4)),
        (k.camera_matrix, np.zeros(4), left_from_right),
    ]
    images = images or [np.full((k.height, k.width), 90, np.uint8)] * 3
    frames = Frames(images, images, STAMPS[: len(images)], k)
    return write_euroc(tmp_path / "rect", frames, cameras)


def test_euroc_intrinsics_and_stamps_are_the_left_cameras(tmp_path):
    k = StereoIntrinsics(640, 400, 410.0, 395.0, 318.0, 203.0, 0.25)  # fx != fy, not square
    root = rectified_euroc(tmp_path, k)
    lines = (root / "mav0/cam1/data.csv").read_text().splitlines()
    shifted = [lines[0]] + [f"{int(s) + 2_000_000},{name}" for s, name in
                            (line.split(",") for line in lines[1:])]  # fmt: skip
    (root / "mav0/cam1/data.csv").write_text("\n".join(shifted) + "\n")
    sequence = EurocSequence(root, TOLERANCE_S)
    assert not sequence.rectification.needed
    got = sequence.intrinsics
    assert (got.width, got.height) == (640, 400)
    assert (got.fx, got.fy, got.cx, got.cy) == pytest.approx((410.0, 395.0, 318.0, 203.0))
    assert got.baseline == pytest.approx(0.25, rel=1e-9)
    assert sequence.stamps_ns() == STAMPS[:3]  # cam0's, not cam1's 2 ms later
    assert not sequence.colour
    colour = [np.dstack([np.full((400, 640), c, np.uint8) for c in (10, 120, 230)])] * 3
    assert EurocSequence(rectified_euroc(tmp_path / "c", k, colour), TOLERANCE_S).colour


@pytest.mark.parametrize(
    ("damage", "needle"),
    [
        (lambda text: text.replace("0.0, 0.0, 0.0, 1.0]", "0.0, 0.0, 0.5, 1.0]"), "rigid T_BS"),
        (lambda text: text.replace("resolution: [640, 400]", "resolution: [640.5, 400]"), "whole"),
        (lambda text: text.replace("camera_model: pinhole", "camera_model: omni"), "only pinhole"),
    ],
)
def test_a_bad_sensor_yaml_is_refused_naming_the_file(tmp_path, damage, needle):
    k = StereoIntrinsics(640, 400, 410.0, 395.0, 318.0, 203.0, 0.25)
    path = rectified_euroc(tmp_path, k) / "mav0/cam1/sensor.yaml"
    path.write_text(damage(path.read_text()))
    with pytest.raises(InputError, match=needle) as caught:
        read_sensor_yaml(path)
    assert str(path) in str(caught.value)


def test_repeated_euroc_stamps_are_refused_with_their_line(tmp_path):
    k = StereoIntrinsics(640, 400, 410.0, 395.0, 318.0, 203.0, 0.25)
    root = rectified_euroc(tmp_path, k)
    csv = root / "mav0/cam0/data.csv"
    lines = csv.read_text().splitlines()
    csv.write_text("\n".join([*lines[:3], lines[2]]) + "\n")  # line 4 repeats line 3
    with pytest.raises(InputError, match="line 4: timestamps must increase"):
        EurocSequence(root, TOLERANCE_S)


# --- ROS bags --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("pair", "ros_model"),
    [(equidistant_pair(), "equidistant"), (rational_pair(), "rational_polynomial")],
    ids=["equidistant", "rational_polynomial"],
)
def test_a_bag_of_raw_images_is_rectified_as_they_show(tmp_path, pair, ros_model):
    bag = write_bag(
        tmp_path / "bag", pair.frames(), "mcap", infos=pair.infos(), distortion_model=ros_model
    )
    sequence = RosbagSequence(bag, TOLERANCE_S)
    assert sequence.rectification is not None
    assert sequence.stamps_ns() == STAMPS
    assert_rectified_as_seen(sequence, pair)


def test_a_ros1_bag_is_read(tmp_path):
    """A ROS 1 `.bag` (rosbags' ROS 1 writer): header stamps, CameraInfo (its upper-case K, D,
    R, P) and images, raw ones rectified with it."""
    pair = radtan_pair()
    bag = write_ros1_bag(tmp_path / "raw.bag", pair.frames(), infos=pair.infos())
    sequence = open_sequence(bag)
    assert isinstance(sequence, RosbagSequence)
    assert sequence.topics == ("/stereo/left/image_raw", "/stereo/right/image_raw")
    assert sequence.stamps_ns() == STAMPS
    assert_rectified_as_seen(sequence, pair)
    # and one of rectified images: the frames as they are, the pinhole of its P
    k = StereoIntrinsics(752, 480, 450.0, 440.0, 370.0, 245.0, 0.11)
    frames = dataclasses.replace(pair.frames(), intrinsics=k)
    rectified = RosbagSequence(write_ros1_bag(tmp_path / "rect.bag", frames), TOLERANCE_S)
    assert rectified.rectification is None
    got = rectified.intrinsics
    assert (got.fx, got.fy, got.cx, got.cy, got.baseline) == pytest.approx(
        (450.0, 440.0, 370.0, 245.0, 0.11)
    )
    np.testing.assert_array_equal(rectified[2][1], frames.right[2])


def small_frames(count: int = 4, stamps: list[int] | None = None) -> Frames:
    k = StereoIntrinsics(64, 48, 50.0, 50.0, 32.0, 24.0, 0.1)
    rng = np.random.default_rng(5)
    images = [rng.integers(0, 256, (48, 64), dtype=np.uint8) for _ in range(count)]
    return Frames(images, images[::-1], stamps or STAMPS[:count], k)


@pytest.mark.parametrize(
    ("stamps", "position"),
    [([10**9, 2 * 10**9, 2 * 10**9], 2), ([10**9, 3 * 10**9, 2 * 10**9 + 5], 2)],
    ids=["repeated", "going-back"],
)
def test_header_stamps_that_do_not_increase_are_one_line(tmp_path, capsys, stamps, position):
    """Headers stamped out of order, the messages logged in order."""
    bag = write_bag(tmp_path / "bag", small_frames(3), "mcap", header_stamps_ns=stamps)
    out = tmp_path / "log.mcap"
    assert main(["frontend", str(bag), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert f"/stereo/left/image_raw message {position}: header stamp {stamps[position]} ns" in err
    assert "is not after the previous one" in err and not out.exists()


def test_header_stamps_keep_their_nanoseconds(tmp_path):
    stamps = [1_700_000_000_123_456_789 + k * 33_333_333 for k in range(3)]
    sequence = RosbagSequence(
        write_bag(tmp_path / "bag", small_frames(3, stamps), "sqlite3"), 0.001
    )
    assert sequence.stamps_ns() == stamps


def test_a_frame_of_another_size_is_refused_naming_it(tmp_path):
    frames = small_frames()
    frames.left[2] = np.zeros((40, 64), np.uint8)
    sequence = RosbagSequence(write_bag(tmp_path / "bag", frames, "mcap"), TOLERANCE_S)
    np.testing.assert_array_equal(sequence[1][0], frames.left[1])
    with pytest.raises(InputError, match="frame 2 of /stereo/left/image_raw is 64x40"):
        sequence.images(2)


def test_an_empty_rectifying_rotation_is_the_identity(tmp_path):
    """Some drivers leave CameraInfo's R all zeros: no rotation, the images as they are."""
    frames = small_frames()
    k = frames.intrinsics
    P_left, P_right = rectified_projections(k)
    infos = [(k.camera_matrix, np.zeros(5), np.zeros((3, 3)), P) for P in (P_left, P_right)]
    sequence = RosbagSequence(write_bag(tmp_path / "bag", frames, "mcap", infos=infos), 0.005)
    assert sequence.rectification is None
    np.testing.assert_array_equal(sequence[3][0], frames.left[3])


def test_one_topic_named_rect_does_not_make_the_pair_rectified(tmp_path):
    pair = radtan_pair()
    topics = ("/stereo/left/image_rect", "/stereo/right/image_raw")
    bag = write_bag(tmp_path / "bag", pair.frames(), "mcap", topics=topics, infos=pair.infos())
    sequence = RosbagSequence(bag, TOLERANCE_S, *topics)
    assert sequence.rectification is not None
    assert_rectified_as_seen(sequence, pair)


def test_equidistant_camera_info_needs_four_coefficients():
    projection = np.hstack([np.eye(3), np.zeros((3, 1))]).ravel()
    info = SimpleNamespace(
        distortion_model="equidistant", width=64, height=48, d=[0.01, 0.002, 0.0],
        k=np.eye(3).ravel(), r=np.eye(3).ravel(), p=projection,
    )  # fmt: skip
    with pytest.raises(InputError, match="4 coefficients"):
        camera_model_from_info(info, "cam")
    info.distortion_model = "fov"
    with pytest.raises(InputError, match="'fov' is not one of"):
        camera_model_from_info(info, "cam")


def test_only_neighbouring_digits_make_a_pair_of_topics():
    assert stereo_topic_pairs(["/cam0/image", "/cam2/image"]) == []
    assert stereo_topic_pairs(["/cam1/image", "/cam2/image"]) == [("/cam1/image", "/cam2/image")]


# Each raw encoding: the bytes of a 2 x 3 image with known pixels, and the BGR (or grey) image
# they must give, by hand: channel c of pixel (r, col) is PIXELS[r, col, c].
PIXELS = np.arange(2 * 3 * 4, dtype=np.uint8).reshape(2, 3, 4) * 7


@pytest.mark.parametrize(
    ("encoding", "channels", "bgr_order"),
    [
        ("mono8", 1, [0]),
        ("8UC1", 1, [0]),
        ("bgr8", 3, [0, 1, 2]),
        ("8UC3", 3, [0, 1, 2]),  # OpenCV's own: taken as BGR, as cv_bridge does
        ("rgb8", 3, [2, 1, 0]),
        ("bgra8", 4, [0, 1, 2]),
        ("rgba8", 4, [2, 1, 0]),
    ],
)
def test_every_raw_encoding_decodes_to_bgr(encoding, channels, bgr_order):
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    Image = ts.types["sensor_msgs/msg/Image"]
    header = ts.types["std_msgs/msg/Header"](
        stamp=ts.types["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id=""
    )
    stored = PIXELS[:, :, :channels]
    step = 3 * channels + 2  # rows padded by 2 bytes
    data = np.zeros((2, step), np.uint8)
    data[:, : 3 * channels] = stored.reshape(2, -1)
    message = Image(header, 2, 3, encoding, 0, step, data.ravel())
    decoded = decode_image(message, Image.__msgtype__, "x")
    expected = PIXELS[:, :, bgr_order]
    np.testing.assert_array_equal(decoded, expected[:, :, 0] if channels == 1 else expected)


def test_a_rectified_pair_keeps_fy_and_its_baseline_over_fx():
    k = np.array([[400.0, 0, 300.0], [0, 380.0, 90.0], [0, 0, 1]])
    camera = CameraModel(600, 180, k, np.zeros(5))
    P_left = np.hstack([k, np.zeros((3, 1))])
    P_right = P_left.copy()
    P_right[0, 3] = -400.0 * 0.3
    rectification = Rectification(camera, camera, np.eye(3), np.eye(3), P_left, P_right)
    assert not rectification.needed
    got = rectification.intrinsics("x")
    assert (got.fx, got.fy, got.baseline) == pytest.approx((400.0, 380.0, 0.3))
    P_right[1, 3] = 2.0  # the right camera off the left one's x axis
    with pytest.raises(InputError, match="offset along x only"):
        Rectification(camera, camera, np.eye(3), np.eye(3), P_left, P_right).intrinsics("x")
    # a pinhole 0.05 px off what the cameras were calibrated with needs warping
    moved = P_left.copy()
    moved[0, 2] += 0.05
    assert Rectification(camera, camera, np.eye(3), np.eye(3), moved, P_right).needed


# --- pairing by stamps, as a property --------------------------------------------------------


def nearest(stamps: list[int], stamp: int) -> int | None:
    """The index of the nearest stamp, the earlier on a tie (brute force)."""
    if not stamps:
        return None
    return min(range(len(stamps)), key=lambda k: (abs(stamps[k] - stamp), k))


increasing = st.lists(st.integers(0, 60), max_size=12, unique=True).map(sorted)


@given(increasing, increasing, st.integers(0, 8))
def test_pairs_are_each_others_nearest_within_the_tolerance(left, right, tolerance):
    pairing = pair_stamps(left, right, tolerance)
    expected = [
        (i, j)
        for i, stamp in enumerate(left)
        if (j := nearest(right, stamp)) is not None
        and abs(right[j] - stamp) <= tolerance
        and nearest(left, right[j]) == i
    ]
    assert pairing.pairs == expected
    assert pairing.unmatched_left == sorted(set(range(len(left))) - {i for i, _ in expected})
    assert pairing.unmatched_right == sorted(set(range(len(right))) - {j for _, j in expected})


@given(st.lists(st.integers(0, 20), min_size=2, max_size=8), increasing)
def test_stamps_that_do_not_increase_strictly_are_refused(stamps, other):
    if all(b > a for a, b in itertools.pairwise(stamps)):
        return
    with pytest.raises(ValueError, match="left stamps must increase strictly"):
        pair_stamps(stamps, other, 5)
    with pytest.raises(ValueError, match="right stamps must increase strictly"):
        pair_stamps(other, stamps, 5)


def test_no_log_warning_for_a_complete_pairing(tmp_path, caplog):
    with caplog.at_level(logging.WARNING, logger="pipeline"):
        RosbagSequence(write_bag(tmp_path / "bag", small_frames(), "mcap"), TOLERANCE_S)
    assert "no partner" not in caplog.text
