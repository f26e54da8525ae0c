"""Darknet `.cfg` + `.weights` to an ONNX graph, with numpy and `onnx.helper` only.

    python -m data_tools.darknet_to_onnx yolov3-tiny.cfg yolov3-tiny.weights out.onnx \
        --names coco.names --verify

Why: OpenCV 5 no longer reads darknet files, and onnxruntime runs ONNX on one core faster than
cv2.dnn did. Layers supported are those of yolov3-tiny: `convolutional` (batch norm folded into
the weights; `leaky` or `linear`), `maxpool` (including the size-2 stride-1 one, which pads the
bottom and right), `route`, `upsample` and `yolo`.

The yolo heads are decoded in the graph, so the model's first output is `(1, N, 5 + C)` rows
`[cx, cy, w, h, objectness, class scores...]` in input pixels: the layout of the common YOLO ONNX
exports (YOLOv5/v7 style). One numpy decoder (`pipeline/frontend/objects.py`) then serves this
model and the ones users bring, and the anchors and strides, which are facts of the weights,
travel with them instead of living in our config. The raw head tensors are extra outputs
(`head_<layer index>`), for checking the convolutions apart from the decode.

`reference_forward` runs the same network as darknet writes it (batch norm unfolded, maxpool with
darknet's padding rule) in float64 numpy: the conversion is checked against it.

Facts from darknet's source (read, not copied): weights file = int32 major, minor, revision, then
`seen` (int64 when major*10 + minor >= 2, else int32), then per convolutional layer: biases,
and with batch norm scales, rolling means, rolling variances, then weights (out, in, k, k);
batch norm is `(x - mean) / (sqrt(var) + 1e-6)`; `pad=1` means padding `size // 2`; maxpool's
padding defaults to `size - 1` with the window offset by `-padding // 2`; leaky slope 0.1;
yolo: `x = (col + sigmoid(tx)) / grid_w`, `w = exp(tw) * anchor_w / net_w`, objectness and
classes through a sigmoid.
"""

from __future__ import annotations

import argparse
import logging
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    import onnx

log = logging.getLogger(__name__)

OPSET = 13
LEAKY_SLOPE = 0.1
DARKNET_BN_EPS = 1e-6  # added to sqrt(variance), darknet's way
DETECTIONS_OUTPUT = "detections"
INPUT_NAME = "images"


class DarknetError(ValueError):
    """A cfg or weights file this converter cannot read."""


# --- cfg and weights --------------------------------------------------------------------------


@dataclass(frozen=True)
class Section:
    kind: str
    options: dict[str, str]

    def int(self, key: str, default: int | None = None) -> int:
        if key not in self.options:
            if default is None:
                raise DarknetError(f"[{self.kind}] needs '{key}'")
            return default
        return int(self.options[key])

    def float(self, key: str, default: float) -> float:
        return float(self.options.get(key, default))

    def ints(self, key: str) -> list[int]:
        return [int(v) for v in self.options[key].split(",") if v.strip()]


