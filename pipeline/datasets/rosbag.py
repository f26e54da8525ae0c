"""ROS 2 bags (MCAP or sqlite3 storage; a bag folder with metadata.yaml, or one .mcap or .db3
file), read with the `rosbags` library. ROS 1 `.bag` files go through the same reader.

    mmslam frontend BAG --out LOG.mcap [--left-topic T --right-topic T] [--calibration F]

The stereo pair: two topics of `sensor_msgs/Image` or `sensor_msgs/CompressedImage`, named with
`--left-topic` and `--right-topic`, or found when exactly one pair of image topics differs only
by `left` -> `right` in one part of the name (`/cam/left/image_raw`, `/cam/right/image_raw`) or
by a digit and the next (`/cam0/image_raw`, `/cam1/image_raw`; `/camera/infra1/...`,
`/camera/infra2/...`). Frames are paired by their header stamps, each the other's nearest
within `[input] stereo_stamp_tolerance`; a frame without such a partner is left out, logged and
counted, never paired with a neighbour's. A frame's time is its left header stamp.

Calibration, from `--calibration FILE` (the plain layout's calibration.toml: the images are then
taken as rectified), or from the `sensor_msgs/CameraInfo` beside each image topic
(`/cam/left/camera_info` for `/cam/left/image_raw` or `/cam/left/image_raw/compressed`; the first
message of each): the pinhole is the left P's, the baseline `-P_right[0, 3] / P_right[0, 0]`.
A topic whose name holds `rect` is taken as rectified already (ROS publishes the raw camera's
K and D beside rectified images too). Other images are rectified with the CameraInfo's K, D, R
and P (as ROS's image_proc does) unless D is zero, R the identity and K the pinhole of P.
Distortion models: plumb_bob, rational_polynomial, equidistant.

Image encodings: mono8, bgr8, rgb8, bgra8, rgba8; compressed: whatever OpenCV decodes (JPEG,
PNG). Frames are read in passes through the bag, one stage after another, never all held.
"""

from __future__ import annotations

import functools
import logging
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.datasets.camera import StereoIntrinsics
from pipeline.datasets.pairing import pair_stamps
from pipeline.datasets.plain import intrinsics_for_images, read_plain_calibration
from pipeline.datasets.rectification import CameraModel, Rectification
from pipeline.datasets.stereo import StereoSequence
from pipeline.errors import InputError

log = logging.getLogger(__name__)

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
IMAGE_TYPES = (IMAGE, COMPRESSED_IMAGE)
BAG_SUFFIXES = (".mcap", ".db3", ".bag")
DISTORTION_MODELS = {
    "plumb_bob": "radtan",
    "rational_polynomial": "radtan",
    "equidistant": "equidistant",
}
LEFT, RIGHT = 0, 1


def is_bag(path: Path) -> bool:
    """A ROS 2 bag folder (metadata.yaml), or a single bag file."""
    if path.is_dir():
        return (path / "metadata.yaml").exists()
    return path.suffix in BAG_SUFFIXES


@functools.cache
def _encodings() -> dict[str, tuple[int, int | None]]:
    """The raw encodings read: channels, and OpenCV's conversion to BGR (None: as it is)."""
    import cv2

    return {
        "mono8": (1, None),
        "8UC1": (1, None),
        "bgr8": (3, None),
        "8UC3": (3, None),
        "rgb8": (3, cv2.COLOR_RGB2BGR),
        "bgra8": (4, cv2.COLOR_BGRA2BGR),
        "rgba8": (4, cv2.COLOR_RGBA2BGR),
    }


def _left_to_right(a: str, b: str) -> bool:
    """Whether one part of a topic name, `a`, and the same part of another, `b`, say left and
    right: `left` -> `right` (any case), or a digit -> the next digit."""
    if "left" in a.lower() and a.lower().replace("left", "right") == b.lower():
        return True
    if len(a) != len(b):
        return False
    differ = [k for k, (x, y) in enumerate(zip(a, b, strict=True)) if x != y]
    if len(differ) != 1:
        return False
    x, y = a[differ[0]], b[differ[0]]
    return x.isdigit() and y.isdigit() and int(y) == int(x) + 1


