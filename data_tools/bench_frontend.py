"""Frames per second of each front-end stage on one core, and its accuracy on real data.

    python -m data_tools.bench_frontend                       # ../shared/data/real/kitti-clip-1
    python -m data_tools.bench_frontend --sequence out/seq    # any KITTI-layout sequence
    python -m data_tools.bench_frontend --odometry            # VO drift and NEES per clip
    python -m data_tools.bench_frontend --odometry --real DIR # ... and on another real clip

Without `--sequence`, the real KITTI clip in ../shared/data/real is used (1226 x 370), or where
it is absent the renderer's `kitti-size` preset is rendered into a temporary directory (about a
second a frame). Frames are read into memory before timing, so disk and PNG decoding are timed
apart ("read"). Every stage runs `--repeat` times over all frames; the best run is reported
(the least disturbed by other processes), with wall-clock and CPU time. No assertions: this
prints figures.

Accuracy, where the sequence has `poses.txt`: the keyframe steps of visual odometry against
the true motions, over every frame and over every 2nd, 3rd, ... frame (`--every`: faster motion,
the hard case), as end-point drift (% of the path), the worst step's translation error, and the
median NEES (squared error over the stated covariance) of the whole 6-DoF step (its median 5.35
when the covariance is honest), of its translation and of its rotation (2.37 each). `--odometry`
prints only these, over every frame and every 2nd and 3rd frame, on kitti-clip-1, on any other
real KITTI-layout clip with `poses.txt` given with `--real` (read from where it is: nothing is
downloaded), and on rendered drives: those the covariance was calibrated on (the demo drive
at pixel noise 0.5-8, seed 0; with a real clip outside the project, see configs/frontend.toml)
and others (other seeds and noise levels, the corridor, the KITTI-size render).
Rendered sequences (`landmarks.json`) also get every tag measured against the true corners and
the true centre's range. With the shared tag photos: recall of the front-end's tag detector
against libapriltag at full resolution (its defaults otherwise: no blur, refined edges,
sharpening 0.25), and its detections on real images without tags.
"""

from __future__ import annotations

import data_tools.one_core  # noqa: F401 - first: one thread under numpy and OpenCV

# isort: split
import argparse
import json
import logging
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from pipeline.datasets.camera import StereoIntrinsics
from pipeline.datasets.kitti import KittiSequence, camera_poses_to_body
from pipeline.datasets.stereo import read_grey
from pipeline.frontend import geometry as g
from pipeline.frontend.apriltags import (
    LIBAPRILTAG_PIXEL_OFFSET,
    AprilTagDetector,
    LibapriltagDetector,
    tag_detection,
)
from pipeline.frontend.config import FrontendConfig, load_frontend_config
from pipeline.frontend.ground_truth import LANDMARKS_FILE, read_landmarks
from pipeline.frontend.stereo_vo import KeyframeStep, StereoOdometry

log = logging.getLogger(__name__)

REAL_DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"
REAL_CLIP = REAL_DATA / "kitti-clip-1"
TAG_PHOTOS = REAL_DATA / "apriltag-photos"
# Real images without tags: street frames, the Middlebury pair.
NON_TAG_IMAGES = ("kitti-clip-1/image_0/*.png", "kitti-object-frame/*.png", "middlebury-teddy/im*")
# A tag of libapriltag's is found again if one of ours has its id and a centre this close (px).
SAME_TAG_PX = 5.0


@dataclass(frozen=True)
class Timing:
    stage: str
    frames: int
    wall_s: float
    cpu_s: float

    @property
    def wall_fps(self) -> float:
        return self.frames / self.wall_s

    @property
    def cpu_fps(self) -> float:
        return self.frames / self.cpu_s


def best_of(stage: str, frames: int, repeat: int, run: Callable[[], object]) -> Timing:
    timings = []
    for _ in range(repeat):
        wall, cpu = time.perf_counter(), time.process_time()
        run()
        timings.append(Timing(stage, frames, time.perf_counter() - wall, time.process_time() - cpu))
    return min(timings, key=lambda t: t.wall_s)