def parse_cfg(text: str) -> list[Section]:
    """The sections of a darknet cfg in order; `[net]` first."""
    sections: list[Section] = []
    for number, raw in enumerate(text.splitlines(), 1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        if line.startswith("["):
            if not line.endswith("]"):
                raise DarknetError(f"cfg line {number}: bad section header {line!r}")
            sections.append(Section(line[1:-1].strip(), {}))
        elif "=" in line and sections:
            key, value = line.split("=", 1)
            sections[-1].options[key.strip()] = value.strip()
        else:
            raise DarknetError(f"cfg line {number}: expected 'key = value', got {line!r}")
    if not sections or sections[0].kind not in ("net", "network"):
        raise DarknetError("cfg must start with a [net] section")
    return sections


def read_weights(path: str | Path) -> np.ndarray:
    """The float32 parameters of a darknet weights file, header skipped."""
    data = Path(path).read_bytes()
    if len(data) < 16:
        raise DarknetError(f"weights {path}: too short")
    major, minor, _revision = np.frombuffer(data, np.int32, 3)
    seen_bytes = 8 if (major * 10 + minor) >= 2 and major < 1000 and minor < 1000 else 4
    start = 12 + seen_bytes
    if (len(data) - start) % 4:
        raise DarknetError(f"weights {path}: size is not a whole number of floats")
    return np.frombuffer(data, np.float32, offset=start).copy()


@dataclass
class Conv:
    weight: np.ndarray  # (out, in, k, k)
    bias: np.ndarray  # (out,): darknet's biases (beta with batch norm)
    stride: int
    padding: int
    activation: str
    bn_scale: np.ndarray | None = None  # gamma
    bn_mean: np.ndarray | None = None
    bn_var: np.ndarray | None = None


@dataclass
class MaxPool:
    size: int
    stride: int
    padding: int  # darknet's total padding; the window starts at -padding // 2


@dataclass
class Route:
    sources: list[int]  # absolute layer indices


@dataclass
class Upsample:
    stride: int
    scale: float


@dataclass
class Yolo:
    anchors: np.ndarray  # (m, 2) pixels of the network input, the masked ones
    classes: int


Layer = Conv | MaxPool | Route | Upsample | Yolo


@dataclass
class Network:
    width: int
    height: int
    channels: int
    layers: list[Layer] = field(default_factory=list)
    shapes: list[tuple[int, int, int]] = field(default_factory=list)  # (c, h, w) out per layer

    @property
    def heads(self) -> list[int]:
        return [i for i, layer in enumerate(self.layers) if isinstance(layer, Yolo)]


def conv_out(size: int, kernel: int, stride: int, padding: int) -> int:
    return (size + 2 * padding - kernel) // stride + 1


def pool_out(size: int, kernel: int, stride: int, padding: int) -> int:
    return (size + padding - kernel) // stride + 1


def build_network(
    sections: list[Section],
    weights: np.ndarray | None,
    width: int | None = None,
    height: int | None = None,
    rng: np.random.Generator | None = None,
) -> Network:
    """The layers of a parsed cfg with their parameters, from `weights` (all of them must be
    used), or drawn from `rng` when `weights` is None (for tests). `width`/`height` override the
    cfg's input size."""
    net = sections[0]
    network = Network(
        width or net.int("width"), height or net.int("height"), net.int("channels", 3)
    )
    offset = 0

    def take(count: int) -> np.ndarray:
        nonlocal offset
        if weights is None:
            assert rng is not None
            return rng.standard_normal(count).astype(np.float32)
        if offset + count > weights.size:
            raise DarknetError("weights file ends before the cfg's layers do")
        chunk = weights[offset : offset + count]
        offset += count
        return chunk

    c, h, w = network.channels, network.height, network.width
    for index, section in enumerate(sections[1:]):
        kind = section.kind
        if kind == "convolutional":
            filters, size = section.int("filters"), section.int("size", 1)
            stride = section.int("stride", 1)
            padding = size // 2 if section.int("pad", 0) else section.int("padding", 0)
            if section.int("groups", 1) != 1:
                raise DarknetError(f"layer {index}: grouped convolutions are not supported")
            activation = section.options.get("activation", "logistic")
            if activation not in ("leaky", "linear"):
                raise DarknetError(f"layer {index}: activation {activation!r} not supported")
            bias = take(filters)
            bn = None
            if section.int("batch_normalize", 0):
                scale, mean, var = take(filters), take(filters), take(filters)
                if weights is None:  # random parameters: keep variances positive
                    var = np.abs(var) + 0.5
                bn = (scale, mean, var)
            weight = take(filters * c * size * size).reshape(filters, c, size, size)
            if weights is None:
                weight = weight * np.float32(1.0 / np.sqrt(c * size * size))
            layer: Layer = Conv(weight, bias, stride, padding, activation)
            if bn is not None:
                layer.bn_scale, layer.bn_mean, layer.bn_var = bn
            c, h, w = (
                filters,
                conv_out(h, size, stride, padding),
                conv_out(w, size, stride, padding),
            )
        elif kind == "maxpool":
            stride = section.int("stride", 1)
            size = section.int("size", stride)
            padding = section.int("padding", size - 1)
            layer = MaxPool(size, stride, padding)
            h, w = pool_out(h, size, stride, padding), pool_out(w, size, stride, padding)
        elif kind == "route":
            sources = [i if i >= 0 else index + i for i in section.ints("layers")]
            if any(not 0 <= i < index for i in sources):
                raise DarknetError(f"layer {index}: route to a layer that is not before it")
            sizes = {network.shapes[i][1:] for i in sources}
            if len(sizes) != 1:
                raise DarknetError(f"layer {index}: route joins maps of sizes {sorted(sizes)}")
            layer = Route(sources)
            c = sum(network.shapes[i][0] for i in sources)
            h, w = network.shapes[sources[0]][1:]
        elif kind == "upsample":
            stride = section.int("stride", 2)
            layer = Upsample(stride, section.float("scale", 1.0))
            h, w = h * stride, w * stride
        elif kind == "yolo":
            classes = section.int("classes", 20)
            pairs = np.array(section.ints("anchors"), float).reshape(-1, 2)
            mask = section.ints("mask") if "mask" in section.options else list(range(len(pairs)))
            if c != len(mask) * (5 + classes):
                raise DarknetError(
                    f"layer {index}: yolo head expects {len(mask) * (5 + classes)} channels, "
                    f"got {c}"
                )
            layer = Yolo(pairs[mask], classes)
        else:
            raise DarknetError(f"layer {index}: [{kind}] is not supported")
        if h <= 0 or w <= 0:
            raise DarknetError(f"layer {index}: input {network.width}x{network.height} too small")
        network.layers.append(layer)
        network.shapes.append((c, h, w))
    if weights is not None and offset != weights.size:
        raise DarknetError(
            f"weights file holds {weights.size - offset} floats more than the cfg uses"
        )
    if not network.heads:
        raise DarknetError("cfg has no [yolo] layer")
    return network


def load_network(
    cfg: str | Path, weights: str | Path, width: int | None = None, height: int | None = None
) -> Network:
    sections = parse_cfg(Path(cfg).read_text())
    return build_network(sections, read_weights(weights), width, height)


# --- batch norm folding and the yolo decode constants ------------------------------------------


def fold_batch_norm(conv: Conv) -> tuple[np.ndarray, np.ndarray]:
    """Convolution weights and bias with darknet's batch norm folded in:
    `gamma * (Wx - mean) / (sqrt(var) + eps) + beta` = `(s W) x + (beta - s mean)`."""
    if conv.bn_scale is None:
        return conv.weight.astype(np.float32), conv.bias.astype(np.float32)
    s = conv.bn_scale.astype(np.float64) / (
        np.sqrt(conv.bn_var.astype(np.float64)) + DARKNET_BN_EPS
    )
    weight = conv.weight.astype(np.float64) * s[:, None, None, None]
    bias = conv.bias.astype(np.float64) - conv.bn_mean.astype(np.float64) * s
    return weight.astype(np.float32), bias.astype(np.float32)


def head_grid(anchors: np.ndarray, grid_h: int, grid_w: int) -> tuple[np.ndarray, np.ndarray]:
    """Per row of a decoded head (anchor-major, then cell row-major): the cell's (col, row) and
    the anchor's (w, h), each (m * grid_h * grid_w, 2)."""
    rows, cols = np.meshgrid(np.arange(grid_h), np.arange(grid_w), indexing="ij")
    cells = np.stack([cols.ravel(), rows.ravel()], axis=1).astype(np.float64)
    m = len(anchors)
    return np.tile(cells, (m, 1)), np.repeat(anchors.astype(np.float64), grid_h * grid_w, axis=0)


def decode_head(raw: np.ndarray, head: Yolo, net_w: int, net_h: int) -> np.ndarray:
    """Darknet's yolo decode of one raw head `(m * (5 + C), gh, gw)` to rows
    `[cx, cy, w, h, objectness, classes...]` in input pixels, `(m * gh * gw, 5 + C)`."""
    m, k = len(head.anchors), 5 + head.classes
    _, gh, gw = raw.shape
    rows = raw.reshape(m, k, gh * gw).transpose(0, 2, 1).reshape(m * gh * gw, k)
    cells, anchors = head_grid(head.anchors, gh, gw)
    out = np.empty_like(rows, dtype=np.float64)
    stride = np.array([net_w / gw, net_h / gh])
    out[:, 0:2] = (cells + sigmoid(rows[:, 0:2])) * stride
    out[:, 2:4] = np.exp(rows[:, 2:4]) * anchors
    out[:, 4:] = sigmoid(rows[:, 4:])
    return out


def sigmoid(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-x))


