"""Render a synthetic stereo sequence in the KITTI layout (see `data_tools.renderer`).

python -m data_tools.render demo --out out/sequences/demo [--seed 0] [--num-frames N]
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import shutil
import sys
import time
from pathlib import Path

import numpy as np

from data_tools.renderer.config import RendererConfig, load_preset, preset_path
from data_tools.renderer.geometry import invert_transform
from data_tools.renderer.layout import build_scene, motion_from_config
from data_tools.renderer.output import visible_landmarks, write_landmarks, write_visibility
from data_tools.renderer.path import body_poses
from data_tools.renderer.raycast import PinholeCamera, SceneRenderer
from pipeline.datasets.camera import BODY_FROM_CAMERA, StereoIntrinsics
from pipeline.datasets.kitti import (
    write_calibration,
    write_poses,
    write_times,
)
from pipeline.errors import InputError
from pipeline.progress import track

log = logging.getLogger(__name__)

# render.json marks a directory as a rendered sequence, which a new render may replace.
MARKER = "render.json"


def intrinsics_of(config: RendererConfig) -> StereoIntrinsics:
    cam = config.camera
    return StereoIntrinsics(cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy, cam.baseline)


def camera_of(config: RendererConfig) -> PinholeCamera:
    cam = config.camera
    return PinholeCamera(cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy, cam.supersample)


def trajectory(config: RendererConfig, num_frames: int | None = None) -> np.ndarray:
    """World-from-body poses of the preset's drive, cut to the first `num_frames`."""
    poses = body_poses(motion_from_config(config), config.camera.frame_rate)
    if num_frames is not None:
        if not 1 <= num_frames <= len(poses):
            raise InputError(
                f"num_frames must be 1..{len(poses)} for this preset, not {num_frames}"
            )
        poses = poses[:num_frames]
    return poses


def stereo_poses(world_from_body: np.ndarray, baseline: float) -> tuple[np.ndarray, np.ndarray]:
    """World-from-camera poses of the left and right cameras of one body pose."""
    left = world_from_body @ BODY_FROM_CAMERA
    right_from_left = np.eye(4)
    right_from_left[0, 3] = baseline
    return left, left @ right_from_left


def to_grey8(image: np.ndarray, rng: np.random.Generator, noise_sigma: float) -> np.ndarray:
    if noise_sigma > 0:
        image = image + rng.normal(0.0, noise_sigma, image.shape).astype(np.float32)
    return np.clip(np.round(image), 0, 255).astype(np.uint8)


def render_sequence(
    preset: str | Path, out_dir: Path, *, seed: int = 0, num_frames: int | None = None
) -> Path:
    """Render the preset's sequence into `out_dir` (KITTI layout plus ground truth).

    Deterministic: the same preset, seed and `num_frames` give the same bytes. `num_frames`
    keeps the first frames of the preset's drive (the scene does not change with it). The
    sequence is written beside `out_dir` and renamed into place; an existing `out_dir` is
    replaced only if it is empty or a previous render.
    """
    import cv2

    config = load_preset(preset)
    out_dir = Path(out_dir)
    _check_replaceable(out_dir)
    started = time.perf_counter()
    full_drive = trajectory(config)
    world_from_body = full_drive if num_frames is None else trajectory(config, num_frames)
    scene = build_scene(config, full_drive[:, :2, 3], seed)
    renderer = SceneRenderer(scene, camera_of(config))
    log.info("scene built in %.1f s", time.perf_counter() - started)

    out_dir.parent.mkdir(parents=True, exist_ok=True)
    staging = out_dir.parent / f".{out_dir.name}.partial-{os.getpid()}"
    shutil.rmtree(staging, ignore_errors=True)
    (staging / "image_0").mkdir(parents=True)
    (staging / "image_1").mkdir()
    try:
        camera_poses, seen = [], []
        frames = track(range(len(world_from_body)), len(world_from_body), "render", "frame")
        render_started = time.perf_counter()
        for i in frames:
            left_pose, right_pose = stereo_poses(world_from_body[i], config.camera.baseline)
            camera_poses.append(left_pose)
            for side, pose in ((0, left_pose), (1, right_pose)):
                view = renderer.render(pose)
                noise = np.random.default_rng([seed, i, side])
                grey = to_grey8(view.image, noise, config.camera.noise_sigma)
                cv2.imwrite(str(staging / f"image_{side}" / f"{i:06d}.png"), grey)
                if side == 0:
                    seen.append(visible_landmarks(view.owner, view.supersample))
        elapsed = time.perf_counter() - render_started
        log.info(
            "rendered %d stereo frames in %.1f s (%.2f frames/s)",
            len(camera_poses),
            elapsed,
            len(camera_poses) / max(elapsed, 1e-9),
        )
        first_inverse = invert_transform(camera_poses[0])
        write_poses(staging / "poses.txt", np.array([first_inverse @ p for p in camera_poses]))
        write_times(staging / "times.txt", np.arange(len(camera_poses)) / config.camera.frame_rate)
        write_calibration(staging / "calib.txt", intrinsics_of(config))
        write_landmarks(staging / "landmarks.json", scene, world_from_body[0])
        write_visibility(staging / "visibility.json", seen)
        provenance = {
            "preset": preset_path(preset).stem,
            "seed": seed,
            "num_frames": len(camera_poses),
        }
        (staging / MARKER).write_text(json.dumps(provenance, indent=1) + "\n")
        _move_into_place(staging, out_dir)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return out_dir


def _check_replaceable(out_dir: Path) -> None:
    if out_dir.exists() and not (
        out_dir.is_dir() and (not any(out_dir.iterdir()) or (out_dir / MARKER).exists())
    ):
        raise InputError(f"{out_dir}: exists and is not a rendered sequence; not replacing it")


def _move_into_place(staging: Path, out_dir: Path) -> None:
    _check_replaceable(out_dir)
    if out_dir.exists():
        old = out_dir.parent / f".{out_dir.name}.old-{os.getpid()}"
        out_dir.rename(old)
        staging.rename(out_dir)
        shutil.rmtree(old)
    else:
        staging.rename(out_dir)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m data_tools.render",
        description="Render a synthetic stereo sequence (KITTI layout, exact ground truth).",
        epilog="example: python -m data_tools.render demo --out out/sequences/demo",
    )
    parser.add_argument("preset", help="a preset name in configs/renderer/ or a TOML file")
    parser.add_argument("--out", type=Path, required=True, help="the sequence directory")
    parser.add_argument("--seed", type=int, default=0, help="scene and noise seed (default 0)")
    parser.add_argument("--num-frames", type=int, default=None, help="render only the first N")
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress")
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING, format="%(message)s"
    )
    try:
        render_sequence(args.preset, args.out, seed=args.seed, num_frames=args.num_frames)
    except InputError as exc:
        log.error("error: %s", exc)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