def bench(sequence: KittiSequence, repeat: int, config_path: Path | None) -> list[Timing]:
    cv2.setNumThreads(1)
    config = load_frontend_config(config_path)
    count = len(sequence)
    frames = [sequence[i] for i in range(count)]
    timings = [best_of("read (2 PNG)", count, 1, lambda: [sequence[i] for i in range(count)])]

    keyframes: list[int] = []

    def odometry() -> None:
        vo = StereoOdometry(sequence.intrinsics, config.vo, config.keyframes)
        keyframes.clear()
        for index, (left, right) in enumerate(frames):
            if vo.process(index, left, right) is not None or index == 0:
                keyframes.append(index)

    timings.append(best_of("visual odometry", count, repeat, odometry))
    tags = AprilTagDetector(config.apriltags, sequence.intrinsics)
    timings.append(
        best_of(
            "tags: left detection", count, repeat, lambda: [tags.detect_image(f[0]) for f in frames]
        )
    )
    timings.append(
        best_of(
            "tags: stereo measurement", count, repeat, lambda: [tags.observe(*f) for f in frames]
        )
    )
    # The pipeline runs tags at keyframes only: per input frame, VO + tags at that share.
    vo, stereo_tags = timings[1], timings[3]
    share = len(keyframes) / count
    timings.append(
        Timing(
            "tags every frame + VO",
            count,
            vo.wall_s + stereo_tags.wall_s,
            vo.cpu_s + stereo_tags.cpu_s,
        )
    )
    timings.append(
        Timing(
            f"tags at keyframes ({share:.0%}) + VO",
            count,
            vo.wall_s + share * stereo_tags.wall_s,
            vo.cpu_s + share * stereo_tags.cpu_s,
        )
    )
    return timings


# --- visual odometry against ground truth ----------------------------------------------------


def step_error(step: KeyframeStep, true_motion: np.ndarray) -> np.ndarray:
    """A step's error against the true body motion in its tangent space, `(rx, ry, rz, tx,
    ty, tz)` of `Log(step^-1 true)`: the right perturbation its covariance is stated over."""
    delta = np.linalg.inv(step.motion) @ true_motion
    return np.concatenate([g.so3_log(delta[:3, :3]), delta[:3, 3]])


def nees(error: np.ndarray, covariance: np.ndarray) -> float:
    """Normalised estimation error squared: `e^T C^-1 e` (its median is 2.37 over 3 degrees of
    freedom and 5.35 over 6 when the covariance is honest)."""
    return float(error @ np.linalg.solve(covariance, error))


@dataclass(frozen=True)
class OdometryFigures:
    steps: int
    lost: int
    recovered: int
    path_m: float
    drift_percent: float  # end-point error of the chained steps, % of the true path
    worst_step_m: float  # the largest translation error of a step not logged as lost
    # NEES of the steps not logged as lost: the whole 6-DoF step, and its translation and
    # rotation apart.
    pose_nees_median: float
    translation_nees_median: float
    translation_nees_max: float
    rotation_nees_median: float


def odometry_figures(
    sequence: KittiSequence, config: FrontendConfig, every: int = 1
) -> OdometryFigures:
    """Visual odometry over every `every`-th frame of a sequence with ground truth, against
    it."""
    truth = camera_poses_to_body(sequence.gt_poses)
    frames = list(range(0, len(sequence), every))
    vo = StereoOdometry(sequence.intrinsics, config.vo, config.keyframes)
    steps = [vo.process(k, *sequence[frame]) for k, frame in enumerate(frames)]
    steps = [s for s in [*steps, vo.finish()] if s is not None]
    estimate, path, previous = np.eye(4), 0.0, 0
    errors, pose, translation, rotation = [], [], [], []
    for step in steps:
        true_motion = np.linalg.inv(truth[frames[previous]]) @ truth[frames[step.frame_index]]
        if not step.lost:
            error = step_error(step, true_motion)
            errors.append(float(np.linalg.norm(error[3:])))
            pose.append(nees(error, step.covariance))
            translation.append(nees(error[3:], step.covariance[3:, 3:]))
            rotation.append(nees(error[:3], step.covariance[:3, :3]))
        estimate = estimate @ step.motion
        path += float(np.linalg.norm(true_motion[:3, 3]))
        previous = step.frame_index
    drift = np.linalg.norm(estimate[:3, 3] - truth[frames[previous]][:3, 3])

    def median(values: list[float]) -> float:
        return float(np.median(values)) if values else float("nan")

    return OdometryFigures(
        steps=len(steps),
        lost=vo.lost_count,
        recovered=vo.recovered_count,
        path_m=path,
        drift_percent=100.0 * drift / path,
        worst_step_m=max(errors, default=float("nan")),
        pose_nees_median=median(pose),
        translation_nees_median=median(translation),
        translation_nees_max=max(translation, default=float("nan")),
        rotation_nees_median=median(rotation),
    )


