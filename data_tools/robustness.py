"""The association suite: every `robust-*` sweep of configs/sweeps/ (street grids in two worlds,
indoor tags and KITTI 05 with their noise stated and understated, a planar park), run or
resumed, and one table of how each method fares on all of them. `--suite numerics` runs the
`numerics-*` sweeps instead: every association method where the solver once fell back (indoor
tags with Known DA over 31 seeds, KITTI 05 at noise 1-5, the planar park, two street grids).

    python -m data_tools.robustness --out out/robust [--suite robust|numerics] [--workers N]
        [--seeds N] [--only NAME ...]

Each sweep's runs go to OUT/<name> (`mmslam sweep` resumes them there). The table gives, per
sweep and method, over its seeds: mean, median and worst translation RMSE (m); wrong and
missed associations, one to one; null-hypothesis wins; landmarks per true landmark; mean replay
time; solver fallbacks (batch solves and QR, summed; each one a bug); and the seeds within 1.5x
Known DA's RMSE + 0.5 m that are also no worse than ML's (the association issue's target for
MM + NH).
"""

from __future__ import annotations

import argparse
import logging
import statistics
import sys
from collections.abc import Sequence
from pathlib import Path

from data_tools.sweep.results import RESULTS_NAME, ResultRow, read_results
from data_tools.sweep.stats import BASELINE, NEAR_FACTOR, NEAR_MARGIN_M, REFERENCE
from data_tools.sweep.tables import markdown_table, method_name
from pipeline.settings import config_path

logger = logging.getLogger(__name__)

SUITES = ("robust", "numerics")


def suite(name: str = "robust") -> list[str]:
    """The names of the suite's sweeps: configs/sweeps/NAME-*.toml."""
    return sorted(p.stem for p in config_path("sweeps").glob(f"{name}-*.toml"))


def _fallbacks(rows: Sequence[ResultRow]) -> str:
    """The runs' solver fallbacks, summed ("-" where a run did not record them)."""
    counts = [(r.fallbacks_batch, r.fallbacks_qr) for r in rows]
    if any(None in c for c in counts):
        return "-"
    return str(sum(b + q for b, q in counts))


def near(rows: Sequence[ResultRow], method: str) -> tuple[int, int]:
    """How many of `method`'s seeds are within NEAR_FACTOR x Known DA + NEAR_MARGIN_M and, for
    methods other than the baseline, no worse than the baseline; out of how many seeds."""
    rmse = {(r.method, r.seed): r.translation_rmse for r in rows}
    seeds = sorted({r.seed for r in rows if r.method == method})
    count = 0
    for seed in seeds:
        ours, known = rmse[method, seed], rmse.get((REFERENCE, seed))
        baseline = rmse.get((BASELINE, seed), float("inf"))
        if known is not None and ours <= NEAR_FACTOR * known + NEAR_MARGIN_M:
            count += method == BASELINE or ours <= baseline
    return count, len(seeds)


def _mean(values: Sequence[float | None]) -> str:
    known = [v for v in values if v is not None]
    return f"{statistics.fmean(known):.1f}" if known else "-"


def suite_table(results: dict[str, list[ResultRow]]) -> str:
    """One Markdown table: a row per sweep and method."""
    header = [
        "sweep", "method", "mean", "median", "worst", "wrong", "missed", "null",
        "landmarks / true", "time s", "fallbacks", "near",
    ]  # fmt: skip
    rows = []
    for name, runs in results.items():
        for method in dict.fromkeys(r.method for r in runs):
            mine = [r for r in runs if r.method == method]
            rmse = [r.translation_rmse for r in mine]
            per_true = [r.landmarks_per_true for r in mine]
            near_count, seeds = near(runs, method)
            rows.append(
                [
                    name.split("-", 1)[1],
                    method_name(method),
                    f"{statistics.fmean(rmse):.2f}",
                    f"{statistics.median(rmse):.2f}",
                    f"{max(rmse):.2f}",
                    _mean([r.one_to_one_wrong for r in mine]),
                    _mean([r.one_to_one_null for r in mine]),
                    _mean([r.null for r in mine]),
                    "-" if None in per_true else f"{statistics.fmean(per_true):.2f}",
                    f"{statistics.fmean(r.runtime_s for r in mine):.1f}",
                    _fallbacks(mine),
                    "-" if method == REFERENCE else f"{near_count} / {seeds}",
                ]
            )
    return markdown_table(header, rows)


def main(argv: Sequence[str] | None = None) -> int:
    from data_tools.sweep.sweep import run_sweep

    parser = argparse.ArgumentParser(prog="python -m data_tools.robustness", description=__doc__)
    parser.add_argument("--out", type=Path, required=True, help="a folder per sweep under it")
    parser.add_argument("--workers", type=int, default=None, help="processes (default: cores)")
    parser.add_argument("--seeds", type=int, default=None, help="seeds 0..N-1 in every sweep")
    parser.add_argument("--suite", choices=SUITES, default="robust", help="which sweeps")
    parser.add_argument("--only", nargs="+", metavar="NAME", help="these sweeps of the suite")
    parser.add_argument("--report", action="store_true", help="only the table of what is there")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    names = suite(args.suite)
    if args.only:
        unknown = sorted(set(args.only) - set(names))
        if unknown:
            parser.error(f"not in the suite: {', '.join(unknown)}; it holds {', '.join(names)}")
        names = [n for n in names if n in args.only]
    results = {}
    for name in names:
        out = args.out / name
        if not args.report:
            summary = run_sweep(
                config_path(f"sweeps/{name}.toml"), out, workers=args.workers, seeds=args.seeds
            )
            print(summary.summary_line(), file=sys.stderr)
        if (out / RESULTS_NAME).exists():
            results[name] = read_results(out / RESULTS_NAME)
    print(suite_table(results), end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
