"""Markdown tables like the paper's Tables I-II, and per-axis tables beside the box plots."""

from __future__ import annotations

from collections.abc import Sequence

from data_tools.sweep.config import FACTOR_LABELS, Axis, SweepConfig
from data_tools.sweep.grid import Cell, axis_cells, base_cell, cells
from data_tools.sweep.results import ResultRow
from data_tools.sweep.stats import (
    STATISTICS,
    MethodSummary,
    median_or_none,
    rows_of_cell,
    series,
    summarise_methods,
)

METHOD_NAMES = {"known": "Known DA", "ml": "ML", "gpda": "GPDA", "mm": "MM", "mm-nh": "MM + NH"}
REFERENCE = "known"  # shown for reference, never bold: the others are compared with each other
TRANSLATION_DIGITS = 2
ROTATION_DIGITS = 4


def method_name(method: str) -> str:
    return METHOD_NAMES.get(method, method)


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def best_text(values: Sequence[float], methods: Sequence[str], digits: int) -> str | None:
    """The lowest value among the compared methods as printed, or None when all compared
    methods print alike (nothing to pick out)."""
    printed = {f"{v:.{digits}f}": v for v, m in zip(values, methods, strict=True) if m != REFERENCE}
    if len(printed) < 2:
        return None
    return min(printed.items(), key=lambda kv: kv[1])[0]


def _cell(value: float | None, digits: int, best: str | None = None) -> str:
    if value is None:
        return "-"
    text = f"{value:.{digits}f}"
    return f"**{text}**" if text == best else text


def error_table(summaries: Sequence[MethodSummary], quantity: str, digits: int) -> str:
    """Max, mean, median and RMSE of `quantity` ("translation" or "rotation") per method; the
    lowest of each column among the compared methods in bold, as in the paper."""
    methods = [s.method for s in summaries]
    columns = {s: [getattr(m, quantity)[s] for m in summaries] for s in STATISTICS}
    best = {s: best_text(columns[s], methods, digits) for s in STATISTICS}
    rows = [
        [method_name(m.method)]
        + [
            _cell(getattr(m, quantity)[s], digits, best[s] if m.method != REFERENCE else None)
            for s in STATISTICS
        ]
        + [str(m.runs)]
        for m in summaries
    ]
    return markdown_table(["Method", "Max", "Mean", "Median", "RMSE", "Runs"], rows)


def association_table(summaries: Sequence[MethodSummary]) -> str:
    rows = [
        [
            method_name(m.method),
            f"{m.correct:.1f}",
            f"{m.wrong:.1f}",
            f"{m.null:.1f}",
            f"{m.landmarks:.1f}",
            f"{m.switches:.1f}",
        ]
        for m in summaries
    ]
    header = ["Method", "Correct", "Wrong", "Null", "Landmarks", "Switches"]
    return markdown_table(header, rows)


def factor_text(factor: str, value: float) -> str:
    return f"{100 * value:g} %" if factor == "misclassification" else f"{value:g}"


def axis_table(
    rows: Sequence[ResultRow],
    methods: Sequence[str],
    axis: Axis,
    axis_cells_: Sequence[Cell],
    column: str,
    digits: int,
) -> str:
    """The median over seeds of a per-run figure (`column`), a row per method, a column per
    value of the axis."""
    header = ["Method"] + [factor_text(axis.factor, v) for v in axis.values]
    body = []
    for method in methods:
        medians = [median_or_none(v) for v in series(rows, axis_cells_, method, column)]
        if all(m is None for m in medians):
            continue
        body.append([method_name(method)] + [_cell(m, digits) for m in medians])
    return markdown_table(header, body)


def held_factor(config: SweepConfig, axis: Axis) -> str:
    """The factor an axis holds at the base cell's value, in words."""
    base = base_cell(config)
    if axis.factor == "odom_noise_scale":
        return f"misclassification {100 * base.misclassification:g} %"
    return f"odometry noise scale {base.odom_noise_scale:g}"


def render_tables(
    config: SweepConfig, rows: Sequence[ResultRow], code_versions: Sequence[str] = ()
) -> str:
    """The whole of tables.md."""
    base = base_cell(config)
    grid = cells(config)
    expected = len(grid) * len(config.seeds) * len(config.methods)
    summaries = summarise_methods(rows_of_cell(rows, base), config.methods)
    parts = [
        f"# Sweep `{config.name}`: scenario `{config.scenario}`\n",
        f"{len(grid)} cell(s) x {len(config.seeds)} seed(s) x {len(config.methods)} method(s): "
        f"{len(rows)} of {expected} runs in results.csv. C = {config.num_classes} classes."
        + (
            f" Runs made by mmslam {', '.join(code_versions)} (git describe).\n"
            if code_versions
            else "\n"
        ),
        "Errors are absolute trajectory errors against ground truth after aligning the first "
        "poses (evo APE). A run's max, mean, median and RMSE are statistics of its per-pose "
        "errors, as in the paper's Tables I-II (one run each); each number below is the mean of "
        "that statistic over the runs (seeds) of the cell. Bold: the lowest among the methods "
        "other than Known DA (the reference, given the true association).\n",
        f"## Translation error (m): {base.label()}\n",
        error_table(summaries, "translation", TRANSLATION_DIGITS),
        f"## Rotation error (rad): {base.label()}\n",
        error_table(summaries, "rotation", ROTATION_DIGITS),
        f"## Associations (detections per run, mean over runs): {base.label()}\n",
        "Correct / wrong: the detection's final landmark stands (by majority vote) for its true "
        "landmark / for another; null: the null hypothesis took it (and, for Known DA, the "
        "detector's false alarms, which have no true landmark to join). Switches: association "
        "changes after the first choice.\n",
        association_table(summaries),
    ]
    for axis in config.axes:
        along = axis_cells(config, axis)
        title = f"{FACTOR_LABELS[axis.factor]}, {held_factor(config, axis)}"
        parts += [
            f"## Axis `{axis.name}`: translation RMSE (m) against {title}\n",
            "Median over seeds of each run's RMSE (the boxes' middle lines in "
            f"fig_{axis.name}.png).\n",
            axis_table(rows, config.methods, axis, along, "translation_rmse", TRANSLATION_DIGITS),
            f"## Axis `{axis.name}`: rotation RMSE (rad) against {title}\n",
            axis_table(rows, config.methods, axis, along, "rotation_rmse", ROTATION_DIGITS),
        ]
    return "\n".join(parts)
