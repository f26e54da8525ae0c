"""The object-box stage on real images: speed on one core, score threshold, range accuracy.

    python -m data_tools.bench_objects                  # every part below
    python -m data_tools.bench_objects --thresholds     # only the threshold table

Parts:
- speed: the detector (letterbox, yolov3-tiny through onnxruntime, decode, suppression) at each
  `--input-size`; stereo range of one box at KITTI-like box sizes, and of a frame with all of
  them; for scale, SGBM on the whole frame. On the KITTI object frame of ../shared/data/real
  (colour, 1242x375), else on scikit-image's Middlebury motorcycle resized to 1226x370.
- thresholds: for each score threshold, the vehicles labelled by eye on real KITTI frames that
  get a box, the boxes on no vehicle (false), and the boxes on 96 real photos without vehicles
  (the shared tag photos and Middlebury's teddy). The configured threshold of a model is chosen
  from this table.
- the KITTI object frame: the stage's boxes at the configured threshold, and each one's range
  against the median range of the LiDAR points in the central part of its box (the part the
  stereo range uses), before the surface-to-centre offset.
- Middlebury's teddy: stereo range of a grid of boxes against the ground-truth disparity, how
  often the logged range sigma covers the error, and what boxes at the left border get.
Each speed figure is the best of `--repeat` runs. No assertions: this prints figures. Needs
`python -m data_tools.models install` for the detector parts.
"""

from __future__ import annotations

import data_tools.one_core  # noqa: F401 - first: one thread under numpy and OpenCV

# isort: split
import argparse
import dataclasses
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from pipeline.datasets.camera import StereoIntrinsics
from pipeline.datasets.kitti import (
    read_calibration,
    read_calibration_rows,
)
from pipeline.datasets.stereo import read_image, to_grey
from pipeline.frontend import objects as ob
from pipeline.frontend import stereo_range as sr
from pipeline.frontend.config import (
    ObjectDetectorConfig,
    StereoRangeConfig,
    load_frontend_config,
)

REAL_DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"
OBJECT_FRAME = REAL_DATA / "kitti-object-frame"
TEDDY = REAL_DATA / "middlebury-teddy"
WIDTH, HEIGHT = 1226, 370
# KITTI 04-12's left camera (calib.txt).
KITTI = StereoIntrinsics(WIDTH, HEIGHT, 707.0912, 707.0912, 601.8873, 183.1104, 0.5372)
# Car boxes as KITTI shows them: far (~40 m) to near (~6 m), (width, height) px.
BOX_SIZES = [(40, 30), (80, 50), (120, 80), (200, 120), (320, 180)]
THRESHOLDS = (0.1, 0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.5, 0.6, 0.7, 0.8)

Box = tuple[float, float, float, float]


@dataclass(frozen=True)
class LabelledImage:
    """A real image with its vehicles boxed by eye (u_min, v_min, u_max, v_max), and regions
    where a box is a vehicle too but vehicles are not told apart (far rows of parked cars)."""

    path: str  # under ../shared/data/real
    vehicles: tuple[Box, ...]
    regions: tuple[Box, ...] = ()


# Labelled by eye, zoomed in; vehicles of about 12 px and more.
LABELLED = (
    LabelledImage(
        "kitti-object-frame/left.png",
        vehicles=(
            (828, 190, 1242, 375),  # the estate car at the right
            (733, 183, 906, 308),  # the dark hatchback
            (686, 178, 772, 256),  # the red car
            (672, 178, 712, 222),  # the dark car beyond it
            (651, 180, 683, 213),  # the teal car
            (632, 178, 653, 204),  # the small dark car
            (628, 156, 666, 192),  # the white van
            (470, 182, 541, 234),  # the dark car on the left
            (527, 184, 548, 214),  # the car beyond it
            (556, 177, 582, 191),  # the far blue car
        ),
    ),
    LabelledImage(
        "kitti-clip-1/image_0/000000.png",
        vehicles=((713, 172, 845, 257), (645, 177, 686, 200), (281, 188, 326, 208)),
        regions=((40, 185, 140, 235),),
    ),
    LabelledImage(
        "kitti-clip-1/image_0/000020.png",
        vehicles=((727, 170, 866, 262),),
        regions=((255, 175, 390, 210),),
    ),
    LabelledImage(
        "kitti-clip-1/image_0/000030.png",
        vehicles=((238, 183, 298, 214),),
        regions=((130, 170, 360, 220),),
    ),
    LabelledImage(
        "kitti-clip-1/image_0/000040.png",
        vehicles=((0, 185, 85, 245), (75, 178, 170, 216)),
        regions=((0, 165, 280, 250),),
    ),
)


