"""Writers of the same stereo frames in several layouts, for the readers' tests: mmslam's plain
layout, ROS 2 bags (rosbags' own writer, MCAP or sqlite3 storage, raw or compressed images)
and EuRoC folders; and a comparison of two detection logs."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from pipeline.datasets.camera import StereoIntrinsics

FLOAT_TOLERANCE = 1e-9


@dataclasses.dataclass(frozen=True)
class Frames:
    """Rectified grey stereo pairs, their stamps (ns) and their camera."""

    left: list[np.ndarray]
    right: list[np.ndarray]
    stamps_ns: list[int]
    intrinsics: StereoIntrinsics

    def without(self, index: int) -> Frames:
        keep = [k for k in range(len(self.left)) if k != index]
        return Frames(
            [self.left[k] for k in keep],
            [self.right[k] for k in keep],
            [self.stamps_ns[k] for k in keep],
            self.intrinsics,
        )


def calibration_toml(k: StereoIntrinsics) -> str:
    return (
        f"[camera]\nfx = {float(k.fx)!r}\nfy = {float(k.fy)!r}\ncx = {float(k.cx)!r}\n"
        f"cy = {float(k.cy)!r}\n"
        f"baseline = {float(k.baseline)!r}\n"
    )


def write_plain(root: Path, frames: Frames) -> Path:
    """The plain layout, times.txt holding the stamps in seconds (exact for small stamps)."""
    for side, images in (("left", frames.left), ("right", frames.right)):
        (root / side).mkdir(parents=True)
        for k, image in enumerate(images):
            cv2.imwrite(str(root / side / f"{k:06d}.png"), image)
    (root / "calibration.toml").write_text(calibration_toml(frames.intrinsics))
    (root / "times.txt").write_text("".join(f"{s / 1e9!r}\n" for s in frames.stamps_ns))
    return root


def _typestore() -> Any:
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)


def _header(ts: Any, stamp_ns: int, frame_id: str) -> Any:
    Header = ts.types["std_msgs/msg/Header"]
    Time = ts.types["builtin_interfaces/msg/Time"]
    return Header(stamp=Time(sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9), frame_id=frame_id)


def image_message(ts: Any, image: np.ndarray, stamp_ns: int, compressed: bool) -> Any:
    header = _header(ts, stamp_ns, "camera")
    if compressed:
        ok, data = cv2.imencode(".png", image)
        assert ok
        CompressedImage = ts.types["sensor_msgs/msg/CompressedImage"]
        return CompressedImage(header=header, format="mono8; png compressed", data=data.ravel())
    Image = ts.types["sensor_msgs/msg/Image"]
    height, width = image.shape[:2]
    return Image(
        header=header,
        height=height,
        width=width,
        encoding="mono8",
        is_bigendian=0,
        step=width,
        data=np.ascontiguousarray(image).ravel(),
    )


def camera_info(
    ts: Any,
    header: Any,
    size: tuple[int, int],
    calibration: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    distortion_model: str = "plumb_bob",
) -> Any:
    """A CameraInfo of the typestore `ts` (ROS 1 or 2) for images of `size` (width, height):
    its `calibration` (K, D, R, P), no binning, no region of interest."""
    CameraInfo = ts.types["sensor_msgs/msg/CameraInfo"]
    RegionOfInterest = ts.types["sensor_msgs/msg/RegionOfInterest"]
    K, D, R, P = calibration
    matrices = {
        "d": np.asarray(D, float),
        "k": np.asarray(K, float).ravel(),
        "r": np.asarray(R, float).ravel(),
        "p": np.asarray(P, float).ravel(),
    }
    if "D" in CameraInfo.__dataclass_fields__:  # ROS 1 names them upper-case
        matrices = {name.upper(): matrix for name, matrix in matrices.items()}
    return CameraInfo(
        header=header,
        height=size[1],
        width=size[0],
        distortion_model=distortion_model,
        **matrices,
        binning_x=0,
        binning_y=0,
        roi=RegionOfInterest(0, 0, 0, 0, False),
    )


def side_calibration(
    frames: Frames,
    infos: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] | None,
    side: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One side's (K, D, R, P): the given `infos`, else the frames' rectified camera."""
    if infos is not None:
        return infos[side]
    k = frames.intrinsics
    return k.camera_matrix, np.zeros(5), np.eye(3), rectified_projections(k)[side]


def rectified_projections(k: StereoIntrinsics) -> tuple[np.ndarray, np.ndarray]:
    P_left = np.hstack([k.camera_matrix, np.zeros((3, 1))])
    P_right = P_left.copy()
    P_right[0, 3] = -k.fx * k.baseline
    return P_left, P_right


