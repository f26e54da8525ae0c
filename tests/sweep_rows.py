"""A sweep's results made by hand: rows of runs as their metrics.json would give them, for
the tests of the tables and statistics a report computes from them."""

from __future__ import annotations

from data_tools.sweep.config import Axis, SweepConfig
from data_tools.sweep.grid import Cell, RunKey
from data_tools.sweep.results import ResultRow, row_from_metrics
from data_tools.sweep.stats import STATISTICS

HAND_CONFIG = SweepConfig(
    name="hand",
    scenario="indoor-tags",
    scenario_config=None,
    backend_config=None,
    num_classes=2,
    true_covariance=False,
    seeds=(0, 1, 2),
    methods=("known", "ml", "mm-nh"),
    odom_noise_scale=1.0,
    misclassification=0.1,
    axes=(Axis("noise", "odom_noise_scale", (1.0, 4.0)),),
    fingerprint="0",
)


def hand_row(cell: Cell, seed: int, method: str, t: tuple, r: tuple, a: tuple) -> ResultRow:
    """The row of a run whose metrics.json says: translation and rotation errors `t` and `r`
    (max, mean, median, rmse), associations `a` (correct, wrong, null, switches, landmarks)."""
    correct, wrong, null, switches, landmarks = a
    metrics = {
        "translation_error_m": dict(zip(STATISTICS, t, strict=True)),
        "rotation_error_rad": dict(zip(STATISTICS, r, strict=True)),
        "association": {"correct": correct, "wrong": wrong, "null": null, "unlabelled": 0},
        "switches": switches,
        "num_poses": 100,
        "num_detections": correct + wrong + null,
        "num_landmarks": landmarks,
        "runtime_s": 1.5,
    }
    return row_from_metrics(RunKey(cell, seed, method), metrics)


BASE, NOISY = Cell(1.0, 0.1), Cell(4.0, 0.1)
HAND_ROWS = [
    # known: translation RMSE 1, 2, 3 on the base cell
    hand_row(BASE, 0, "known", (2.0, 1.0, 0.9, 1.0), (0.02, 0.01, 0.01, 0.01), (10, 0, 0, 0, 5)),
    hand_row(BASE, 1, "known", (3.0, 1.5, 1.4, 2.0), (0.04, 0.02, 0.02, 0.02), (10, 0, 0, 0, 5)),
    hand_row(BASE, 2, "known", (4.0, 2.0, 1.9, 3.0), (0.06, 0.03, 0.03, 0.03), (10, 0, 0, 0, 5)),
    hand_row(BASE, 0, "ml", (10.0, 6.0, 5.0, 7.0), (0.3, 0.1, 0.09, 0.12), (7, 3, 0, 1, 8)),
    hand_row(BASE, 1, "ml", (20.0, 9.0, 8.0, 11.0), (0.5, 0.2, 0.19, 0.22), (8, 2, 0, 0, 7)),
    hand_row(BASE, 2, "ml", (33.0, 12.0, 11.0, 13.0), (0.7, 0.3, 0.29, 0.32), (6, 4, 0, 2, 9)),
    hand_row(BASE, 0, "mm-nh", (4.0, 2.0, 1.5, 2.5), (0.1, 0.05, 0.04, 0.06), (9, 0, 1, 3, 6)),
    hand_row(BASE, 1, "mm-nh", (5.0, 3.0, 2.5, 3.5), (0.2, 0.06, 0.05, 0.07), (9, 1, 0, 1, 6)),
    # mm-nh seed 2 is missing: its numbers are means over two runs
    hand_row(NOISY, 0, "known", (9, 9, 9, 9.0), (0.9, 0.9, 0.9, 0.9), (10, 0, 0, 0, 5)),
    hand_row(NOISY, 1, "known", (9, 9, 9, 5.0), (0.9, 0.9, 0.9, 0.5), (10, 0, 0, 0, 5)),
    hand_row(NOISY, 2, "known", (9, 9, 9, 7.0), (0.9, 0.9, 0.9, 0.7), (10, 0, 0, 0, 5)),
    hand_row(NOISY, 0, "ml", (9, 9, 9, 40.0), (0.9, 0.9, 0.9, 0.4), (10, 0, 0, 0, 5)),
    hand_row(NOISY, 1, "ml", (9, 9, 9, 20.0), (0.9, 0.9, 0.9, 0.2), (10, 0, 0, 0, 5)),
]
