"""Markdown tables like the paper's Tables I-II, per-axis tables beside the box plots, and per
cell the means over seeds with their intervals and MM + NH's paired comparisons; the summary
lines the sweep command ends with."""

from __future__ import annotations

from collections.abc import Sequence

from data_tools.sweep.config import FACTOR_LABELS, STATED_FACTORS, Axis, SweepConfig
from data_tools.sweep.grid import Cell, axis_cells, base_cell, cells
from data_tools.sweep.inference import CONFIDENCE, RESAMPLES, TIE_M, TIE_SHARE, Comparison, Estimate
from data_tools.sweep.results import ResultRow
from data_tools.sweep.stats import (
    BASELINE,
    CHAMPION,
    NEAR_FACTOR,
    NEAR_MARGIN_M,
    REFERENCE,
    STATISTICS,
    Headline,
    MethodSummary,
    SeedSummary,
    SlowestRun,
    comparisons,
    mean_or_none,
    median_or_none,
    rows_of_cell,
    seed_summaries,
    series,
    slowest_run,
    summarise_methods,
)
from pipeline.backend.noise import MEASUREMENT_COMPONENTS, ODOMETRY_AXES

METHOD_NAMES = {
    "known": "Known DA",
    "ml": "ML",
    "gpda": "GPDA",
    "mm": "MM",
    "mm-nh": "MM + NH",
    "dcsam": "DC-SAM",
}
TRANSLATION_DIGITS = 2
ROTATION_DIGITS = 4
# The per-cell table's figures (stats.SEED_FIGURES): heading and digits.
SEED_COLUMNS = {
    "translation_rmse": ("Translation RMSE (m)", TRANSLATION_DIGITS),
    "rotation_rmse": ("Rotation RMSE (rad)", ROTATION_DIGITS),
    "one_to_one_wrong": ("Wrong", 1),
    "one_to_one_null": ("Missed", 1),
    "landmarks_per_true": ("Landmarks / true", 2),
    "null": ("Null wins", 1),
    "switches": ("Switches", 1),
}
RUNTIME_DIGITS = 1


def method_name(method: str) -> str:
    return METHOD_NAMES.get(method, method)


def slowest_text(slowest: SlowestRun) -> str:
    return (
        f"slowest run {slowest.ratio:.1f}x its cell's median ({slowest.cell}, "
        f"{method_name(slowest.method)}, seed {slowest.seed})"
    )


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


def estimate_text(value: Estimate | None, digits: int) -> str:
    """`mean [low, high]`; the mean alone for a single run; `-` for none."""
    if value is None:
        return "-"
    mean = f"{value.mean:.{digits}f}"
    if value.low is None or value.high is None:
        return mean
    return f"{mean} [{value.low:.{digits}f}, {value.high:.{digits}f}]"


def p_text(p: float | None) -> str:
    return "-" if p is None else f"{p:.3g}"


def seed_table(summaries: Sequence[SeedSummary]) -> str:
    """Per method: mean [95 % interval] over seeds of each figure; the median and worst
    translation RMSE and the runs near Known DA's; the mean replay time."""
    header = ["Method", "Runs"]
    for column, (title, _) in SEED_COLUMNS.items():
        header.append(title)
        if column == "translation_rmse":
            header += ["Median", "Worst", f"Near {method_name(REFERENCE)}"]
    header.append("Time (s)")
    body = []
    for m in summaries:
        row = [method_name(m.method), str(m.runs)]
        for column, (_, digits) in SEED_COLUMNS.items():
            row.append(estimate_text(m.estimates[column], digits))
            if column == "translation_rmse":
                row += [
                    _cell(m.median_translation_rmse, TRANSLATION_DIGITS),
                    _cell(m.worst_translation_rmse, TRANSLATION_DIGITS),
                    "-" if m.near_reference is None else "{} / {}".format(*m.near_reference),
                ]
        row.append(_cell(m.runtime_s, RUNTIME_DIGITS))
        body.append(row)
    return markdown_table(header, body)


def comparison_table(compared: Sequence[tuple[str, Comparison]]) -> str:
    header = [f"{method_name(CHAMPION)} vs", "Seeds", "Wins", "Ties", "Losses"]
    header += ["Wilcoxon p", "Sign test p"]
    body = [
        [
            method_name(method),
            *(str(n) for n in (c.pairs, c.wins, c.ties, c.losses)),
            *(p_text(p) for p in (c.wilcoxon_p, c.sign_p)),
        ]
        for method, c in compared
    ]
    return markdown_table(header, body)