def vehicle_free_images() -> list[Path]:
    """Real photos without vehicles: the shared tag photos (an office) and Middlebury's teddy."""
    tags = [p for p in (REAL_DATA / "apriltag-photos").glob("*/*") if p.suffix.lower() == ".jpg"]
    return sorted(tags) + sorted(TEDDY.glob("im*.png"))


def inside(point: tuple[float, float], box: Box) -> bool:
    return box[0] <= point[0] <= box[2] and box[1] <= point[1] <= box[3]


@dataclass(frozen=True)
class ThresholdRow:
    threshold: float
    vehicles_found: int  # labelled vehicles with a box centred on them
    vehicles: int
    false_boxes: int  # boxes centred on no vehicle or vehicle region
    best_false: float  # the best score of a false box at the lowest threshold (nan if none)
    vehicle_free_boxes: int  # boxes on the photos without vehicles


def threshold_table(config: ObjectDetectorConfig, thresholds=THRESHOLDS) -> list[ThresholdRow]:
    """Boxes of the detector (before stereo) on the labelled images, threshold by threshold."""
    lowest = dataclasses.replace(config, thresholds={Path(config.model).name: min(thresholds)})
    detector = ob.ObjectDetector(lowest)
    labelled = [
        (item, detector.detect_boxes(read_image(REAL_DATA / item.path))) for item in LABELLED
    ]
    free = [
        b.score for path in vehicle_free_images() for b in detector.detect_boxes(read_image(path))
    ]
    false_scores = [
        box.score
        for item, boxes in labelled
        for box in boxes
        if not any(inside(_centre(box.bbox), v) for v in (*item.vehicles, *item.regions))
    ]
    rows = []
    for threshold in thresholds:
        found = sum(
            any(b.score >= threshold and inside(_centre(b.bbox), v) for b in boxes)
            for item, boxes in labelled
            for v in item.vehicles
        )
        rows.append(
            ThresholdRow(
                threshold,
                found,
                sum(len(item.vehicles) for item in LABELLED),
                sum(s >= threshold for s in false_scores),
                max(false_scores, default=float("nan")),
                sum(s >= threshold for s in free),
            )
        )
    return rows


def _centre(box: Box) -> tuple[float, float]:
    return (box[0] + box[2]) / 2.0, (box[1] + box[3]) / 2.0


# --- the KITTI object frame against its LiDAR --------------------------------------------------


def lidar_in_left_camera(root: Path = OBJECT_FRAME) -> tuple[np.ndarray, np.ndarray]:
    """The Velodyne points of a KITTI object frame in front of the left colour camera: their
    pixels (N, 2) and camera-frame points (N, 3), through Tr_velo_to_cam, R0_rect and P2."""
    m = read_calibration_rows(root / "calib.txt")
    p2 = m["P2"].reshape(3, 4)
    rectified = np.eye(4)
    rectified[:3, :3] = m["R0_rect"].reshape(3, 3)
    velodyne = np.eye(4)
    velodyne[:3] = m["Tr_velo_to_cam"].reshape(3, 4)
    points = np.fromfile(root / "lidar.bin", np.float32).reshape(-1, 4)[:, :3].astype(float)
    rect = np.c_[points, np.ones(len(points))] @ (rectified @ velodyne).T
    rect = rect[rect[:, 2] > 1.0]
    pixels = rect @ p2.T
    pixels = pixels[:, :2] / pixels[:, 2:]
    # P2 = K [I | t]: the colour camera sits at -t in the rectified frame.
    camera = rect[:, :3] + np.linalg.solve(p2[:, :3], p2[:, 3])
    return pixels, camera


