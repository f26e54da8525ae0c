"""Object boxes: the darknet -> ONNX conversion against a numpy reference, decoding and
suppression on hand-made tensors, the config, and the real detector on a real photo."""

from __future__ import annotations

import dataclasses
import itertools
from pathlib import Path

import numpy as np
import pytest

from data_tools import darknet_to_onnx as dn
from data_tools.bench_objects import (
    OBJECT_FRAME,
    cars_on_object_frame,
    lidar_in_left_camera,
    object_frame,
)
from pipeline.datasets.camera import StereoIntrinsics
from pipeline.errors import InputError
from pipeline.frontend import model_files
from pipeline.frontend import objects as ob
from pipeline.frontend.config import load_frontend_config
from tests import real_data
from tests.detector import installed

ANCHORS = "10,14,  23,27,  37,58,  81,82,  135,169,  344,319"


def cfg_section(kind: str, **options: object) -> str:
    """One `[kind]` section of a darknet cfg, its options in order."""
    return f"[{kind}]\n" + "".join(f"{key}={value}\n" for key, value in options.items()) + "\n"


def convolution(filters: int, size: int, activation: str = "leaky") -> str:
    """A stride-1 padded convolution; the leaky ones batch-normed, the linear (head) ones not."""
    normed = {"batch_normalize": 1} if activation == "leaky" else {}
    shape = {"filters": filters, "size": size, "stride": 1, "pad": 1}
    return cfg_section("convolutional", **normed, **shape, activation=activation)


def yolo_head(mask: str) -> str:
    return cfg_section("yolo", mask=mask, anchors=ANCHORS, classes=3, num=6)


# A small network with every layer kind of yolov3-tiny: batch-normed leaky convolutions, 2x2
# maxpools of stride 2 and of stride 1, two yolo heads, a route back, an upsample and a route
# joining two layers.
TINY_CFG = "".join(
    [
        cfg_section("net", width=64, height=64, channels=3),
        convolution(8, 3),
        cfg_section("maxpool", size=2, stride=2),
        convolution(16, 3),
        cfg_section("maxpool", size=2, stride=2),
        convolution(16, 3),
        cfg_section("maxpool", size=2, stride=1),
        convolution(16, 1),
        convolution(24, 1, "linear"),
        yolo_head("3,4,5"),
        cfg_section("route", layers="-4"),
        convolution(8, 1),
        cfg_section("upsample", stride=2),
        cfg_section("route", layers="-1, 2"),
        convolution(24, 3, "linear"),
        yolo_head("0,1,2"),
    ]
)
TINY_NAMES = ["car", "bus", "dog"]


def write_weights(network: dn.Network, path: Path) -> None:
    """A darknet weights file (version 0.2: 64-bit `seen`) holding the network's parameters."""
    chunks = []
    for layer in network.layers:
        if isinstance(layer, dn.Conv):
            chunks.append(layer.bias)
            if layer.bn_scale is not None:
                chunks += [layer.bn_scale, layer.bn_mean, layer.bn_var]
            chunks.append(layer.weight.ravel())
    header = np.array([0, 2, 0], np.int32).tobytes() + np.array([12345], np.int64).tobytes()
    path.write_bytes(header + np.concatenate(chunks).astype(np.float32).tobytes())


@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> dict:
    """The tiny network with random parameters, written as darknet files and converted."""
    directory = tmp_path_factory.mktemp("tiny")
    cfg, weights, names = directory / "tiny.cfg", directory / "tiny.weights", directory / "names"
    cfg.write_text(TINY_CFG)
    names.write_text("\n".join(TINY_NAMES) + "\n")
    generated = dn.build_network(dn.parse_cfg(TINY_CFG), None, rng=np.random.default_rng(7))
    write_weights(generated, weights)
    onnx_path = directory / "tiny.onnx"
    network = dn.convert(cfg, weights, onnx_path, names)
    return {
        "cfg": cfg,
        "weights": weights,
        "generated": generated,
        "network": network,
        "onnx": onnx_path,
    }


# --- darknet -> ONNX -------------------------------------------------------------------------


