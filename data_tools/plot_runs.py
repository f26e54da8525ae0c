"""Top-down plot of replays against the log's ground truth (the README's picture).

    mmslam plot LOG.mcap RUN_DIR [RUN_DIR ...] --out FIGURE.png

Each RUN_DIR is a `mmslam replay --out` folder; its panel shows the ground-truth path, the
estimated path (origin-aligned, as the metrics are), the landmarks, and the RMSE; axes in
metres, x and y of the log's world frame (pose 0's body frame).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from matplotlib.backend_bases import FigureCanvasBase
from matplotlib.figure import Figure

from pipeline.errors import InputError
from pipeline.log import read_log
from pipeline.outputs import AtomicFile


def read_tum(path: Path) -> np.ndarray:
    """Positions (N, 3) of a TUM trajectory file."""
    try:
        return np.loadtxt(path, ndmin=2)[:, 1:4]
    except (OSError, ValueError) as exc:
        raise InputError(f"trajectory {path}: cannot read ({exc})") from None


def read_metrics(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise InputError(f"metrics {path}: cannot read ({exc})") from None


def read_landmarks(path: Path) -> np.ndarray:
    try:
        return np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)[:, 1:4]
    except (OSError, ValueError) as exc:
        raise InputError(f"landmarks {path}: cannot read ({exc})") from None


def figure(log_path: Path, runs: list[Path], title: str | None = None) -> Figure:
    """A panel per run: ground truth, estimate and landmarks, seen from above."""
    log = read_log(log_path)
    if not log.has_ground_truth:
        raise InputError(f"{log_path}: no ground truth to plot the runs against")
    truth = np.array([m.translation for m in log.ground_truth_poses])
    truth_landmarks = (
        np.array([lm.position for lm in log.ground_truth_landmarks.landmarks])
        if log.ground_truth_landmarks
        else np.zeros((0, 3))
    )
    panels = [
        (
            read_metrics(run / "metrics.json"),
            read_tum(run / "trajectory.tum"),
            read_landmarks(run / "landmarks.csv"),
        )
        for run in runs
    ]
    fig = Figure(figsize=(4.2 * len(runs), 4.2))
    axes = fig.subplots(1, len(runs), squeeze=False)[0]
    for ax, (metrics, path, landmarks) in zip(axes, panels, strict=True):
        ax.plot(truth[:, 0], truth[:, 1], color="0.15", lw=1.0, label="ground truth")
        ax.plot(path[:, 0], path[:, 1], color="tab:red", lw=1.0, label="estimate")
        ax.scatter(*truth_landmarks[:, :2].T, s=4, color="0.6", label="true landmarks")
        ax.scatter(*landmarks[:, :2].T, s=4, color="tab:blue", label="mapped landmarks")
        rmse = metrics["translation_error_m"]["rmse"]
        ax.set_title(f"{metrics['method']}: RMSE {rmse:.2f} m, {len(landmarks)} landmarks")
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.tick_params(labelsize=7)
    axes[0].legend(loc="lower left", fontsize=7)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig


def plot_runs(log_path: Path, runs: list[Path], out: Path, title: str | None = None) -> None:
    """The figure of `runs` to `out` (its format from the suffix), replacing it only once whole."""
    image_format = out.suffix.lstrip(".").lower()
    if image_format not in FigureCanvasBase.get_supported_filetypes():
        raise InputError(f"--out {out}: not an image format matplotlib writes (.png, .pdf, .svg)")
    fig = figure(log_path, runs, title)
    with AtomicFile(out) as target:
        fig.savefig(target.file, dpi=110, format=image_format)