def object_frame() -> tuple[np.ndarray, np.ndarray, StereoIntrinsics]:
    left, right = read_image(OBJECT_FRAME / "left.png"), read_image(OBJECT_FRAME / "right.png")
    height, width = left.shape[:2]
    intrinsics = read_calibration(OBJECT_FRAME / "calib.txt", width, height, ("P2", "P3"))
    return left, right, intrinsics


def central_part(box: Box, fraction: float) -> Box:
    """The central `fraction` of a box's width and height, as the stereo range uses it."""
    half_w, half_h = fraction * (box[2] - box[0]) / 2, fraction * (box[3] - box[1]) / 2
    cu, cv = _centre(box)
    return cu - half_w, cv - half_h, cu + half_w, cv + half_h


@dataclass(frozen=True)
class RangedCar:
    bbox: Box
    score: float
    range_m: float  # stereo range of the visible surface (before surface_to_centre)
    lidar_m: float  # median range of the LiDAR points in the box's central part
    lidar_points: int

    @property
    def error(self) -> float:
        return self.range_m / self.lidar_m - 1.0


def cars_on_object_frame(config: ObjectDetectorConfig) -> list[RangedCar]:
    """The object stage on the KITTI object frame, each box against the LiDAR."""
    left, right, intrinsics = object_frame()
    pixels, points = lidar_in_left_camera()
    ranges = np.linalg.norm(points, axis=1)
    cars = []
    for record in ob.ObjectDetector(config).detect(left, right, intrinsics):
        part = central_part(record.bbox, config.stereo.central_fraction)
        mask = (pixels[:, 0] >= part[0]) & (pixels[:, 0] <= part[2])
        mask &= (pixels[:, 1] >= part[1]) & (pixels[:, 1] <= part[3])
        surface = float(np.linalg.norm(record.point)) - config.stereo.surface_to_centre
        lidar = float(np.median(ranges[mask])) if mask.any() else float("nan")
        cars.append(RangedCar(record.bbox, record.score, surface, lidar, int(mask.sum())))
    return cars


# --- Middlebury's teddy: a grid of boxes -------------------------------------------------------

# Teddy's quarter-size pair: disparities up to 53 px; a focal length and baseline of its
# scale (only their product matters to relative errors).
TEDDY_INTRINSICS_F, TEDDY_BASELINE = 935.0, 0.16
TEDDY_BOX_SIZES = ((30, 40), (60, 60), (100, 80), (150, 120))


@dataclass(frozen=True)
class GridCoverage:
    boxes: int  # boxes whose central part has ground truth
    ranged: int
    within_3_sigma: int  # ranged boxes whose range error is within 3 logged sigmas
    confident_and_wrong: int  # ranged boxes off by more than 20 % and by more than 3 sigmas
    border_boxes: int  # boxes at the left border no wider than the scene's disparities
    border_ranged: int