def test_weights_file_reads_back_what_was_written(tiny):
    read = dn.load_network(tiny["cfg"], tiny["weights"])
    convs = [(a, b) for a, b in zip(tiny["generated"].layers, read.layers, strict=True)]
    assert [type(b).__name__ for _, b in convs] == [type(a).__name__ for a, _ in convs]
    for a, b in convs:
        if isinstance(a, dn.Conv):
            np.testing.assert_array_equal(a.weight, b.weight)
            np.testing.assert_array_equal(a.bias, b.bias)
            if a.bn_scale is not None:
                np.testing.assert_array_equal(a.bn_var, b.bn_var)
    assert read.shapes[5] == (16, 16, 16)  # the stride-1 maxpool keeps the size
    assert read.shapes[-1] == (24, 32, 32)


def test_weights_file_of_the_wrong_size_is_refused(tiny, tmp_path):
    data = tiny["weights"].read_bytes()
    longer, shorter = tmp_path / "longer.weights", tmp_path / "shorter.weights"
    longer.write_bytes(data + b"\0\0\0\0")
    shorter.write_bytes(data[:-4])
    with pytest.raises(dn.DarknetError, match="more than the cfg uses"):
        dn.load_network(tiny["cfg"], longer)
    with pytest.raises(dn.DarknetError, match="ends before"):
        dn.load_network(tiny["cfg"], shorter)


@pytest.mark.parametrize("size", [(64, 64), (96, 64)])
def test_conversion_matches_the_numpy_reference(tiny, size):
    # The model was built at 64x64; its decode reads the grid off the tensors, so 96x64 works.
    network = dn.load_network(tiny["cfg"], tiny["weights"], *size)
    diff = dn.compare(network, tiny["onnx"].read_bytes(), seed=3)
    assert diff["raw"] < 1e-4
    assert diff["decoded"] < 1e-4


def test_fold_batch_norm_by_hand():
    conv = dn.Conv(
        weight=np.full((1, 1, 1, 1), 2.0, np.float32),
        bias=np.array([1.0], np.float32),
        stride=1,
        padding=0,
        activation="linear",
        bn_scale=np.array([3.0], np.float32),
        bn_mean=np.array([0.5], np.float32),
        bn_var=np.array([4.0], np.float32),
    )
    weight, bias = dn.fold_batch_norm(conv)
    # 3 * (2x - 0.5) / 2 + 1 = 3x + 0.25
    assert weight.ravel()[0] == pytest.approx(3.0, rel=1e-6)
    assert bias[0] == pytest.approx(0.25, rel=1e-5)


def test_reference_maxpool_of_stride_one_ignores_the_padding():
    # Darknet pads the bottom and right with -inf: a map of negatives keeps its values there.
    x = np.array([[[-1.0, -2.0], [-3.0, -4.0]]])
    out = dn._maxpool_reference(x, dn.MaxPool(size=2, stride=1, padding=1))
    np.testing.assert_array_equal(out, [[[-1.0, -2.0], [-3.0, -4.0]]])


def test_decode_head_by_hand():
    head = dn.Yolo(anchors=np.array([[10.0, 20.0]]), classes=1)
    raw = np.zeros((6, 2, 2))  # one anchor, 5 + 1 channels, a 2x2 grid
    raw[2, 0, 1] = np.log(2.0)  # tw of the cell at row 0, col 1
    rows = dn.decode_head(raw, head, net_w=64, net_h=64)
    # Cell order is row-major: the second row is (row 0, col 1). Stride 32 px.
    np.testing.assert_allclose(rows[1], [1.5 * 32, 0.5 * 32, 20.0, 20.0, 0.5, 0.5])
    np.testing.assert_allclose(rows[2, :2], [16.0, 48.0])


# --- decoding and suppression ----------------------------------------------------------------


def test_prediction_rows_accepts_both_layouts():
    rows = np.arange(2 * 8, dtype=np.float32).reshape(1, 2, 8)
    out, objectness = ob.prediction_rows(rows, num_classes=3)
    assert objectness and out.shape == (2, 8)
    out, objectness = ob.prediction_rows(np.zeros((1, 7, 100)), num_classes=3)
    assert not objectness and out.shape == (100, 7)
    with pytest.raises(InputError, match="fits neither"):
        ob.prediction_rows(np.zeros((1, 10, 9)), num_classes=3)


