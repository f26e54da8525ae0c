"""Frames per second of each front-end stage on one core, and its accuracy where the sequence
has ground truth.

    python -m data_tools.bench_frontend                       # renders 30 kitti-size frames
    python -m data_tools.bench_frontend --sequence out/seq    # any KITTI-layout sequence

Without `--sequence`, the renderer's `kitti-size` preset (1226 x 370, KITTI's camera) is
rendered into a temporary directory first (about a second a frame). Frames are read into memory
before timing, so disk and PNG decoding are timed apart ("read"). Every stage runs `--repeat`
times over all frames; the best run is reported (the least disturbed by other processes), with
wall-clock and CPU time. No assertions: this prints figures.

Accuracy (with `poses.txt`, and `landmarks.json` for tags, as rendered sequences have): the
keyframe motions against the true ones, and every tag measured in every frame against the true
corners (projected) and the true centre's range. NEES = squared error over the stated
covariance (expected: 6 for motions, 3 for tag points).
"""

from __future__ import annotations

import os

# One core: no thread pools under numpy or OpenCV (set before they load).
for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import logging  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from pipeline.datasets.kitti import KittiSequence, camera_poses_to_body  # noqa: E402
from pipeline.frontend import geometry as g  # noqa: E402
from pipeline.frontend.apriltags import AprilTagDetector, tag_detection  # noqa: E402
from pipeline.frontend.config import FrontendConfig, load_frontend_config  # noqa: E402
from pipeline.frontend.ground_truth import LANDMARKS_FILE, read_landmarks  # noqa: E402
from pipeline.frontend.stereo_vo import StereoOdometry  # noqa: E402

log = logging.getLogger(__name__)


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


def odometry_accuracy(sequence: KittiSequence, config: FrontendConfig) -> dict[str, float]:
    truth = camera_poses_to_body(sequence.gt_poses)
    vo = StereoOdometry(sequence.intrinsics, config.vo, config.keyframes)
    steps = [vo.process(i, *sequence[i]) for i in range(len(sequence))]
    steps = [s for s in steps if s is not None]
    translation, rotation, nees, previous = [], [], [], 0
    estimate, path = np.eye(4), 0.0
    for step in steps:
        true_motion = np.linalg.inv(truth[previous]) @ truth[step.frame_index]
        delta = np.linalg.inv(step.motion) @ true_motion
        error = np.concatenate([g.so3_log(delta[:3, :3]), delta[:3, 3]])
        translation.append(np.linalg.norm(error[3:]))
        rotation.append(np.linalg.norm(error[:3]))
        nees.append(error @ np.linalg.solve(step.covariance, error))
        estimate, path = estimate @ step.motion, path + np.linalg.norm(true_motion[:3, 3])
        previous = step.frame_index
    drift = np.linalg.norm(estimate[:3, 3] - truth[previous][:3, 3])
    return {
        "keyframes": len(steps) + 1,
        "step length mean (m)": path / max(len(steps), 1),
        "translation error mean (cm)": 100 * np.mean(translation),
        "translation error max (cm)": 100 * np.max(translation),
        "rotation error mean (deg)": np.degrees(np.mean(rotation)),
        "rotation error max (deg)": np.degrees(np.max(rotation)),
        "end-point drift (% of path)": 100 * drift / path,
        "NEES mean (6 = calibrated)": np.mean(nees),
        "tracking losses": vo.lost_count,
    }


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


def render_kitti_size(frames: int, root: Path) -> Path:
    from data_tools.render import render_sequence

    log.info("rendering %d kitti-size frames (about a second each)", frames)
    return render_sequence("kitti-size", root / "kitti-size", seed=0, num_frames=frames)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m data_tools.bench_frontend",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--sequence", type=Path, help="a KITTI-layout sequence (else rendered)")
    parser.add_argument("--frames", type=int, default=30, help="frames to render or use (30)")
    parser.add_argument("--repeat", type=int, default=3, help="runs of each stage; best kept")
    parser.add_argument("--config", type=Path, help="front-end TOML over configs/frontend.toml")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    with tempfile.TemporaryDirectory(prefix="mmslam-bench-") as scratch:
        root = args.sequence or render_kitti_size(args.frames, Path(scratch))
        sequence = KittiSequence(root)
        if args.sequence is not None and args.frames < len(sequence):
            sequence.left_files = sequence.left_files[: args.frames]
            sequence.right_files = sequence.right_files[: args.frames]
        size = f"{sequence.intrinsics.width}x{sequence.intrinsics.height}"
        timings = bench(sequence, args.repeat, args.config)
        print(f"{len(sequence)} stereo frames of {size}, one thread, best of {args.repeat}")
        print(f"{'stage':34s} {'frames/s':>9s} {'ms/frame':>9s} {'CPU frames/s':>13s}")
        for t in timings:
            print(f"{t.stage:34s} {t.wall_fps:9.1f} {1000 / t.wall_fps:9.1f} {t.cpu_fps:13.1f}")
        config = load_frontend_config(args.config)
        if sequence.gt_poses is not None:
            print("\nvisual odometry against poses.txt")
            for name, value in odometry_accuracy(sequence, config).items():
                print(f"  {name:44s} {value:10.3f}")
            if (sequence.root / LANDMARKS_FILE).exists():
                print("tags against landmarks.json (every frame)")
                for name, value in tag_accuracy(sequence, config).items():
                    print(f"  {name:44s} {value:10.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