def stereo_topic_pairs(image_topics: list[str]) -> list[tuple[str, str]]:
    """Every (left, right) pair of topics whose names differ in one part only, and there as
    left and right (`_left_to_right`)."""
    pairs = []
    for a in image_topics:
        for b in image_topics:
            parts_a, parts_b = a.split("/"), b.split("/")
            if len(parts_a) != len(parts_b):
                continue
            differing = [(x, y) for x, y in zip(parts_a, parts_b, strict=True) if x != y]
            if len(differing) == 1 and _left_to_right(*differing[0]):
                pairs.append((a, b))
    return sorted(pairs)


def camera_info_topic(image_topic: str) -> str:
    """The CameraInfo topic beside an image topic: its namespace's `camera_info`."""
    base = re.sub(r"/compressed$", "", image_topic)
    namespace = base.rsplit("/", 1)[0]
    return f"{namespace}/camera_info"


@dataclass(frozen=True)
class _Side:
    topic: str
    msgtype: str
    stamps_ns: list[int]  # header stamps, in the bag's order


def _open_reader(path: Path) -> Any:
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    # The typestore only serves bags that hold no message definitions (older sqlite3 bags).
    reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
    try:
        reader.open()
    except Exception as exc:  # rosbags raises its own errors, OSError, and parser errors
        raise InputError(f"bag {path}: cannot read ({_reason(exc)})") from None
    return reader


def _reason(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0]}" if text else type(exc).__name__


def _stamp_ns(message: Any) -> int:
    return int(message.header.stamp.sec) * 1_000_000_000 + int(message.header.stamp.nanosec)


def decode_image(message: Any, msgtype: str, where: str) -> np.ndarray:
    """An Image or CompressedImage message as an 8-bit grey or BGR image."""
    import cv2

    if msgtype == COMPRESSED_IMAGE:
        data = np.frombuffer(bytes(message.data), np.uint8)
        image = cv2.imdecode(data, cv2.IMREAD_ANYCOLOR) if data.size else None
        if image is None or image.dtype != np.uint8:
            raise InputError(f"{where}: cannot decode the {message.format!r} image")
        return image
    encodings = _encodings()
    if message.encoding not in encodings:
        raise InputError(
            f"{where}: encoding {message.encoding!r} is not one of {', '.join(encodings)}"
        )
    channels, conversion = encodings[message.encoding]
    height, width, step = int(message.height), int(message.width), int(message.step)
    data = np.asarray(message.data, dtype=np.uint8).ravel()
    if height < 1 or width < 1 or step < width * channels or data.size < height * step:
        raise InputError(
            f"{where}: {data.size} bytes for a {width}x{height} {message.encoding} image with "
            f"rows of {step} bytes"
        )
    rows = data[: height * step].reshape(height, step)[:, : width * channels]
    image = rows.reshape(height, width, channels) if channels > 1 else rows.copy()
    if conversion is not None:
        image = cv2.cvtColor(image, conversion)
    return np.ascontiguousarray(image)


def _info_field(message: Any, name: str) -> Any:
    """A CameraInfo matrix: ROS 2 names them k, d, r, p; ROS 1 K, D, R, P."""
    value = getattr(message, name, None)
    return getattr(message, name.upper()) if value is None else value


def camera_model_from_info(message: Any, where: str) -> tuple[CameraModel, np.ndarray, np.ndarray]:
    """A CameraInfo's camera (K, D, its model), rectifying rotation R and projection P."""
    model = DISTORTION_MODELS.get(message.distortion_model or "plumb_bob")
    if model is None:
        raise InputError(
            f"{where}: distortion model {message.distortion_model!r} is not one of "
            f"{', '.join(DISTORTION_MODELS)}"
        )
    K = np.asarray(_info_field(message, "k"), float).reshape(3, 3)
    R = np.asarray(_info_field(message, "r"), float).reshape(3, 3)
    P = np.asarray(_info_field(message, "p"), float).reshape(3, 4)
    D = np.asarray(_info_field(message, "d"), float).ravel()
    if not all(np.all(np.isfinite(m)) for m in (K, R, P, D)):
        raise InputError(f"{where}: K, D, R or P holds a number that is not finite")
    if not np.any(R):  # left empty by some drivers: no rectifying rotation
        R = np.eye(3)
    if np.any(D) and model == "equidistant" and D.size < 4:
        raise InputError(f"{where}: equidistant distortion needs 4 coefficients")
    camera = CameraModel(int(message.width), int(message.height), K, D, model)
    return camera, R, P