def write_bag(
    path: Path,
    frames: Frames,
    storage: str,
    compressed: bool = False,
    topics: tuple[str, str] = ("/stereo/left/image_raw", "/stereo/right/image_raw"),
    drop_right: Sequence[int] = (),
    right_offset_ns: int = 0,
    camera_infos: bool = True,
    extra_topics: Sequence[str] = (),
    infos: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] | None = None,
    distortion_model: str = "plumb_bob",
    header_stamps_ns: Sequence[int] | None = None,
) -> Path:
    """A ROS 2 bag of the frames: each side's images on its topic, a CameraInfo beside each
    (rectified: P's from the intrinsics), logged at their header stamps (or at the frames'
    stamps, with `header_stamps_ns` in the headers). `drop_right` frames have no right image;
    right stamps are `right_offset_ns` after the left ones. `infos`: each side's CameraInfo
    (K, D, R, P) instead, of `distortion_model`."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    ts = _typestore()
    image_type = "sensor_msgs/msg/CompressedImage" if compressed else "sensor_msgs/msg/Image"
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    k = frames.intrinsics
    size = (k.width, k.height)
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        images = [writer.add_connection(t, image_type, typestore=ts) for t in topics]
        info_connections = []
        if camera_infos:
            for topic in topics:
                namespace = topic.rsplit("/", 1)[0]
                info_connections.append(
                    writer.add_connection(
                        f"{namespace}/camera_info", "sensor_msgs/msg/CameraInfo", typestore=ts
                    )
                )
        others = [
            writer.add_connection(t, "std_msgs/msg/String", typestore=ts) for t in extra_topics
        ]
        String = ts.types["std_msgs/msg/String"]
        for index, stamp in enumerate(frames.stamps_ns):
            for side in (0, 1):
                if side == 1 and index in drop_right:
                    continue
                side_stamp = stamp + (right_offset_ns if side == 1 else 0)
                header_stamp = side_stamp if header_stamps_ns is None else header_stamps_ns[index]
                image = (frames.left, frames.right)[side][index]
                message = image_message(ts, image, header_stamp, compressed)
                writer.write(images[side], side_stamp, ts.serialize_cdr(message, image_type))
                if info_connections:
                    header = _header(ts, side_stamp, "camera")
                    calibration = side_calibration(frames, infos, side)
                    info = camera_info(ts, header, size, calibration, distortion_model)
                    data = ts.serialize_cdr(info, "sensor_msgs/msg/CameraInfo")
                    writer.write(info_connections[side], side_stamp, data)
            for connection in others:
                data = ts.serialize_cdr(String(data="x"), "std_msgs/msg/String")
                writer.write(connection, stamp, data)
    return path


def write_ros1_bag(
    path: Path,
    frames: Frames,
    infos: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] | None = None,
    topics: tuple[str, str] = ("/stereo/left/image_raw", "/stereo/right/image_raw"),
) -> Path:
    """A ROS 1 `.bag` of the frames (rosbags' ROS 1 writer, Noetic's message types: upper-case
    K, D, R, P in CameraInfo): mono8 images and a CameraInfo beside each, as `write_bag`."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    Header, Time = ts.types["std_msgs/msg/Header"], ts.types["builtin_interfaces/msg/Time"]
    Image, CameraInfo = ts.types["sensor_msgs/msg/Image"], ts.types["sensor_msgs/msg/CameraInfo"]
    k = frames.intrinsics
    size = (k.width, k.height)
    with Writer(path) as writer:
        images, cameras = [], []
        for topic in topics:
            images.append(writer.add_connection(topic, Image.__msgtype__, typestore=ts))
            info_topic = f"{topic.rsplit('/', 1)[0]}/camera_info"
            cameras.append(writer.add_connection(info_topic, CameraInfo.__msgtype__, typestore=ts))
        for index, stamp in enumerate(frames.stamps_ns):
            header = Header(
                seq=index, stamp=Time(sec=stamp // 10**9, nanosec=stamp % 10**9), frame_id="cam"
            )
            for side in (0, 1):
                image = (frames.left, frames.right)[side][index]
                height, width = image.shape[:2]
                message = Image(header, height, width, "mono8", 0, width, image.ravel())
                writer.write(images[side], stamp, ts.serialize_ros1(message, Image.__msgtype__))
                info = camera_info(ts, header, size, side_calibration(frames, infos, side))
                data = ts.serialize_ros1(info, CameraInfo.__msgtype__)
                writer.write(cameras[side], stamp, data)
    return path


def sensor_yaml(
    K: np.ndarray,
    distortion: np.ndarray,
    body_from_camera: np.ndarray,
    size: tuple[int, int],
    distortion_model: str = "radial-tangential",
) -> str:
    def numbers(values: np.ndarray) -> str:
        return "[" + ", ".join(repr(float(v)) for v in np.ravel(values)) + "]"

    return (
        "# General sensor definitions.\nsensor_type: camera\ncomment: test camera\n\n"
        f"T_BS:\n  cols: 4\n  rows: 4\n  data: {numbers(body_from_camera)}\n\n"
        f"rate_hz: 10\nresolution: [{size[0]}, {size[1]}]\ncamera_model: pinhole\n"
        f"intrinsics: {numbers([K[0, 0], K[1, 1], K[0, 2], K[1, 2]])} #fu, fv, cu, cv\n"
        f"distortion_model: {distortion_model}\n"
        f"distortion_coefficients: {numbers(distortion)}\n"
    )


def write_euroc(
    root: Path,
    frames: Frames,
    cameras: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None,
    stamps_ns: Sequence[int] | None = None,
    distortion_model: str = "radial-tangential",
) -> Path:
    """A EuRoC folder of the frames: `mav0/cam0` left, `mav0/cam1` right. `cameras`: each
    camera's (K, distortion, T_BS) of `distortion_model`; default a rectified pair (the right
    camera +baseline along the left one's x, the body frame an arbitrary rigid transform of
    the left camera's)."""
    k = frames.intrinsics
    stamps = list(stamps_ns if stamps_ns is not None else frames.stamps_ns)
    if cameras is None:
        body_from_left = np.eye(4)
        angle = 0.3
        body_from_left[:3, :3] = [
            [math.cos(angle), -math.sin(angle), 0.0],
            [math.sin(angle), math.cos(angle), 0.0],
            [0.0, 0.0, 1.0],
        ]
        body_from_left[:3, 3] = [0.1, -0.2, 0.05]
        left_from_right = np.eye(4)
        left_from_right[0, 3] = k.baseline
        cameras = [
            (k.camera_matrix, np.zeros(4), body_from_left),
            (k.camera_matrix, np.zeros(4), body_from_left @ left_from_right),
        ]
    for camera, images, (K, distortion, body_from_camera) in zip(
        ("cam0", "cam1"), (frames.left, frames.right), cameras, strict=True
    ):
        folder = root / "mav0" / camera
        (folder / "data").mkdir(parents=True)
        lines = ["#timestamp [ns],filename"]
        for stamp, image in zip(stamps, images, strict=True):
            cv2.imwrite(str(folder / "data" / f"{stamp}.png"), image)
            lines.append(f"{stamp},{stamp}.png")
        (folder / "data.csv").write_text("\n".join(lines) + "\n")
        (folder / "sensor.yaml").write_text(
            sensor_yaml(K, distortion, body_from_camera, (k.width, k.height), distortion_model)
        )
    return root


def assert_same(a: Any, b: Any, where: str = "log") -> None:
    """Equal structures, floats within FLOAT_TOLERANCE."""
    if dataclasses.is_dataclass(a) and not isinstance(a, type):
        assert type(a) is type(b), where
        for field in dataclasses.fields(a):
            assert_same(getattr(a, field.name), getattr(b, field.name), f"{where}.{field.name}")
    elif isinstance(a, list | tuple):
        assert isinstance(b, list | tuple) and len(a) == len(b), f"{where}: {len(a)} != {len(b)}"
        for k, (x, y) in enumerate(zip(a, b, strict=True)):
            assert_same(x, y, f"{where}[{k}]")
    elif isinstance(a, float) or isinstance(b, float):
        assert abs(a - b) <= FLOAT_TOLERANCE, f"{where}: {a!r} != {b!r}"
    else:
        assert a == b, f"{where}: {a!r} != {b!r}"


def assert_same_log(a: Any, b: Any) -> None:
    """Two detection logs hold the same calibration, odometry and detections (stamps equal,
    numbers within FLOAT_TOLERANCE) and the same classes."""
    assert a.num_poses == b.num_poses
    assert a.num_poses >= 3  # a log with motion in it, or the comparison says little
    assert_same(a.calibration, b.calibration, "calibration")
    assert_same(a.odometry, b.odometry, "odometry")
    assert_same(a.detections, b.detections, "detections")
    assert a.metadata.class_names == b.metadata.class_names
    assert_same(a.metadata.confusion_matrix, b.metadata.confusion_matrix, "confusion")
