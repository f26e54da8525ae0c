"""`make demo`: the whole pipeline on a small built-in sequence, images to map.

    render a stereo sequence (KITTI layout) -> mmslam frontend -> mmslam replay (mm-nh) -> Rerun

then why it matters: a simulated indoor run with noisy odometry and misclassified tags, where
maximum-likelihood association takes wrong loop closures and mm-nh does not.

Usage: python -m data_tools.demo [--out out/demo] [--method mm-nh]
"""

from __future__ import annotations

import argparse
import logging
import subprocess
import sys
from pathlib import Path

log = logging.getLogger("mmslam.demo")


def _mmslam(*args: str) -> None:
    command = [sys.executable, "-m", "pipeline.cli", *args]
    print("$ mmslam " + " ".join(args), flush=True)
    subprocess.run(command, check=True)


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
    _mmslam(
        "replay", str(log_path), "--method", args.method, "--out", str(out / args.method),
        "--rrd", str(recording),
    )  # fmt: skip

    tags = out / "indoor-tags.mcap"
    _mmslam(
        "simulate", "indoor-tags", "--out", str(tags), "--seed", "2", "--odom-noise-scale", "4",
        "--misclassification", "0.1", "--true-covariance",
    )  # fmt: skip
    for method in ("ml", "mm-nh"):
        _mmslam("replay", str(tags), "--method", method, "--out", str(out / f"indoor-{method}"))
    print(
        f"\nDone. Outputs in {out / args.method}/ (trajectory.tum, landmarks.csv, "
        f"associations.csv, metrics.json).\nOpen the recording with: .venv/bin/rerun {recording}"
        f"\nCompare the indoor runs: mmslam plot {tags} "
        f"{out / 'indoor-ml'} {out / 'indoor-mm-nh'} --out {out / 'indoor.png'}"
        "\n(mmslam, rerun and evo's commands are in .venv/bin: `source .venv/bin/activate` or "
        "`make shell` puts them on your PATH, and the README's commands then run as typed.)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