class RosbagSequence(StereoSequence):
    """A stereo pair of image topics of a ROS bag (see the module's description).
    `unmatched_left` and `unmatched_right` count the frames left without a partner."""

    def __init__(
        self,
        path: str | Path,
        stereo_tolerance_s: float,
        left_topic: str | None = None,
        right_topic: str | None = None,
        calibration: str | Path | None = None,
    ):
        self.root = Path(path)
        if not self.root.exists():
            raise InputError(f"bag {self.root}: no such file or directory")
        reader = _open_reader(self.root)
        try:
            topics = {topic: info.msgtype for topic, info in reader.topics.items()}
            left, right = self._choose_topics(topics, left_topic, right_topic)
            self.topics = (left, right)
            sides = [self._scan(reader, topic, topics[topic]) for topic in (left, right)]
            infos = None if calibration is not None else self._camera_infos(reader, topics)
        finally:
            reader.close()
        self._sides = sides
        pairing = pair_stamps(
            sides[LEFT].stamps_ns, sides[RIGHT].stamps_ns, round(stereo_tolerance_s * 1e9)
        )
        self.unmatched_left = len(pairing.unmatched_left)
        self.unmatched_right = len(pairing.unmatched_right)
        if self.unmatched_left or self.unmatched_right:
            first = min(
                [sides[LEFT].stamps_ns[i] for i in pairing.unmatched_left]
                + [sides[RIGHT].stamps_ns[j] for j in pairing.unmatched_right]
            )
            log.warning(
                "bag %s: %d frames of %s and %d of %s have no partner within %g s: left out "
                "(the first at %d ns)",
                self.root,
                self.unmatched_left,
                left,
                self.unmatched_right,
                right,
                stereo_tolerance_s,
                first,
            )
        if not pairing.pairs:
            raise InputError(
                f"bag {self.root}: no frame of {left} has one of {right} within "
                f"{stereo_tolerance_s:g} s"
            )
        self._pairs = pairing.pairs
        self.exact_stamps_ns = [sides[LEFT].stamps_ns[i] for i, _ in self._pairs]
        self.times = np.array(self.exact_stamps_ns, dtype=np.int64) / 1e9
        self.left_files, self.right_files = [], []  # frames live in the bag
        self._cursor: _PairCursor | None = None
        self._last: tuple[int, tuple[np.ndarray, np.ndarray]] | None = None
        self.rectification: Rectification | None = None
        first_left, _ = self._raw_images(0)
        height, width = first_left.shape[:2]
        self.colour = first_left.ndim == 3
        if calibration is not None:
            self.intrinsics = self._file_intrinsics(Path(calibration), width, height)
        else:
            assert infos is not None
            self.intrinsics = self._info_intrinsics(infos, width, height)
        self.gt_poses = None

    # --- the topics ----------------------------------------------------------------------

    def _choose_topics(
        self, topics: dict[str, str | None], left: str | None, right: str | None
    ) -> tuple[str, str]:
        images = sorted(t for t, kind in topics.items() if kind in IMAGE_TYPES)
        listed = ", ".join(f"{t} ({kind})" for t, kind in sorted(topics.items())) or "none"
        if (left is None) != (right is None):
            raise InputError("give both --left-topic and --right-topic, or neither")
        if left is not None and right is not None:
            for flag, topic in (("--left-topic", left), ("--right-topic", right)):
                if topic not in topics:
                    raise InputError(f"bag {self.root}: no topic {topic} ({flag}); it has {listed}")
                if topics[topic] not in IMAGE_TYPES:
                    raise InputError(
                        f"bag {self.root}: {topic} ({flag}) is {topics[topic]}, not an image topic"
                    )
            if left == right:
                raise InputError("--left-topic and --right-topic name the same topic")
            return left, right
        pairs = stereo_topic_pairs(images)
        if len(pairs) == 1:
            log.info("bag %s: stereo pair %s, %s", self.root, *pairs[0])
            return pairs[0]
        if not pairs:
            raise InputError(
                f"bag {self.root}: no stereo pair of image topics found; its topics: {listed}"
                + (
                    "; name the pair with --left-topic and --right-topic"
                    if len(images) >= 2
                    else ""
                )
            )
        shown = "; ".join(f"{a} + {b}" for a, b in pairs)
        raise InputError(
            f"bag {self.root}: {len(pairs)} possible stereo pairs ({shown}): choose one with "
            "--left-topic and --right-topic"
        )

    def _scan(self, reader: Any, topic: str, msgtype: str | None) -> _Side:
        """The header stamps of a topic's messages, strictly increasing."""
        assert msgtype is not None
        connections = [c for c in reader.connections if c.topic == topic]
        stamps: list[int] = []
        for position, (_, _, raw) in enumerate(reader.messages(connections=connections)):
            where = f"bag {self.root}: {topic} message {position}"
            try:
                stamp = _stamp_ns(reader.deserialize(raw, msgtype))
            except Exception as exc:  # a message rosbags cannot decode
                raise InputError(f"{where}: cannot decode ({_reason(exc)})") from None
            if stamps and stamp <= stamps[-1]:
                raise InputError(
                    f"{where}: header stamp {stamp} ns is not after the previous one "
                    f"({stamps[-1]} ns)"
                )
            stamps.append(stamp)
        if not stamps:
            raise InputError(f"bag {self.root}: {topic} holds no messages")
        return _Side(topic, msgtype, stamps)

    # --- calibration ---------------------------------------------------------------------

    def _camera_infos(self, reader: Any, topics: dict[str, str | None]) -> list[Any]:
        infos = []
        for image_topic in self.topics:
            topic = camera_info_topic(image_topic)
            if topics.get(topic) != CAMERA_INFO:
                raise InputError(
                    f"bag {self.root}: no {CAMERA_INFO} topic {topic} beside {image_topic}: "
                    "give the calibration with --calibration FILE"
                )
            connections = [c for c in reader.connections if c.topic == topic]
            for _, _, raw in reader.messages(connections=connections):
                try:
                    infos.append((topic, reader.deserialize(raw, CAMERA_INFO)))
                except Exception as exc:
                    raise InputError(
                        f"bag {self.root}: {topic} message 0: cannot decode ({_reason(exc)})"
                    ) from None
                break
            else:
                raise InputError(f"bag {self.root}: {topic} holds no messages")
        return infos

    def _info_intrinsics(self, infos: list[Any], width: int, height: int) -> StereoIntrinsics:
        where = f"bag {self.root}: {infos[0][0]} and {infos[1][0]}"
        models = []
        for topic, info in infos:
            camera, R, P = camera_model_from_info(info, f"bag {self.root}: {topic}")
            if (camera.width, camera.height) != (width, height):
                raise InputError(
                    f"bag {self.root}: {topic} is for {camera.width}x{camera.height} images, "
                    f"the images are {width}x{height}"
                )
            models.append((camera, R, P))
        (left, R_left, P_left), (right, R_right, P_right) = models
        if all("rect" in topic for topic in self.topics):
            # Rectified images: only their projections count (K and D are the raw camera's).
            left = CameraModel(width, height, P_left[:3, :3], np.zeros(5))
            right = CameraModel(width, height, P_right[:3, :3], np.zeros(5))
            R_left = R_right = np.eye(3)
        rectification = Rectification(left, right, R_left, R_right, P_left, P_right)
        intrinsics = rectification.intrinsics(where)
        if rectification.needed:
            self.rectification = rectification
        log.info(
            "bag %s: calibration from CameraInfo, %s",
            self.root,
            "rectified here" if rectification.needed else "images rectified already",
        )
        return intrinsics

    def _file_intrinsics(self, path: Path, width: int, height: int) -> StereoIntrinsics:
        camera, _ = read_plain_calibration(path)
        return intrinsics_for_images(path, camera, width, height)

    # --- frames --------------------------------------------------------------------------

    def __len__(self) -> int:
        return len(self._pairs)

    def _raw_images(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """A frame's (left, right) images as stored, read in a pass through the bag: a frame
        before the last one read starts a new pass."""
        if not 0 <= index < len(self):
            raise IndexError(index)
        if self._last is not None and self._last[0] == index:
            return self._last[1]
        if self._cursor is None or index < self._cursor.position:
            if self._cursor is not None:
                self._cursor.close()
            self._cursor = _PairCursor(self.root, self._sides, self._pairs)
        raw = self._cursor.get(index)
        images = tuple(
            decode_image(
                message,
                self._sides[side].msgtype,
                f"bag {self.root}: {self._sides[side].topic} message {ordinal}",
            )
            for side, (ordinal, message) in enumerate(raw)
        )
        self._last = (index, images)  # type: ignore[assignment]
        return images  # type: ignore[return-value]

    def images(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        pair = self._raw_images(index)
        expected = (self.intrinsics.width, self.intrinsics.height)
        for side, image in enumerate(pair):
            size = (image.shape[1], image.shape[0])
            if size != expected:
                raise InputError(
                    f"bag {self.root}: frame {index} of {self._sides[side].topic} is "
                    f"{size[0]}x{size[1]}, the sequence's images are {expected[0]}x{expected[1]}"
                )
        if self.rectification is not None:
            return self.rectification.apply(*pair)
        return pair


class _PairCursor:
    """One pass through a bag's two image topics, handing out the paired frames in order:
    messages of frames passed over are dropped, those read ahead of a frame held."""

    def __init__(self, path: Path, sides: list[_Side], pairs: list[tuple[int, int]]):
        self.reader = _open_reader(path)
        self.sides = sides
        self.pairs = pairs
        self.position = 0  # the first frame this pass can still give
        self.wanted = [{i for i, _ in pairs}, {j for _, j in pairs}]
        self.held: dict[tuple[int, int], Any] = {}
        self.messages = self._messages()

    def _messages(self) -> Iterator[tuple[int, int, bytes]]:
        topics = {side.topic: k for k, side in enumerate(self.sides)}
        connections = [c for c in self.reader.connections if c.topic in topics]
        counts = [0, 0]
        for connection, _, raw in self.reader.messages(connections=connections):
            side = topics[connection.topic]
            yield side, counts[side], raw
            counts[side] += 1

    def get(self, index: int) -> tuple[tuple[int, Any], tuple[int, Any]]:
        left, right = self.pairs[index]
        needed = ((LEFT, left), (RIGHT, right))
        while not all(key in self.held for key in needed):
            try:
                side, ordinal, raw = next(self.messages)
            except StopIteration:
                raise InputError(
                    f"bag {self.reader.paths[0]}: changed while being read (frame {index} is gone)"
                ) from None
            if ordinal in self.wanted[side] and ordinal >= needed[side][1]:
                side_info = self.sides[side]
                try:
                    message = self.reader.deserialize(raw, side_info.msgtype)
                except Exception as exc:
                    raise InputError(
                        f"bag {self.reader.paths[0]}: {side_info.topic} message {ordinal}: "
                        f"cannot decode ({_reason(exc)})"
                    ) from None
                self.held[(side, ordinal)] = message
        result = ((left, self.held.pop((LEFT, left))), (right, self.held.pop((RIGHT, right))))
        self.held = {key: value for key, value in self.held.items() if key[1] > needed[key[0]][1]}
        self.position = index + 1
        return result

    def close(self) -> None:
        self.reader.close()