def teddy_grid(config: StereoRangeConfig, step: int = 15) -> GridCoverage:
    """Stereo range of a grid of boxes over teddy against its ground-truth disparity (the median
    over the box's central part; `disp2.png` holds 4x the disparity, 0 where unknown)."""
    left, right = to_grey(read_image(TEDDY / "im2.png")), to_grey(read_image(TEDDY / "im6.png"))
    truth = to_grey(read_image(TEDDY / "disp2.png")).astype(float) / 4.0
    truth[truth == 0] = np.nan
    height, width = left.shape
    k = StereoIntrinsics(
        width, height, TEDDY_INTRINSICS_F, TEDDY_INTRINSICS_F, width / 2, height / 2,
        TEDDY_BASELINE,
    )  # fmt: skip
    config = dataclasses.replace(
        config, max_disparity=64, surface_to_centre=0.0, surface_to_centre_sigma=0.0
    )
    counts = dict(boxes=0, ranged=0, within=0, wrong=0, border=0, border_ranged=0)
    widest_border_box = int(np.nanmax(truth))
    for box_width, box_height in TEDDY_BOX_SIZES:
        for u0 in range(0, width - box_width + 1, step):
            for v0 in range(0, height - box_height + 1, 2 * step):
                box = (u0, v0, u0 + box_width, v0 + box_height)
                cu0, cv0, cu1, cv1 = sr.central_box(box, config.central_fraction, width, height)
                expected = sr.robust_disparity(truth[cv0:cv1, cu0:cu1], config)
                if expected is None:
                    continue
                found = sr.measure_box(left, right, box, k, config)
                border = u0 == 0 and box_width <= widest_border_box
                counts["boxes"] += 1
                counts["border"] += border
                if found is None:
                    continue
                counts["ranged"] += 1
                counts["border_ranged"] += border
                true_uvd = np.array([found.uvd[0], found.uvd[1], expected.disparity])
                true_range = float(np.linalg.norm(sr.triangulate(true_uvd, k)))
                ray = found.point / np.linalg.norm(found.point)
                sigma = float(np.sqrt(ray @ found.covariance @ ray))
                error = abs(found.range - true_range)
                counts["within"] += error <= 3 * sigma
                counts["wrong"] += error > 3 * sigma and error > 0.2 * true_range
    return GridCoverage(
        counts["boxes"],
        counts["ranged"],
        counts["within"],
        counts["wrong"],
        counts["border"],
        counts["border_ranged"],
    )


# --- speed -------------------------------------------------------------------------------------


def motorcycle_pairs() -> list[tuple[np.ndarray, np.ndarray]]:
    from skimage.data import stereo_motorcycle

    left, right, _ = stereo_motorcycle()
    band = round(left.shape[1] * HEIGHT / WIDTH)
    top = (left.shape[0] - band) // 2
    pair = []
    for image in (left, right):
        bgr = cv2.cvtColor(image[top : top + band], cv2.COLOR_RGB2BGR)
        pair.append(cv2.resize(bgr, (WIDTH, HEIGHT), interpolation=cv2.INTER_LINEAR))
    return [(pair[0], pair[1])]


