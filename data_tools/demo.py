"""`make demo`: the whole pipeline on a small built-in sequence, images to map.

    render a stereo sequence (KITTI layout) -> mmslam frontend -> mmslam replay (mm-nh) -> Rerun

then why it matters: a simulated indoor run with noisy odometry and misclassified tags, where
maximum-likelihood association takes wrong loop closures and mm-nh does not.

Usage: python -m data_tools.demo [--out out/demo] [--method mm-nh]
"""

from __future__ import annotations

import argparse
import csv
import logging
import os
import subprocess
import sys
from collections import Counter
from pathlib import Path

log = logging.getLogger("mmslam.demo")


def _mmslam(*args: str) -> None:
    command = [sys.executable, "-m", "pipeline.cli", *args]
    print("$ mmslam " + " ".join(args), flush=True)
    subprocess.run(command, check=True)


def box_landmarks(log_path: Path, run_dir: Path) -> str:
    """What became of the log's box detections in a replay: the objects they saw (where the
    log knows), and the landmarks the replay made of them, by class."""
    from pipeline.log import read_log

    detection_log = read_log(log_path)
    names = detection_log.metadata.class_names
    boxes = {
        (m.pose_index, k): d
        for m in detection_log.detections
        for k, d in enumerate(m.detections)
        if d.source == "bbox"
    }
    if not boxes:
        return "no box detections: the object detector found nothing (or is not installed)"
    labelled = [d.truth_landmark_id for d in boxes.values() if d.truth_landmark_id is not None]
    on_objects = [t for t in labelled if t >= 0]
    landmark_class: dict[int, str] = {}
    with open(run_dir / "associations.csv", newline="") as f:
        for row in csv.DictReader(f):
            detection = boxes.get((int(row["pose_index"]), int(row["detection_index"])))
            if detection is not None and int(row["landmark_id"]) >= 0:
                landmark_class[int(row["landmark_id"])] = names[detection.class_id]
    with open(run_dir / "landmarks.csv", newline="") as f:
        final = {int(row["id"]): names[int(row["class_id"])] for row in csv.DictReader(f)}
    made = Counter(final[j] for j in landmark_class if j in final)
    by_class = ", ".join(f"{n} {name}" for name, n in sorted(made.items()))
    truth = (
        f" ({len(on_objects)} on {len(set(on_objects))} objects of the log's ground truth, "
        f"{len(labelled) - len(on_objects)} on none)"
        if labelled
        else ""
    )
    return (
        f"images -> map: {len(boxes)} box detections{truth} became {sum(made.values())} "
        f"landmarks in {run_dir} ({by_class or 'none'})"
    )


def viewer_command(recording: Path) -> str:
    """How to open a recording here: the viewer needs a display; without one, Rerun's web
    viewer serves it to a browser."""
    if os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
        return f"Open the recording with: .venv/bin/rerun {recording}"
    return (
        f"No display here (DISPLAY and WAYLAND_DISPLAY are unset), so the native viewer cannot "
        f"open: .venv/bin/rerun --web-viewer {recording} serves it to a browser instead "
        "(open the address it prints)"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out/demo"))
    parser.add_argument("--method", default="mm-nh")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")

    from data_tools.render import render_sequence

    out: Path = args.out
    sequence = out / "sequence"
    if not (sequence / "render.json").exists():
        print(f"rendering the demo stereo sequence into {sequence} (about half a minute)")
        render_sequence("demo", sequence)
    log_path = out / "demo.mcap"
    _mmslam("frontend", str(sequence), "--out", str(log_path), "--images")
    _mmslam("inspect", str(log_path))
    recording = out / f"{args.method}.rrd"
    run_dir = out / args.method
    _mmslam(
        "replay", str(log_path), "--method", args.method, "--out", str(run_dir),
        "--rrd", str(recording),
    )  # fmt: skip
    boxes = box_landmarks(log_path, run_dir)
    print(boxes, flush=True)

    tags = out / "indoor-tags.mcap"
    _mmslam(
        "simulate", "indoor-tags", "--out", str(tags), "--seed", "2", "--odom-noise-scale", "4",
        "--misclassification", "0.1", "--true-covariance",
    )  # fmt: skip
    for method in ("ml", "mm-nh"):
        _mmslam("replay", str(tags), "--method", method, "--out", str(out / f"indoor-{method}"))
    print(
        f"\nDone. Outputs in {run_dir}/ (trajectory.tum, landmarks.csv, associations.csv, "
        f"metrics.json).\n{boxes}\n{viewer_command(recording)}\n(its camera view shows each "
        "box with its class, score, range and the landmark it went to)"
        f"\nCompare the indoor runs: mmslam plot {tags} "
        f"{out / 'indoor-ml'} {out / 'indoor-mm-nh'} --out {out / 'indoor.png'}"
        "\n(mmslam, rerun and evo's commands are in .venv/bin: `source .venv/bin/activate` or "
        "`make shell` puts them on your PATH, and the README's commands then run as typed.)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
