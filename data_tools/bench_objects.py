"""Frames per second of the object-box stage on 1226x370 stereo pairs, one core.

    python -m data_tools.bench_objects                     # Middlebury's motorcycle, resized
    python -m data_tools.bench_objects --sequence DIR      # the first frames of a KITTI layout

Parts: the detector (letterbox, yolov3-tiny through onnxruntime, decode, suppression) at each
`--input-size`; stereo range of one box at KITTI-like box sizes, and of a frame with all of them
(SGBM on the box's crop, median); for scale, SGBM on the whole frame. The default pair is
scikit-image's Middlebury motorcycle, its middle band resized to 1226x370 (real texture, real
stereo). Each figure is the best of `--repeat` runs. No assertions: this prints figures.
Needs `python -m data_tools.models install` for the detector part.
"""

from __future__ import annotations

import dataclasses
import os

# One core: no thread pools under numpy or OpenCV (set before they load).
for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from pipeline.datasets.kitti import StereoIntrinsics  # noqa: E402
from pipeline.frontend import objects as ob  # noqa: E402
from pipeline.frontend import stereo_range as sr  # noqa: E402
from pipeline.frontend.config import load_frontend_config  # noqa: E402

WIDTH, HEIGHT = 1226, 370
# KITTI 04-12's left camera (calib.txt).
KITTI = StereoIntrinsics(WIDTH, HEIGHT, 707.0912, 707.0912, 601.8873, 183.1104, 0.5372)
# Car boxes as KITTI shows them: far (~40 m) to near (~6 m), (width, height) px.
BOX_SIZES = [(40, 30), (80, 50), (120, 80), (200, 120), (320, 180)]


def motorcycle_pairs() -> list[tuple[np.ndarray, np.ndarray]]:
    from skimage.data import stereo_motorcycle

    left, right, _ = stereo_motorcycle()
    band = round(left.shape[1] * HEIGHT / WIDTH)
    top = (left.shape[0] - band) // 2
    pair = []
    for image in (left, right):
        grey = cv2.cvtColor(image[top : top + band], cv2.COLOR_RGB2GRAY)
        pair.append(cv2.resize(grey, (WIDTH, HEIGHT), interpolation=cv2.INTER_LINEAR))
    return [(pair[0], pair[1])]


def sequence_pairs(path: Path, count: int) -> list[tuple[np.ndarray, np.ndarray]]:
    from pipeline.datasets.kitti import KittiSequence

    sequence = KittiSequence(path)
    return [sequence[i] for i in range(min(count, len(sequence)))]


def best_time(run: Callable[[], object], repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        started = time.perf_counter()
        run()
        best = min(best, time.perf_counter() - started)
    return best


def boxes_for(image_shape: tuple[int, int]) -> list[tuple[float, float, float, float]]:
    """One box of each size, spread along the image's middle row."""
    height, width = image_shape
    boxes = []
    for i, (w, h) in enumerate(BOX_SIZES):
        cu = width * (i + 1) / (len(BOX_SIZES) + 1)
        cv = height / 2
        boxes.append((cu - w / 2, cv - h / 2, cu + w / 2, cv + h / 2))
    return boxes


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sequence", type=Path, help="a KITTI-layout sequence (first frames)")
    parser.add_argument("--frames", type=int, default=10)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument(
        "--input-size", action="append", default=None, help="WxH, repeatable (832x256, 416x416)"
    )
    args = parser.parse_args(argv)
    cv2.setNumThreads(1)
    sizes = args.input_size or ["832x256", "416x416"]

    pairs = sequence_pairs(args.sequence, args.frames) if args.sequence else motorcycle_pairs()
    frames = [pairs[i % len(pairs)] for i in range(args.frames)]
    shape = frames[0][0].shape
    print(f"{len(frames)} stereo pairs of {shape[1]}x{shape[0]}, one core\n")
    print(f"{'stage':34s} {'ms/frame':>10s} {'frames/s':>8s}")

    def row(name: str, seconds: float, count: int) -> None:
        print(f"{name:34s} {1e3 * seconds / count:10.1f} {count / seconds:8.1f}", flush=True)

    if ob.resolve_model_path(ob.DEFAULT_MODEL).exists():
        for size in sizes:
            width, height = (int(v) for v in size.lower().split("x"))
            config = dataclasses.replace(
                load_frontend_config().objects, input_size=(width, height), num_threads=1
            )
            detector = ob.ObjectDetector(config)
            detector.detect_boxes(frames[0][0])  # warm-up: onnxruntime plans on the first run
            seconds = best_time(
                lambda d=detector: [d.detect_boxes(f[0]) for f in frames], args.repeat
            )
            row(f"detect, yolov3-tiny {width}x{height}", seconds, len(frames))
    else:
        print("detector: no model (python -m data_tools.models install); skipped")

    config = load_frontend_config().objects.stereo
    boxes = boxes_for(shape)
    for box, (w, h) in zip(boxes, BOX_SIZES, strict=True):

        def one_box(b=box) -> None:
            for left, right in frames:
                sr.measure_box(left, right, b, KITTI, config)

        row(f"stereo range, one {w}x{h} box", best_time(one_box, args.repeat), len(frames))

    def all_boxes() -> None:
        for left, right in frames:
            for b in boxes:
                sr.measure_box(left, right, b, KITTI, config)

    row(f"stereo range, {len(boxes)} boxes a frame", best_time(all_boxes, args.repeat), len(frames))

    matcher = cv2.StereoSGBM.create(
        0, config.max_disparity, config.block_size, mode=cv2.StereoSGBM_MODE_SGBM_3WAY
    )
    whole = best_time(lambda: [matcher.compute(f[0], f[1]) for f in frames], min(args.repeat, 2))
    row(f"(whole-frame SGBM, {config.max_disparity} disparities)", whole, len(frames))
    return 0


if __name__ == "__main__":
    sys.exit(main())