def best_time(run: Callable[[], object], repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        started = time.process_time()
        run()
        best = min(best, time.process_time() - started)
    return best


def boxes_for(image_shape: tuple[int, ...]) -> list[Box]:
    """One box of each size, spread along the image's middle row."""
    height, width = image_shape[:2]
    boxes = []
    for i, (w, h) in enumerate(BOX_SIZES):
        cu = width * (i + 1) / (len(BOX_SIZES) + 1)
        cv = height / 2
        boxes.append((cu - w / 2, cv - h / 2, cu + w / 2, cv + h / 2))
    return boxes


def print_speed(frames: list[tuple[np.ndarray, np.ndarray]], sizes: list[str], repeat: int) -> None:
    shape = frames[0][0].shape
    print(f"\n{len(frames)} stereo pairs of {shape[1]}x{shape[0]}, one core, CPU time")
    print(f"{'stage':34s} {'ms/frame':>10s} {'frames/s':>8s}")

    def row(name: str, seconds: float, count: int) -> None:
        print(f"{name:34s} {1e3 * seconds / count:10.1f} {count / seconds:8.1f}", flush=True)

    for size in sizes:
        width, height = (int(v) for v in size.lower().split("x"))
        config = dataclasses.replace(
            load_frontend_config().objects, input_size=(width, height), num_threads=1
        )
        detector = ob.ObjectDetector(config)
        detector.detect_boxes(frames[0][0])  # warm-up: onnxruntime plans on the first run
        seconds = best_time(lambda d=detector: [d.detect_boxes(f[0]) for f in frames], repeat)
        row(f"detect, yolov3-tiny {width}x{height}", seconds, len(frames))

    config = load_frontend_config().objects.stereo
    boxes = boxes_for(shape)
    for box, (w, h) in zip(boxes, BOX_SIZES, strict=True):

        def one_box(b=box) -> None:
            for left, right in frames:
                sr.measure_box(left, right, b, KITTI, config)

        row(f"stereo range, one {w}x{h} box", best_time(one_box, repeat), len(frames))

    def all_boxes() -> None:
        for left, right in frames:
            for b in boxes:
                sr.measure_box(left, right, b, KITTI, config)

    row(f"stereo range, {len(boxes)} boxes a frame", best_time(all_boxes, repeat), len(frames))
    matcher = cv2.StereoSGBM.create(
        0, config.max_disparity, config.block_size, mode=cv2.StereoSGBM_MODE_SGBM_3WAY
    )
    grey = [(to_grey(a), to_grey(b)) for a, b in frames]
    whole = best_time(lambda: [matcher.compute(a, b) for a, b in grey], min(repeat, 2))
    row(f"(whole-frame SGBM, {config.max_disparity} disparities)", whole, len(frames))


def print_thresholds(config: ObjectDetectorConfig) -> None:
    rows = threshold_table(config)
    free = len(vehicle_free_images())
    print(
        f"\nscore thresholds of {Path(config.model).name} at {config.input_size[0]}x"
        f"{config.input_size[1]}: {len(LABELLED)} real KITTI frames labelled by eye "
        f"({rows[0].vehicles} vehicles), {free} real photos without vehicles "
        f"(best false box on the labelled frames: {rows[0].best_false:.2f})"
    )
    print(
        f"  {'threshold':>9s} {'vehicles found':>15s} {'false boxes':>12s} {'on vehicle-free':>16s}"
    )
    for r in rows:
        print(
            f"  {r.threshold:9.2f} {f'{r.vehicles_found} of {r.vehicles}':>15s} "
            f"{r.false_boxes:12d} {r.vehicle_free_boxes:16d}"
        )
    print(f"  configured: {config.confidence_threshold}")


def print_object_frame(config: ObjectDetectorConfig) -> None:
    cars = cars_on_object_frame(config)
    print(
        f"\nKITTI object frame ({OBJECT_FRAME}), threshold {config.confidence_threshold}: "
        f"{len(cars)} boxes; surface range against the LiDAR median in the central part"
    )
    header = ("box", "score", "stereo m", "LiDAR m", "points", "error")
    print("  " + " ".join(f"{h:>{w}s}" for h, w in zip(header, (26, 6, 9, 8, 7, 7), strict=True)))
    for car in cars:
        box = "[" + " ".join(f"{v:.0f}" for v in car.bbox) + "]"
        print(
            f"  {box:>26s} {car.score:6.2f} {car.range_m:9.2f} {car.lidar_m:8.2f} "
            f"{car.lidar_points:7d} {100 * car.error:+6.1f}%"
        )


def print_teddy(config: StereoRangeConfig) -> None:
    g = teddy_grid(config)
    print(
        f"\nMiddlebury teddy ({TEDDY}), a grid of {g.boxes} boxes: {g.ranged} ranged, "
        f"{g.within_3_sigma} ({100 * g.within_3_sigma / g.ranged:.1f} %) within 3 logged sigmas "
        f"of the true range, {g.confident_and_wrong} off by > 20 % and > 3 sigmas; "
        f"{g.border_ranged} of {g.border_boxes} narrow boxes at the left border ranged"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=10, help="pairs to time (the same pair)")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--thresholds", action="store_true", help="only the threshold table")
    parser.add_argument(
        "--input-size", action="append", default=None, help="WxH, repeatable (832x256, 416x416)"
    )
    args = parser.parse_args(argv)
    cv2.setNumThreads(1)
    config = load_frontend_config().objects
    have_model = config.model_path.exists()
    have_data = OBJECT_FRAME.is_dir() and TEDDY.is_dir()
    if not have_model:
        print("\nobject detector: no model (python -m data_tools.models install); skipped")
    if args.thresholds:
        if have_model and have_data:
            print_thresholds(config)
        return 0
    pair = object_frame()[:2] if OBJECT_FRAME.is_dir() else motorcycle_pairs()[0]
    sizes = (args.input_size or ["832x256", "416x416"]) if have_model else []
    print_speed([pair] * args.frames, sizes, args.repeat)
    if have_data:
        print_teddy(config.stereo)
        if have_model:
            print_thresholds(config)
            print_object_frame(config)
    else:
        print(f"\n{REAL_DATA}: absent; the real-data parts are skipped")
    return 0


if __name__ == "__main__":
    sys.exit(main())