# --- the numpy reference ---------------------------------------------------------------------


def _conv_reference(x: np.ndarray, conv: Conv) -> np.ndarray:
    """Darknet's convolution layer as written: convolve, batch norm, scale and bias, activate."""
    k, p, s = conv.weight.shape[-1], conv.padding, conv.stride
    padded = np.pad(x, ((0, 0), (p, p), (p, p)))
    windows = np.lib.stride_tricks.sliding_window_view(padded, (k, k), axis=(1, 2))
    windows = windows[:, ::s, ::s]  # (c, h_out, w_out, k, k)
    y = np.tensordot(conv.weight.astype(np.float64), windows, axes=([1, 2, 3], [0, 3, 4]))
    if conv.bn_scale is not None:
        std = np.sqrt(conv.bn_var.astype(np.float64)) + DARKNET_BN_EPS
        y = (y - conv.bn_mean[:, None, None]) / std[:, None, None]
        y = y * conv.bn_scale[:, None, None]
    y = y + conv.bias[:, None, None]
    if conv.activation == "leaky":
        y = np.where(y > 0, y, LEAKY_SLOPE * y)
    return y


def _maxpool_reference(x: np.ndarray, pool: MaxPool) -> np.ndarray:
    """Darknet's maxpool: windows start at `-padding // 2`; outside the map counts as -inf."""
    _, h, w = x.shape
    h_out, w_out = (
        pool_out(h, pool.size, pool.stride, pool.padding),
        pool_out(w, pool.size, pool.stride, pool.padding),
    )
    begin = pool.padding // 2
    end_h = max(0, (h_out - 1) * pool.stride + pool.size - begin - h)
    end_w = max(0, (w_out - 1) * pool.stride + pool.size - begin - w)
    padded = np.pad(x, ((0, 0), (begin, end_h), (begin, end_w)), constant_values=-np.inf)
    windows = np.lib.stride_tricks.sliding_window_view(padded, (pool.size, pool.size), (1, 2))
    return windows[:, :: pool.stride, :: pool.stride][:, :h_out, :w_out].max(axis=(3, 4))