def tag_accuracy(sequence: KittiSequence, config: FrontendConfig) -> dict[str, float]:
    truth = camera_poses_to_body(sequence.gt_poses)
    landmarks = {lm.tag_id: lm for lm in read_landmarks(sequence.root / LANDMARKS_FILE)}
    corners_doc = {
        entry["tag_id"]: np.array(entry["corners"])
        for entry in json.loads((sequence.root / LANDMARKS_FILE).read_text())["landmarks"]
        if entry["kind"] == "tag"
    }
    tags = AprilTagDetector(config.apriltags, sequence.intrinsics)
    corner_errors, range_errors, relative, nees, unknown = [], [], [], [], 0
    for index in range(len(sequence)):
        camera_from_body0 = np.linalg.inv(truth[index] @ g.BODY_FROM_CAMERA)
        for observation in tags.observe(*sequence[index]):
            if observation.tag_id not in landmarks:
                unknown += 1
                continue
            corners = corners_doc[observation.tag_id] @ camera_from_body0[:3, :3].T
            corners = g.project(corners + camera_from_body0[:3, 3], sequence.intrinsics)
            corner_errors.extend(np.linalg.norm(observation.corners - corners, axis=1))
            detection = tag_detection(observation, sequence.intrinsics, 1, 100.0)
            point = np.linalg.inv(truth[index]) @ np.r_[landmarks[observation.tag_id].position, 1]
            true = g.bearing_elevation_range(point[:3])
            error = np.array([detection.bearing, detection.elevation, detection.range]) - true
            range_errors.append(abs(error[2]))
            relative.append(abs(error[2]) / true[2])
            nees.append(error @ np.linalg.solve(np.reshape(detection.covariance, (3, 3)), error))
    return {
        "tag measurements": len(range_errors),
        "false tags": unknown,
        "dropped (not measurable in the right image)": tags.dropped,
        "corner error median (px)": np.median(corner_errors),
        "corner error p95 (px)": np.percentile(corner_errors, 95),
        "range error median (m)": np.median(range_errors),
        "range error p95 (m)": np.percentile(range_errors, 95),
        "range error max (m)": np.max(range_errors),
        "range error median (% of range)": 100 * np.median(relative),
        "range error p95 (% of range)": 100 * np.percentile(relative, 95),
        "NEES mean (3 = calibrated)": np.mean(nees),
    }


# --- tags on real photos ---------------------------------------------------------------------


@dataclass(frozen=True)
class TagRecall:
    images: int
    reference: int  # tags libapriltag finds at full resolution
    found: int  # of those, found by the front-end's detector
    extra: int  # the front-end's detections libapriltag does not have

    @property
    def recall(self) -> float:
        return self.found / self.reference


def tag_recall(photos: Sequence[Path], config: FrontendConfig) -> TagRecall:
    """The front-end's tag detector (`detect_image`, its decode checks included) against
    libapriltag at full resolution with its own defaults otherwise, photo by photo."""
    reference = LibapriltagDetector(
        families=config.apriltags.family,
        nthreads=1,
        quad_decimate=1.0,
        quad_sigma=0.0,
        refine_edges=1,
        decode_sharpening=0.25,
    )
    ours = AprilTagDetector(config.apriltags, StereoIntrinsics(1, 1, 1.0, 1.0, 0.5, 0.5, 1.0))
    total = found = extra = 0
    for photo in photos:
        image = read_grey(photo)
        expected = reference.detect(image)
        sightings = ours.detect_image(image)
        unused = list(range(len(sightings)))
        for tag in expected:
            for k in unused:
                centre = sightings[k].centre + LIBAPRILTAG_PIXEL_OFFSET
                if (
                    sightings[k].tag_id == tag.tag_id
                    and np.linalg.norm(centre - tag.center) < SAME_TAG_PX
                ):
                    unused.remove(k)
                    found += 1
                    break
        total += len(expected)
        extra += len(unused)
    return TagRecall(len(photos), total, found, extra)