def test_decode_rows_by_hand():
    rows = np.array(
        [
            [50, 40, 20, 10, 0.9, 0.1, 0.95],  # 0.9 * 0.95 = 0.855: kept, class 1
            [50, 40, 20, 10, 0.8, 0.95, 0.1],  # 0.76: dropped at 0.8
        ],
        np.float32,
    )
    boxes, scores, classes = ob.decode_rows(rows, objectness=True, threshold=0.8)
    np.testing.assert_allclose(boxes, [[40, 35, 60, 45]])
    np.testing.assert_allclose(scores, [0.855], rtol=1e-6)
    assert classes.tolist() == [1]
    _, scores, classes = ob.decode_rows(
        rows[:, [0, 1, 2, 3, 5, 6]], objectness=False, threshold=0.8
    )
    assert classes.tolist() == [1, 0]
    np.testing.assert_allclose(scores, [0.95, 0.95], rtol=1e-6)


def test_letterbox_and_its_inverse():
    image = np.zeros((100, 200), np.uint8)
    image[40:60, 90:110] = 255
    tensor, box = ob.letterbox(image, 64, 64)
    assert tensor.shape == (1, 3, 64, 64) and tensor.dtype == np.float32
    assert box.scale == pytest.approx(0.32) and (box.pad_x, box.pad_y) == (0, 16)
    assert tensor[0, :, 0, 0] == pytest.approx([127 / 255] * 3)  # the grey band
    assert tensor[0, :, 16 + 16, 32] == pytest.approx([1.0] * 3)  # the square's centre
    network_box = np.array([[90 * 0.32, 16 + 40 * 0.32, 110 * 0.32, 16 + 60 * 0.32]])
    np.testing.assert_allclose(ob.undo_letterbox(network_box, box, 200, 100), [[90, 40, 110, 60]])
    outside = np.array([[-10.0, 0.0, 80.0, 70.0]])
    np.testing.assert_allclose(ob.undo_letterbox(outside, box, 200, 100), [[0, 0, 200, 100]])


def test_letterbox_of_a_tall_colour_image():
    image = np.zeros((128, 64, 3), np.uint8)
    image[..., 0] = 255  # blue, in OpenCV's BGR order
    tensor, box = ob.letterbox(image, 64, 64)
    # 64 / 128, computed: equal to round-off
    assert box.scale == pytest.approx(0.5, rel=1e-12) and (box.pad_x, box.pad_y) == (16, 0)
    assert tensor[0, :, 32, 32] == pytest.approx([0.0, 0.0, 1.0])  # the network wants RGB
    network_box = np.array([[16 + 10 * 0.5, 20 * 0.5, 16 + 30 * 0.5, 60 * 0.5]])
    np.testing.assert_allclose(ob.undo_letterbox(network_box, box, 64, 128), [[10, 20, 30, 60]])


def test_suppression_keeps_the_best_of_overlapping_boxes_across_classes():
    boxes = np.array([[0, 0, 10, 10], [1, 1, 11, 11], [50, 50, 60, 60], [0, 0, 10, 10.5]], float)
    scores = np.array([0.85, 0.9, 0.8, 0.95])
    kept = ob.suppress(boxes, scores, iou=0.45)
    assert kept.tolist() == [3, 2]
    assert ob.suppress(np.empty((0, 4)), np.empty(0), 0.45).tolist() == []
    assert ob.box_iou((0, 0, 10, 10), (5, 0, 15, 10)) == pytest.approx(1 / 3)


def test_inside_fraction_by_hand():
    assert ob.inside_fraction((2, 2, 4, 4), (0, 0, 10, 10)) == pytest.approx(1.0)
    assert ob.inside_fraction((8, 0, 12, 10), (0, 0, 10, 10)) == pytest.approx(0.5)
    assert ob.inside_fraction((0, 0, 10, 10), (8, 0, 12, 10)) == pytest.approx(0.2)
    assert ob.inside_fraction((20, 20, 30, 30), (0, 0, 10, 10)) == pytest.approx(0.0, abs=1e-12)


