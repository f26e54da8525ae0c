"""Statistics over runs, pure functions of result rows.

How runs are pooled, everywhere in the reports: each run's statistic (max, mean, median, RMSE)
is one of its per-pose absolute errors, as in the paper's Tables I-II (one run each); a table
gives, per method, the mean of that statistic over the runs (seeds) of a cell. Box plots and
axis tables show the spread of a per-run statistic (its RMSE) over the seeds of each cell.
Per-cell summaries give the mean of a per-run figure with its bootstrap interval over seeds,
and compare MM + NH with each other method seed by seed (`inference.py`). A figure a run did
not record (None) is left out of its statistics: they are over the runs that have it.
"""

from __future__ import annotations

import statistics
from collections.abc import Sequence
from dataclasses import dataclass

from data_tools.sweep.grid import Cell
from data_tools.sweep.inference import Comparison, Estimate, compare, estimate
from data_tools.sweep.results import ResultRow

STATISTICS = ("max", "mean", "median", "rmse")
QUANTITIES = ("translation", "rotation")
# The per-run figures (results.csv columns) given per cell with a mean and an interval.
SEED_FIGURES = (
    "translation_rmse",
    "rotation_rmse",
    "one_to_one_wrong",
    "one_to_one_null",  # missed: detections of a real landmark left to none
    "landmarks_per_true",
    "null",  # null-hypothesis wins, false alarms' included
    "switches",
)
CHAMPION = "mm-nh"  # compared with every other method, seed by seed
REFERENCE = "known"  # given the true association: the others are measured against it, never bold
# A run is near the reference when its translation RMSE is at most NEAR_FACTOR times the
# reference's on the same seed plus NEAR_MARGIN_M: mmslam's per-seed target for MM + NH.
NEAR_FACTOR = 1.5
NEAR_MARGIN_M = 0.5
BASELINE = "ml"  # the summary lines count every method's wins against it


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


@dataclass(frozen=True)
class SlowestRun:
    """The run that took longest against its own cell and method's median replay time."""

    ratio: float  # its runtime over the median of its cell and method's runs
    cell: str
    method: str
    seed: int


def slowest_run(rows: Sequence[ResultRow]) -> SlowestRun | None:
    """The largest runtime / median runtime over the runs of each (cell, method) with two
    seeds or more: where a run's cost ran away (no run should exceed 3x)."""
    groups: dict[tuple[str, str], list[ResultRow]] = {}
    for r in rows:
        groups.setdefault((r.cell, r.method), []).append(r)
    slowest = None
    for (cell, method), runs in groups.items():
        median = statistics.median(r.runtime_s for r in runs)
        if len(runs) < 2 or median <= 0:
            continue
        worst = max(runs, key=lambda r: r.runtime_s)
        ratio = worst.runtime_s / median
        if slowest is None or ratio > slowest.ratio:
            slowest = SlowestRun(ratio, cell, method, worst.seed)
    return slowest


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


def mean_or_none(values: Sequence[float | None]) -> float | None:
    """The mean of the values there are (None where none is)."""
    present = [v for v in values if v is not None]
    return statistics.fmean(present) if present else None


def median_or_none(values: Sequence[float]) -> float | None:
    return statistics.median(values) if values else None


def recorded(rows: Sequence[ResultRow], column: str) -> list[float]:
    """The values of `column` in `rows`, those not recorded (None) left out."""
    return [float(v) for r in rows if (v := getattr(r, column)) is not None]


@dataclass(frozen=True)
class SeedSummary:
    """One method over the runs (seeds) of one cell: means with their intervals, and the
    spread of the translation RMSE."""

    method: str
    runs: int
    estimates: dict[str, Estimate | None]  # SEED_FIGURES column -> over the runs that have it
    median_translation_rmse: float
    worst_translation_rmse: float  # the largest over seeds
    runtime_s: float  # mean
    # (runs near the reference, runs the reference has too); None for the reference itself
    # or without its runs
    near_reference: tuple[int, int] | None = None


def near_reference(
    ours: dict[tuple[str, int], float], reference: dict[tuple[str, int], float]
) -> tuple[int, int] | None:
    """How many of the runs (by `by_run` key) both have are near the reference's (within
    NEAR_FACTOR times its RMSE plus NEAR_MARGIN_M), out of how many; None if none is shared."""
    shared = set(ours) & set(reference)
    if not shared:
        return None
    near = sum(ours[k] <= NEAR_FACTOR * reference[k] + NEAR_MARGIN_M for k in shared)
    return near, len(shared)


def seed_summaries(rows: Sequence[ResultRow], methods: Sequence[str]) -> list[SeedSummary]:
    """A summary per method with runs in `rows` (one cell's), in the order of `methods`."""
    reference = by_run(rows, REFERENCE)
    found = []
    for method in methods:
        mine = [r for r in rows if r.method == method]
        if not mine:
            continue
        rmse = recorded(mine, "translation_rmse")
        found.append(
            SeedSummary(
                method=method,
                runs=len(mine),
                estimates={c: estimate(recorded(mine, c)) for c in SEED_FIGURES},
                median_translation_rmse=statistics.median(rmse),
                worst_translation_rmse=max(rmse),
                runtime_s=statistics.fmean(recorded(mine, "runtime_s")),
                near_reference=None
                if method == REFERENCE
                else near_reference(by_run(mine, method), reference),
            )
        )
    return found


def by_run(rows: Sequence[ResultRow], method: str) -> dict[tuple[str, int], float]:
    """The translation RMSE of each run of `method`, by (cell, seed): what pairs the runs of
    two methods."""
    return {(r.cell, r.seed): r.translation_rmse for r in rows if r.method == method}


def comparisons(
    rows: Sequence[ResultRow], methods: Sequence[str], champion: str = CHAMPION
) -> list[tuple[str, Comparison]]:
    """`champion` against each other method with runs in `rows`, on translation RMSE over the
    runs both have; none when `champion` has no run."""
    ours = by_run(rows, champion)
    if not ours:
        return []
    others = [(m, by_run(rows, m)) for m in methods if m != champion]
    return [(m, compare(ours, theirs)) for m, theirs in others if theirs]


def representative_seed(rows: Sequence[ResultRow], method: str = CHAMPION) -> int | None:
    """The seed whose run of `method` has the median translation RMSE among `rows` (one
    cell's): the lower middle one for an even count, ties by seed. None without a run."""
    ranked = sorted((r.translation_rmse, r.seed) for r in rows if r.method == method)
    return ranked[(len(ranked) - 1) // 2][1] if ranked else None


@dataclass(frozen=True)
class Headline:
    """One method over every run of a sweep, for the line the command ends with."""

    method: str
    runs: int
    translation_rmse: Estimate | None
    against_baseline: Comparison | None  # None for the baseline itself, or without it


def headlines(
    rows: Sequence[ResultRow], methods: Sequence[str], baseline: str = BASELINE
) -> list[Headline]:
    """A headline per method with runs, in the order of `methods`: its mean translation RMSE
    over all runs with an interval, and its wins against `baseline` over the same cells and
    seeds."""
    theirs = by_run(rows, baseline)
    found = []
    for method in methods:
        ours = by_run(rows, method)
        if not ours:
            continue
        paired = compare(ours, theirs) if theirs and method != baseline else None
        found.append(Headline(method, len(ours), estimate(list(ours.values())), paired))
    return found