def reference_forward(network: Network, image: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    """The network on one `(channels, height, width)` image in [0, 1], float64: the decoded rows
    of all heads `(N, 5 + C)` and the raw head tensors."""
    outputs: list[np.ndarray] = []
    x = np.asarray(image, np.float64)
    for layer in network.layers:
        if isinstance(layer, Conv):
            x = _conv_reference(x, layer)
        elif isinstance(layer, MaxPool):
            x = _maxpool_reference(x, layer)
        elif isinstance(layer, Route):
            x = np.concatenate([outputs[i] for i in layer.sources], axis=0)
        elif isinstance(layer, Upsample):
            x = layer.scale * x.repeat(layer.stride, axis=1).repeat(layer.stride, axis=2)
        # a yolo layer passes its input on; it is decoded below
        outputs.append(x)
    raws = [outputs[i] for i in network.heads]
    decoded = [
        decode_head(outputs[i], network.layers[i], network.width, network.height)  # type: ignore[arg-type]
        for i in network.heads
    ]
    return np.concatenate(decoded, axis=0), raws


# --- the ONNX graph --------------------------------------------------------------------------


def to_onnx(
    network: Network, class_names: list[str] | None = None, producer: str = ""
) -> onnx.ModelProto:
    """The network as an `onnx.ModelProto`: input `images` (1, C, H, W) float32 RGB in [0, 1];
    outputs `detections` (1, N, 5 + C) and `head_<i>` (raw heads)."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    nodes: list = []
    initializers: list = []

    def const(name: str, value: np.ndarray) -> str:
        initializers.append(numpy_helper.from_array(np.asarray(value), name))
        return name

    names: list[str] = []
    previous = INPUT_NAME
    for index, layer in enumerate(network.layers):
        out = f"layer_{index}"
        if isinstance(layer, Conv):
            weight, bias = fold_batch_norm(layer)
            k = weight.shape[-1]
            p = layer.padding
            conv_out_name = out if layer.activation == "linear" else f"{out}_conv"
            nodes.append(
                helper.make_node(
                    "Conv",
                    [previous, const(f"{out}_w", weight), const(f"{out}_b", bias)],
                    [conv_out_name],
                    kernel_shape=[k, k],
                    strides=[layer.stride, layer.stride],
                    pads=[p, p, p, p],
                )
            )
            if layer.activation == "leaky":
                nodes.append(
                    helper.make_node("LeakyRelu", [conv_out_name], [out], alpha=LEAKY_SLOPE)
                )
        elif isinstance(layer, MaxPool):
            _, h, w = network.shapes[index - 1] if index else (0, network.height, network.width)
            _, h_out, w_out = network.shapes[index]
            begin = layer.padding // 2
            end_h = (h_out - 1) * layer.stride + layer.size - begin - h
            end_w = (w_out - 1) * layer.stride + layer.size - begin - w
            if end_h < 0 or end_w < 0:
                raise DarknetError(f"layer {index}: this maxpool geometry is not supported")
            # ONNX's MaxPool ignores padded cells, as darknet's -FLT_MAX does.
            nodes.append(
                helper.make_node(
                    "MaxPool",
                    [previous],
                    [out],
                    kernel_shape=[layer.size, layer.size],
                    strides=[layer.stride, layer.stride],
                    pads=[begin, begin, end_h, end_w],
                )
            )
        elif isinstance(layer, Route):
            inputs = [names[i] for i in layer.sources]
            op = "Concat" if len(inputs) > 1 else "Identity"
            kwargs = {"axis": 1} if len(inputs) > 1 else {}
            nodes.append(helper.make_node(op, inputs, [out], **kwargs))
        elif isinstance(layer, Upsample):
            s = float(layer.stride)
            scales = const(f"{out}_scales", np.array([1.0, 1.0, s, s], np.float32))
            resized = out if layer.scale == 1.0 else f"{out}_resized"
            # asymmetric + floor: output cell i copies input cell i // stride, darknet's rule.
            nodes.append(
                helper.make_node(
                    "Resize",
                    [previous, "", scales],
                    [resized],
                    mode="nearest",
                    coordinate_transformation_mode="asymmetric",
                    nearest_mode="floor",
                )
            )
            if layer.scale != 1.0:
                factor = const(f"{out}_factor", np.array(layer.scale, np.float32))
                nodes.append(helper.make_node("Mul", [resized, factor], [out]))
        elif isinstance(layer, Yolo):
            out = previous  # the raw head is the previous layer's output
        names.append(out)
        previous = out

    f32 = TensorProto.FLOAT

    def node(op: str, inputs: list[str], output: str, **attrs: Any) -> str:
        nodes.append(helper.make_node(op, inputs, [output], **attrs))
        return output

    def ints(name: str, *values: int) -> str:
        return const(name, np.array(values, np.int64))

    # The decode reads the grid size off the tensors: the model takes any input size that is a
    # multiple of the network's stride (32 for yolov3-tiny), e.g. 832x256 for KITTI's frames.
    i2, i4 = ints("i2", 2), ints("i4", 4)
    zero, one = const("zero", np.array(0.0, np.float32)), const("one", np.array(1.0, np.float32))
    swap = ints("swap", 1, 0)
    axis0, axis1, axis2 = ints("axis0", 0), ints("axis1", 1), ints("axis2", 2)
    scalar0 = const("scalar0", np.array(0, np.int64))
    scalar1 = const("scalar1", np.array(1, np.int64))
    net_hw = node("Slice", [node("Shape", [INPUT_NAME], "input_shape"), i2, i4], "net_hw")
    net_wh = node("Cast", [node("Gather", [net_hw, swap], "net_wh_i", axis=0)], "net_wh", to=f32)
    decoded = []
    for index in network.heads:
        head: Yolo = network.layers[index]  # type: ignore[assignment]
        m, k = len(head.anchors), 5 + head.classes
        p = f"head_{index}"
        raw = names[index]
        grid_hw = node("Slice", [node("Shape", [raw], f"{p}_shape"), i2, i4], f"{p}_hw")
        grid_hw_f = node("Cast", [grid_hw], f"{p}_hw_f", to=f32)
        grid_h = node("Gather", [grid_hw_f, scalar0], f"{p}_h", axis=0)  # scalars, for Range
        grid_w = node("Gather", [grid_hw_f, scalar1], f"{p}_w", axis=0)
        cols = node("Range", [zero, grid_w, one], f"{p}_cols")
        rows = node("Range", [zero, grid_h, one], f"{p}_rows")
        col_grid = node("Expand", [node("Unsqueeze", [cols, axis0], f"{p}_c1"), grid_hw], f"{p}_cg")
        row_grid = node("Expand", [node("Unsqueeze", [rows, axis1], f"{p}_r1"), grid_hw], f"{p}_rg")
        cells = node(
            "Concat",
            [
                node("Unsqueeze", [col_grid, axis2], f"{p}_cg3"),
                node("Unsqueeze", [row_grid, axis2], f"{p}_rg3"),
            ],
            f"{p}_cells_hw",
            axis=2,
        )  # (gh, gw, 2): (col, row) of each cell
        cells = node("Reshape", [cells, ints(f"{p}_cells_shape", 1, 1, -1, 2)], f"{p}_cells")
        grid_wh = node("Gather", [grid_hw_f, swap], f"{p}_wh", axis=0)
        stride = node("Div", [net_wh, grid_wh], f"{p}_stride")  # input pixels per cell
        # (1, m*k, gh, gw) -> (1, m, gh*gw, k): rows anchor-major, then cells row-major
        t = node("Reshape", [raw, ints(f"{p}_split_shape", 1, m, k, -1)], f"{p}_split")
        t = node("Transpose", [t], f"{p}_t", perm=[0, 1, 3, 2])
        axis3 = ints(f"{p}_axis3", 3)
        xy = node("Slice", [t, ints(f"{p}_s0", 0), ints(f"{p}_e0", 2), axis3], f"{p}_xy")
        wh = node("Slice", [t, ints(f"{p}_s1", 2), ints(f"{p}_e1", 4), axis3], f"{p}_whr")
        scores = node("Slice", [t, ints(f"{p}_s2", 4), ints(f"{p}_e2", k), axis3], f"{p}_sc")
        xy = node(
            "Mul",
            [node("Add", [node("Sigmoid", [xy], f"{p}_xys"), cells], f"{p}_xyc"), stride],
            f"{p}_xyp",
        )
        anchors = const(f"{p}_anchors", head.anchors.reshape(1, m, 1, 2).astype(np.float32))
        wh = node("Mul", [node("Exp", [wh], f"{p}_whe"), anchors], f"{p}_whp")
        scores = node("Sigmoid", [scores], f"{p}_scs")
        joined = node("Concat", [xy, wh, scores], f"{p}_dec4", axis=3)
        decoded.append(node("Reshape", [joined, ints(f"{p}_rows_shape", 1, -1, k)], f"{p}_dec"))
    node("Concat", decoded, DETECTIONS_OUTPUT, axis=1)

    classes = {network.layers[i].classes for i in network.heads}  # type: ignore[union-attr]
    if len(classes) != 1:
        raise DarknetError("yolo heads disagree on the number of classes")
    num_classes = classes.pop()
    outputs = [helper.make_tensor_value_info(DETECTIONS_OUTPUT, f32, [1, "rows", 5 + num_classes])]
    for index in network.heads:
        node("Identity", [names[index]], f"head_{index}")
        channels = network.shapes[index][0]
        size = [f"head_{index}_height", f"head_{index}_width"]
        outputs.append(helper.make_tensor_value_info(f"head_{index}", f32, [1, channels, *size]))
    image = helper.make_tensor_value_info(INPUT_NAME, f32, [1, network.channels, "height", "width"])
    graph = helper.make_graph(nodes, "darknet", [image], outputs, initializers)
    model = helper.make_model(
        graph,
        opset_imports=[helper.make_opsetid("", OPSET)],
        producer_name="mmslam data_tools.darknet_to_onnx",
    )
    model.ir_version = 8  # readable by onnxruntime releases of the last years
    metadata = {"source": producer or "darknet", "layout": "rows: cx cy w h objectness classes"}
    if class_names is not None:
        if len(class_names) != num_classes:
            raise DarknetError(f"{len(class_names)} class names for {num_classes} classes")
        # The Ultralytics exports' convention: a dict literal {index: name}.
        metadata["names"] = repr(dict(enumerate(class_names)))
    for key, value in metadata.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.checker.check_model(model)
    return model


def onnx_forward(model_bytes: bytes, image: np.ndarray) -> list[np.ndarray]:
    """All outputs of an ONNX model (bytes) on one `(C, H, W)` image, float32, one thread."""
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    session = ort.InferenceSession(model_bytes, options, providers=["CPUExecutionProvider"])
    return session.run(None, {INPUT_NAME: image[None].astype(np.float32)})


def compare(network: Network, model_bytes: bytes, seed: int = 0) -> dict[str, float]:
    """Largest differences between the ONNX model and the numpy reference on a random image:
    `raw` over the raw head tensors, `decoded` over the decoded rows relative to their size."""
    rng = np.random.default_rng(seed)
    image = rng.random((network.channels, network.height, network.width))
    decoded_ref, raws_ref = reference_forward(network, image)
    outputs = onnx_forward(model_bytes, image)
    raw_diff = max(
        float(np.max(np.abs(o[0] - r))) for o, r in zip(outputs[1:], raws_ref, strict=True)
    )
    scale = np.maximum(1.0, np.abs(decoded_ref))
    decoded_diff = float(np.max(np.abs(outputs[0][0] - decoded_ref) / scale))
    return {"raw": raw_diff, "decoded": decoded_diff}


def convert(
    cfg: str | Path,
    weights: str | Path,
    out: str | Path,
    names: str | Path | None = None,
    width: int | None = None,
    height: int | None = None,
) -> Network:
    """Convert and write `out` (through a temporary name)."""
    network = load_network(cfg, weights, width, height)
    class_names = None
    if names is not None:
        class_names = [n.strip() for n in Path(names).read_text().splitlines() if n.strip()]
    model = to_onnx(network, class_names, producer=f"{Path(cfg).name} + {Path(weights).name}")
    out = Path(out)
    temporary = out.with_name(out.name + ".part")
    temporary.write_bytes(model.SerializeToString())
    temporary.replace(out)
    log.info("wrote %s (%d heads; input of any multiple of 32)", out, len(network.heads))
    return network


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("cfg", type=Path)
    parser.add_argument("weights", type=Path)
    parser.add_argument("out", type=Path)
    parser.add_argument("--names", type=Path, help="class names, one a line (model metadata)")
    parser.add_argument("--width", type=int, help="input width (default: the cfg's)")
    parser.add_argument("--height", type=int, help="input height (default: the cfg's)")
    parser.add_argument(
        "--verify", action="store_true", help="compare with the numpy reference on a random image"
    )
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    try:
        network = convert(args.cfg, args.weights, args.out, args.names, args.width, args.height)
    except (DarknetError, OSError) as exc:
        log.error("darknet_to_onnx: %s", exc)
        return 2
    if args.verify:
        diff = compare(network, args.out.read_bytes())
        log.info(
            "max abs difference: raw heads %.3g, decoded rows (relative) %.3g",
            diff["raw"],
            diff["decoded"],
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