def tags_on_images(images: Sequence[Path], config: FrontendConfig) -> int:
    """How many tags the front-end's detector reports on these images."""
    ours = AprilTagDetector(config.apriltags, StereoIntrinsics(1, 1, 1.0, 1.0, 0.5, 0.5, 1.0))
    return sum(len(ours.detect_image(read_grey(path))) for path in images)


def shared_tag_photos() -> list[Path]:
    return sorted(p for p in TAG_PHOTOS.glob("*/*") if p.suffix.lower() in (".jpg", ".png"))


def shared_non_tag_images() -> list[Path]:
    return sorted(p for pattern in NON_TAG_IMAGES for p in REAL_DATA.glob(pattern))


def render_kitti_size(frames: int, root: Path) -> Path:
    from data_tools.render import render_sequence

    log.info("rendering %d kitti-size frames (about a second each)", frames)
    return render_sequence("kitti-size", root / "kitti-size", seed=0, num_frames=frames)


ODOMETRY_HEADER = (
    f"  {'clip':44s} {'steps':>5s} {'path m':>7s} {'drift %':>8s} {'worst cm':>9s} "
    f"{'NEES 6-DoF':>10s} {'transl.':>8s} {'rot.':>6s} {'lost':>5s} {'found again':>11s}"
)


def odometry_line(name: str, f: OdometryFigures) -> str:
    return (
        f"  {name:44s} {f.steps:5d} {f.path_m:7.1f} {f.drift_percent:8.2f} "
        f"{100 * f.worst_step_m:9.1f} {f.pose_nees_median:10.2f} "
        f"{f.translation_nees_median:8.2f} {f.rotation_nees_median:6.2f} {f.lost:5d} "
        f"{f.recovered:11d}"
    )


def print_odometry(sequence: KittiSequence, config: FrontendConfig, every: list[int]) -> None:
    print(
        f"\nvisual odometry against poses.txt ({sequence.root}); median NEES (honest: 5.35 "
        "6-DoF, 2.37 translation or rotation)"
    )
    print(ODOMETRY_HEADER)
    for step in every:
        name = "every frame" if step == 1 else f"1 frame in {step}"
        print(odometry_line(name, odometry_figures(sequence, config, step)))


# The clips the VO covariance is calibrated and checked on (configs/frontend.toml, [vo]): the
# real KITTI clip and the renderer's drives at several pixel noise levels (grey levels), each
# (preset, noise, seed, frames, used to calibrate).
RENDERED_CLIPS = (
    ("demo", 0.5, 0, 80, True),
    ("demo", 2.0, 0, 80, True),
    ("demo", 4.0, 0, 80, True),
    ("demo", 8.0, 0, 80, True),
    ("demo", 1.0, 1, 80, False),
    ("demo", 6.0, 2, 80, False),
    ("corridor", 1.0, 0, 80, False),
    ("corridor", 3.0, 1, 80, False),
    ("kitti-size", 1.0, 0, 40, False),
)


def render_with_noise(preset: str, noise: float, seed: int, frames: int, root: Path) -> Path:
    """A renderer preset with its pixel noise changed, rendered into `root`."""
    import re

    from data_tools.render import render_sequence
    from data_tools.renderer.config import preset_path

    name = f"{preset}-noise{noise:g}-seed{seed}"
    text = preset_path(preset).read_text()
    text, count = re.subn(r"(?m)^noise_sigma = \S+", f"noise_sigma = {noise!r}", text)
    if count != 1:
        raise RuntimeError(f"preset {preset}: no single noise_sigma line")
    changed = root / f"{name}.toml"
    changed.write_text(text)
    return render_sequence(changed, root / name, seed=seed, num_frames=frames)


# Frame steps the odometry figures are given at: every frame, and every 2nd and 3rd frame (the
# same drive two and three times as fast).
ODOMETRY_STEPS = (1, 2, 3)


def print_clip_steps(name: str, sequence: KittiSequence, config: FrontendConfig) -> None:
    for every in ODOMETRY_STEPS:
        label = name + ("" if every == 1 else f", 1 frame in {every}")
        print(odometry_line(label, odometry_figures(sequence, config, every)), flush=True)