def cell_sections(config: SweepConfig, rows: Sequence[ResultRow]) -> list[str]:
    """For every cell with runs: the seed table and MM + NH's paired comparisons."""
    parts = [
        "## Per cell: means over seeds, and MM + NH seed by seed\n",
        f"Each figure: the mean over the cell's runs (seeds) and, in brackets, its "
        f"{100 * CONFIDENCE:g} % percentile bootstrap interval ({RESAMPLES} resamples, fixed "
        "seed). Wrong and missed: detections of a real landmark that went to another landmark "
        "(a duplicate included) or to none, with landmarks matched to true ones one to one; "
        "landmarks / true: estimated landmarks holding a real landmark's detection, per real "
        "landmark seen; null wins: every detection left to the null hypothesis, false alarms' "
        "included. Median and worst: of the runs' translation RMSE. Near Known DA: the runs "
        f"whose translation RMSE is at most {NEAR_FACTOR:g} times Known DA's on the same seed "
        f"plus {NEAR_MARGIN_M:g} m, of the seeds both have. Time: the mean replay. "
        "`-`: no run recorded the figure (runs made before it was recorded).\n",
        f"{method_name(CHAMPION)} against each method on the same seeds, by translation RMSE: "
        f"a win is a lower RMSE, a tie within {100 * TIE_M:g} cm or {100 * TIE_SHARE:g} % of the "
        "larger; two-sided p-values of the Wilcoxon signed-rank test on the differences (zero "
        "differences left out) and of the sign test on wins against losses; `-`: nothing to "
        "test.\n",
    ]
    for cell in cells(config):
        mine = rows_of_cell(rows, cell)
        if not mine:
            continue
        parts += [
            f"### `{cell.name}`: {cell.label()}\n",
            seed_table(seed_summaries(mine, config.methods)),
        ]
        compared = comparisons(mine, config.methods)
        if compared:
            parts.append(comparison_table(compared))
    return parts


def headline_text(headline: Headline) -> str:
    """A line for the end of the sweep command."""
    line = (
        f"{method_name(headline.method)}: translation RMSE "
        f"{estimate_text(headline.translation_rmse, TRANSLATION_DIGITS)} m over "
        f"{headline.runs} run(s)"
    )
    c = headline.against_baseline
    if c is not None:
        line += (
            f"; against {method_name(BASELINE)} on the same {c.pairs}: wins {c.wins}, "
            f"ties {c.ties}, losses {c.losses}"
        )
    return line


def factor_text(factor: str, value: float) -> str:
    if factor == "misclassification":
        return f"{100 * value:g} %"
    return f"{value:g}x" if factor in STATED_FACTORS else f"{value:g}"


# The noise-learning method whose learnt scales the tables set against the truth.
LEARNER = "mm-nh"
# A direction's learnt scale is shown where its truth or its mean leaves 1 by this factor.
SHOWN_SCALE = 1.25


def scales_table(
    config: SweepConfig, rows: Sequence[ResultRow], axis: Axis, axis_cells_: Sequence[Cell]
) -> str | None:
    """MM + NH's learnt variance scales along an axis, each direction's mean over seeds beside
    the truth the scenario knows (the noise drawn over the noise the log states, `noise_truth`):
    a column for each direction whose truth or learnt scale leaves 1 somewhere on the axis."""
    from data_tools.scenarios import noise_truth

    names = (*ODOMETRY_AXES, *MEASUREMENT_COMPONENTS)
    truth, learnt = [], []
    for cell in axis_cells_:
        truth.append(
            noise_truth(
                config.scenario,
                config.scenario_config,
                cell.odom_noise_scale,
                config.true_covariance,
                cell.stated_noise(),
            )
        )
        mine = [r for r in rows if r.cell == cell.name and r.method == LEARNER]
        learnt.append(
            {n: mean_or_none([getattr(r, f"variance_scale_{n}") for r in mine]) for n in names}
        )
    shown = [
        n
        for n in names
        if any(max(t[n], 1 / t[n]) >= SHOWN_SCALE for t in truth)
        or any(v[n] is not None and max(v[n], 1 / v[n]) >= SHOWN_SCALE for v in learnt)
    ]
    if not shown or all(v[n] is None for v in learnt for n in shown):
        return None
    body = [
        [factor_text(axis.factor, value)] + [f"{_cell(v[n], 3)} ({t[n]:.3g})" for n in shown]
        for value, v, t in zip(axis.values, learnt, truth, strict=True)
    ]
    return markdown_table([FACTOR_LABELS[axis.factor], *shown], body)


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
    """The factors an axis holds at the base cell's values, in words."""
    base = base_cell(config)
    if axis.factor == "odom_noise_scale":
        return f"misclassification {100 * base.misclassification:g} %"
    if axis.factor == "misclassification":
        return f"odometry noise scale {base.odom_noise_scale:g}"
    return (
        f"odometry noise scale {base.odom_noise_scale:g}, "
        f"misclassification {100 * base.misclassification:g} %"
    )


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
    slowest = slowest_run(rows)
    if slowest is not None:
        parts.append(
            f"Replay time: the {slowest_text(slowest)}; a run past 3x is a cost that ran away.\n"
        )
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
        learnt = scales_table(config, rows, axis, along)
        if learnt is not None:
            parts += [
                f"## Axis `{axis.name}`: {method_name(LEARNER)}'s learnt noise scales\n",
                "Each direction's variance scale at the end of the run, the mean over seeds, and "
                "in brackets the truth: the variance of the noise the scenario drew over the "
                "variance its log states.\n",
                learnt,
            ]
    return "\n".join(parts + cell_sections(config, rows))