def test_a_box_inside_another_at_its_disparity_is_a_part_of_it():
    # The KITTI object frame's hatchback and its rear, boxed apart (IoU 0.32: NMS keeps both),
    # a car seen beyond it inside its box, and a box beside it.
    boxes = [
        (733.0, 184.0, 919.0, 305.0),  # the hatchback, 47.0 px
        (787.0, 197.0, 864.0, 291.0),  # its rear, 47.1 px
        (737.0, 187.0, 756.0, 207.0),  # a car beyond, 29.2 px
        (600.0, 190.0, 700.0, 250.0),  # another car, 47 px
    ]
    disparities = np.array([47.0, 47.1, 29.2, 47.0])
    sigmas = np.array([1.0, 0.7, 4.0, 1.0])
    assert ob.box_iou(boxes[0], boxes[1]) < 0.45
    assert ob.nested_duplicates(boxes, disparities, sigmas, 0.8, 3.0) == {1: 0}
    # Three sigmas: 18 px apart with sigmas of 4 and 1 is another object; with 7, the same.
    sigmas[2] = 7.0
    assert ob.nested_duplicates(boxes, disparities, sigmas, 0.8, 3.0) == {1: 0, 2: 0}
    # A part of a part belongs to the outermost box.
    inner = [(800.0, 220.0, 840.0, 280.0)]
    owner = ob.nested_duplicates(
        boxes[:2] + inner, np.array([47.0, 47.1, 47.2]), np.ones(3), 0.8, 3.0
    )
    assert owner == {1: 0, 2: 0}


# --- configuration ---------------------------------------------------------------------------


def default_objects() -> ob.ObjectDetectorConfig:
    return load_frontend_config().objects


def test_object_config_keys_are_checked(tmp_path):
    override = tmp_path / "frontend.toml"
    override.write_text(
        'classes = ["vehicle"]\n[objects.class_map]\ncar = "vehicle"\n'
        "[objects.stereo]\nmargin = 4\n".replace("classes", "[objects]\nclasses", 1)
    )
    config = load_frontend_config(override).objects
    assert config.classes == ("vehicle",) and config.class_map["car"] == "vehicle"
    assert config.stereo.margin == 4 and config.stereo.max_disparity == 128
    for text, message in [
        ("[objects]\nmodel_path = 'x'\n", "unknown key 'objects.model_path'"),
        ("[objects.class_map]\ncar = 'plane'\n", "not in classes"),
        ("[objects]\ninput_size = [416, 400]\n", "multiples of 32"),
        ("[objects.thresholds]\n'yolov3-tiny.onnx' = 1.5\n", "thresholds"),
        ("[objects]\nmodel = 'other.onnx'\n", "no score threshold for the model 'other.onnx'"),
        ("[objects]\nnested_fraction = 0.0\n", "nested_fraction"),
        ("[objects.stereo]\nblock_size = 4\n", "block_size"),
    ]:
        override.write_text(text)
        with pytest.raises(InputError, match=message):
            load_frontend_config(override)


def test_models_directory_follows_the_environment(monkeypatch, tmp_path):
    monkeypatch.setenv(model_files.MODELS_ENV, str(tmp_path))
    assert default_objects().model_path == tmp_path / ob.DEFAULT_MODEL
    assert model_files.resolve_model_path("/elsewhere/m.onnx") == Path("/elsewhere/m.onnx")


# --- the detector on the tiny model ----------------------------------------------------------


def tiny_detector(tiny, **table) -> ob.ObjectDetector:
    base = {
        "model": str(tiny["onnx"]),
        "input_size": (64, 64),
        "classes": ("car", "truck"),
        "class_map": {"car": "car", "bus": "truck"},
        "thresholds": {tiny["onnx"].name: 0.05},
    }
    return ob.ObjectDetector(dataclasses.replace(default_objects(), **{**base, **table}))


def test_detector_reports_only_mapped_classes_inside_the_image(tiny):
    detector = tiny_detector(tiny)
    assert detector.detector_classes == TINY_NAMES  # from the model's metadata
    image = np.random.default_rng(1).integers(0, 256, (90, 160, 3), np.uint8)
    boxes = detector.detect_boxes(image)
    assert boxes, "random parameters at threshold 0.05 should fire somewhere"
    for box in boxes:
        assert box.detector_class in ("car", "bus")
        assert box.class_name == {"car": "car", "bus": "truck"}[box.detector_class]
        assert box.class_id == detector.class_names.index(box.class_name)
        assert 0 <= box.bbox[0] <= box.bbox[2] <= 160 and 0 <= box.bbox[1] <= box.bbox[3] <= 90
        assert box.score >= 0.05
    scores = [b.score for b in boxes]
    assert scores == sorted(scores, reverse=True)