def print_odometry_clips(config: FrontendConfig, root: Path, real: Sequence[Path] = ()) -> None:
    """Drift, worst step and median NEES on every clip of the covariance's calibration and
    check: kitti-clip-1 (if present), the `real` KITTI-layout clips and the rendered ones."""
    print(
        "\nvisual odometry: drift, worst step and median NEES per clip (honest: 5.35 6-DoF, "
        "2.37 translation or rotation); * = used to calibrate the covariance"
    )
    print(ODOMETRY_HEADER)
    if (REAL_CLIP / "poses.txt").exists():
        print_clip_steps("kitti-clip-1", KittiSequence(REAL_CLIP), config)
    else:
        print(f"  {REAL_CLIP} is absent: real clip skipped")
    for path in real:
        print_clip_steps(path.name, KittiSequence(path), config)
    for preset, noise, seed, frames, calibrating in RENDERED_CLIPS:
        log.info("rendering %s at noise %g, seed %d (%d frames)", preset, noise, seed, frames)
        sequence = KittiSequence(render_with_noise(preset, noise, seed, frames, root))
        name = f"{preset}, noise {noise:g}, seed {seed}" + (" *" if calibrating else "")
        print_clip_steps(name, sequence, config)


def print_tags(config: FrontendConfig) -> None:
    photos = shared_tag_photos()
    if not photos:
        print(f"\ntags: no photos in {TAG_PHOTOS}; skipped")
        return
    result = tag_recall(photos, config)
    print(
        f"\ntags on {result.images} real photos ({TAG_PHOTOS}): libapriltag at full resolution "
        f"finds {result.reference}, the front-end {result.found} of them "
        f"({100 * result.recall:.1f} %) and {result.extra} others"
    )
    others = shared_non_tag_images()
    print(f"tags on {len(others)} real images without tags: {tags_on_images(others, config)}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m data_tools.bench_frontend",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--sequence", type=Path, help="a KITTI-layout sequence")
    parser.add_argument("--frames", type=int, default=60, help="frames to render or use (60)")
    parser.add_argument("--repeat", type=int, default=3, help="runs of each stage; best kept")
    parser.add_argument("--every", default="1,2,3,4,6", help="odometry on every n-th frame")
    parser.add_argument("--config", type=Path, help="front-end TOML over configs/frontend.toml")
    parser.add_argument(
        "--odometry",
        action="store_true",
        help="only the VO figures (drift, worst step, NEES) on the covariance's calibration "
        "and check clips: kitti-clip-1 and rendered drives (renders ~1.5 min)",
    )
    parser.add_argument(
        "--real",
        type=Path,
        action="append",
        default=[],
        metavar="DIR",
        help="with --odometry: another real KITTI-layout clip with poses.txt (repeatable)",
    )
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(message)s")
    cv2.setNumThreads(1)
    config = load_frontend_config(args.config)
    if args.real and not args.odometry:
        parser.error("--real goes with --odometry")
    for path in args.real:
        if not (path / "poses.txt").is_file():
            parser.error(f"--real {path}: no poses.txt there (a KITTI-layout clip with truth)")
    if args.odometry:
        with tempfile.TemporaryDirectory(prefix="mmslam-bench-") as scratch:
            print_odometry_clips(config, Path(scratch), args.real)
        return 0
    with tempfile.TemporaryDirectory(prefix="mmslam-bench-") as scratch:
        root = args.sequence
        if root is None:
            root = (
                REAL_CLIP if REAL_CLIP.is_dir() else render_kitti_size(args.frames, Path(scratch))
            )
        sequence = KittiSequence(root)
        if args.frames < len(sequence):
            sequence.left_files = sequence.left_files[: args.frames]
            sequence.right_files = sequence.right_files[: args.frames]
        size = f"{sequence.intrinsics.width}x{sequence.intrinsics.height}"
        timings = bench(sequence, args.repeat, args.config)
        print(
            f"\n{len(sequence)} stereo frames of {size} ({root}), one thread, best of {args.repeat}"
        )
        print(f"{'stage':34s} {'frames/s':>9s} {'ms/frame':>9s} {'CPU frames/s':>13s}")
        for t in timings:
            print(f"{t.stage:34s} {t.wall_fps:9.1f} {1000 / t.wall_fps:9.1f} {t.cpu_fps:13.1f}")
        if sequence.gt_poses is not None:
            print_odometry(sequence, config, [int(v) for v in args.every.split(",")])
            if (sequence.root / LANDMARKS_FILE).exists():
                print("tags against landmarks.json (every frame)")
                for name, value in tag_accuracy(sequence, config).items():
                    print(f"  {name:44s} {value:10.3f}")
    print_tags(config)
    return 0


if __name__ == "__main__":
    sys.exit(main())
