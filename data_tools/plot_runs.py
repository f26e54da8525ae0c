"""Top-down plot of replays against the log's ground truth (the README's picture).

    python -m data_tools.plot_runs LOG.mcap RUN_DIR [RUN_DIR ...] --out FIGURE.png

Each RUN_DIR is a `mmslam replay --out` folder; its panel shows the ground-truth path, the
estimated path (origin-aligned, as the metrics are), the landmarks, and the RMSE.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from pipeline.errors import InputError
from pipeline.log import read_log


def read_tum(path: Path) -> np.ndarray:
    """Positions (N, 3) of a TUM trajectory file."""
    try:
        return np.loadtxt(path, ndmin=2)[:, 1:4]
    except (OSError, ValueError) as exc:
        raise InputError(f"trajectory {path}: cannot read ({exc})") from None


def read_landmarks(path: Path) -> np.ndarray:
    try:
        return np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)[:, 1:4]
    except (OSError, ValueError) as exc:
        raise InputError(f"landmarks {path}: cannot read ({exc})") from None


def plot_runs(log_path: Path, runs: list[Path], out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    log = read_log(log_path)
    truth = np.array([m.translation for m in log.ground_truth_poses])
    truth_landmarks = (
        np.array([lm.position for lm in log.ground_truth_landmarks.landmarks])
        if log.ground_truth_landmarks
        else np.zeros((0, 3))
    )
    fig, axes = plt.subplots(1, len(runs), figsize=(4.2 * len(runs), 4.2), squeeze=False)
    for ax, run in zip(axes[0], runs, strict=True):
        metrics = json.loads((run / "metrics.json").read_text())
        path = read_tum(run / "trajectory.tum")
        landmarks = read_landmarks(run / "landmarks.csv")
        ax.plot(truth[:, 0], truth[:, 1], color="0.15", lw=1.0, label="ground truth")
        ax.plot(path[:, 0], path[:, 1], color="tab:red", lw=1.0, label="estimate")
        ax.scatter(*truth_landmarks[:, :2].T, s=4, color="0.6", label="true landmarks")
        ax.scatter(*landmarks[:, :2].T, s=4, color="tab:blue", label="mapped landmarks")
        rmse = metrics["translation_error_m"]["rmse"]
        ax.set_title(f"{metrics['method']}: RMSE {rmse:.2f} m, {len(landmarks)} landmarks")
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
    axes[0][0].legend(loc="lower left", fontsize=7)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("log", type=Path)
    parser.add_argument("runs", type=Path, nargs="+")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    try:
        plot_runs(args.log, args.runs, args.out)
    except InputError as exc:
        print(f"plot_runs: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