def test_detector_refuses_what_it_cannot_use(tiny, tmp_path):
    with pytest.raises(InputError, match=r"data_tools\.models install"):
        ob.ObjectDetector(dataclasses.replace(default_objects(), model=str(tmp_path / "none.onnx")))
    with pytest.raises(InputError, match="no such class"):
        tiny_detector(tiny, class_map={"truck": "truck"})


# --- the real detector on a real photo (installed by `python -m data_tools.models install`) ---

# A real KITTI object-benchmark frame (development data, ../shared/data/real): the dark
# hatchback parked on the right, 10 m ahead, boxed by hand.
KITTI_FRAME = real_data.REAL_DATA / "kitti-object-frame"
KITTI_CAR_BOX = (734.0, 184.0, 906.0, 306.0)
# yolov3-tiny scores that car 0.95 at the configured input (measured); the paper's threshold is
# 0.8, and the test asks for 0.5 and a box on the car.
CAR_THRESHOLD = 0.5


@pytest.fixture(scope="module")
def kitti_photo() -> np.ndarray:
    import cv2

    path = KITTI_FRAME / "left.png"
    real_data.skip_unless_present(path)
    image = cv2.imread(str(path))
    assert image is not None
    return image


@pytest.fixture(scope="module")
def yolo() -> ob.ObjectDetector:
    from data_tools.models import model_path

    installed(model_path())
    config = default_objects()
    bare_stereo = dataclasses.replace(config.stereo, surface_to_centre=0.0)
    config = dataclasses.replace(
        config, thresholds={ob.DEFAULT_MODEL: CAR_THRESHOLD}, stereo=bare_stereo
    )
    return ob.ObjectDetector(config)


def test_yolov3_tiny_finds_the_parked_car_in_a_kitti_frame(yolo, kitti_photo):
    cars = [b for b in yolo.detect_boxes(kitti_photo) if b.class_name == "car"]
    assert cars, "no car found in the KITTI frame"
    best = max(cars, key=lambda b: ob.box_iou(b.bbox, KITTI_CAR_BOX))
    assert best.score >= CAR_THRESHOLD
    assert ob.box_iou(best.bbox, KITTI_CAR_BOX) >= 0.7, best


def test_the_stage_ranges_the_car_on_a_shifted_pair(yolo, kitti_photo):
    # A fronto-parallel scene: the right image is the left one moved 30 px left.
    import cv2

    shift = 30
    left = cv2.cvtColor(kitti_photo, cv2.COLOR_BGR2GRAY)
    right = np.zeros_like(left)
    right[:, :-shift] = left[:, shift:]
    k = StereoIntrinsics(left.shape[1], left.shape[0], 700.0, 700.0, 384.0, 288.0, 0.5)
    records = [r for r in yolo.detect(left, right, k) if r.class_name == "car"]
    assert records
    record = max(records, key=lambda r: ob.box_iou(r.bbox, KITTI_CAR_BOX))
    assert record.disparity == pytest.approx(shift, abs=0.25)
    assert record.point[2] == pytest.approx(700.0 * 0.5 / shift, rel=0.01)
    assert record.covariance.shape == (3, 3)


# --- the KITTI object frame of ../shared/data/real, against its LiDAR ------------------------

needs_object_frame = real_data.needs(OBJECT_FRAME / "lidar.bin")


@needs_object_frame
def test_lidar_projects_onto_the_object_frame():
    pixels, points = lidar_in_left_camera()
    left, _, _ = object_frame()
    seen = (pixels[:, 0] >= 0) & (pixels[:, 0] < left.shape[1])
    seen &= (pixels[:, 1] >= 0) & (pixels[:, 1] < left.shape[0])
    assert seen.sum() > 10000 and np.all(points[:, 2] > 0)


@needs_object_frame
def test_cars_of_the_object_frame_are_found_once_each_at_their_lidar_range():
    # About 9 vehicles in view. Measured at the configured threshold (0.3): 7 boxes, the rear of
    # the hatchback merged into it, ranges 0.9-4.4 % beyond the LiDAR's.
    installed(model_files.resolve_model_path(ob.DEFAULT_MODEL))
    config = default_objects()
    cars = cars_on_object_frame(config)
    for a, b in itertools.permutations(cars, 2):
        assert ob.inside_fraction(a.bbox, b.bbox) < config.nested_fraction, (a.bbox, b.bbox)
    checked = [car for car in cars if car.lidar_points >= 5]
    assert len(checked) >= 3
    for car in checked:
        assert abs(car.error) <= 0.05, car
