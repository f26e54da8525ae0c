"""Statistics over runs, pure functions of result rows.

How runs are pooled, everywhere in the reports: each run's statistic (max, mean, median, RMSE)
is one of its per-pose absolute errors, as in the paper's Tables I-II (one run each); a table
gives, per method, the mean of that statistic over the runs (seeds) of a cell. Box plots and
axis tables show the spread of a per-run statistic (its RMSE) over the seeds of each cell.
"""

from __future__ import annotations

import statistics
from collections.abc import Sequence
from dataclasses import dataclass

from data_tools.sweep.grid import Cell
from data_tools.sweep.results import ResultRow

STATISTICS = ("max", "mean", "median", "rmse")
QUANTITIES = ("translation", "rotation")


@dataclass(frozen=True)
class MethodSummary:
    """One method over the runs of one cell: means over runs of per-run figures."""

    method: str
    runs: int
    translation: dict[str, float]  # statistic -> mean over runs
    rotation: dict[str, float]
    correct: float  # detections per run
    wrong: float
    null: float
    landmarks: float
    switches: float


def rows_of_cell(rows: Sequence[ResultRow], cell: Cell) -> list[ResultRow]:
    return [r for r in rows if r.cell == cell.name]


def summarise_method(rows: Sequence[ResultRow], method: str) -> MethodSummary | None:
    """The summary of `method` over `rows` (one cell's), or None if it has no run there."""
    mine = [r for r in rows if r.method == method]
    if not mine:
        return None

    def mean(column: str) -> float:
        return statistics.fmean(getattr(r, column) for r in mine)

    return MethodSummary(
        method=method,
        runs=len(mine),
        translation={s: mean(f"translation_{s}") for s in STATISTICS},
        rotation={s: mean(f"rotation_{s}") for s in STATISTICS},
        correct=mean("correct"),
        wrong=mean("wrong"),
        null=mean("null"),
        landmarks=mean("num_landmarks"),
        switches=mean("switches"),
    )


def summarise_methods(rows: Sequence[ResultRow], methods: Sequence[str]) -> list[MethodSummary]:
    """A summary per method that has runs in `rows`, in the order of `methods`."""
    found = (summarise_method(rows, m) for m in methods)
    return [s for s in found if s is not None]


def series(
    rows: Sequence[ResultRow], cells: Sequence[Cell], method: str, column: str
) -> list[list[float]]:
    """For each cell, the values of `column` over the runs of `method` there (seed order)."""
    out = []
    for cell in cells:
        mine = [r for r in rows if r.cell == cell.name and r.method == method]
        runs = sorted(mine, key=lambda r: r.seed)
        out.append([float(getattr(r, column)) for r in runs])
    return out


def median_or_none(values: Sequence[float]) -> float | None:
    return statistics.median(values) if values else None
