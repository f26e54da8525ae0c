"""The report of a sweep folder: tables.md and a box plot per axis, made from its results.csv
and sweep.json alone (so they can be redone without running anything: see `report.py`), and,
where the runs' folders are there, the paper's Fig. 5: the trajectory of one representative
run per method in the base cell (the seed whose MM + NH RMSE is the median), by `mmslam plot`.

The report (results.csv, tables.md, the figures, run.json) is one set of files, replaced all
or nothing (`pipeline.outputs.FileSet`): written into `REPORT`'s staging folder, then moved
into the sweep's folder together.
"""

from __future__ import annotations

import logging
from pathlib import Path

from data_tools.sweep.config import SweepConfig, code_versions_of, from_json
from data_tools.sweep.grid import RunKey, axis_cells, base_cell, log_path, run_dir
from data_tools.sweep.plots import box_figure
from data_tools.sweep.results import RESULTS_NAME, ResultRow, read_results
from data_tools.sweep.stats import CHAMPION, representative_seed, rows_of_cell
from data_tools.sweep.tables import held_factor, method_name, render_tables
from pipeline.errors import InputError
from pipeline.outputs import FileSet, write_text

logger = logging.getLogger(__name__)

REPORT = "report"  # the name of the report's set of files (`FileSet`)
DESCRIPTION_NAME = "sweep.json"
TABLES_NAME = "tables.md"
TRAJECTORIES_NAME = "fig_trajectories.png"
RUN_FILES = ("metrics.json", "trajectory.tum", "landmarks.csv")  # what `mmslam plot` reads


def figure_name(axis_name: str) -> str:
    return f"fig_{axis_name}.png"


def read_description(out: Path) -> tuple[SweepConfig, tuple[str, ...]]:
    """The sweep's config and the code versions that made its runs, from its sweep.json."""
    path = out / DESCRIPTION_NAME
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"{out}: no {DESCRIPTION_NAME}; is it a sweep's output folder?") from None
    return from_json(text, path), code_versions_of(text)


def trajectory_figure(
    out: Path, config: SweepConfig, rows: list[ResultRow], into: Path
) -> Path | None:
    """Write the base cell's representative runs of the sweep folder `out`, a panel per
    method, to fig_trajectories.png in `into`; None without an MM + NH run to choose the seed
    by, or (with a warning) where the runs' folders are not there to plot."""
    cell = base_cell(config)
    mine = rows_of_cell(rows, cell)
    seed = representative_seed(mine, CHAMPION)
    if seed is None:
        return None
    folders = [run_dir(out, RunKey(cell, seed, m)) for m in config.methods]
    folders = [f for f in folders if all((f / name).is_file() for name in RUN_FILES)]
    log = log_path(out, cell, seed)
    if not folders or not log.is_file():
        logger.warning(
            "%s: the runs of %s seed %d are not there: no %s",
            out,
            cell.name,
            seed,
            TRAJECTORIES_NAME,
        )
        return None
    from data_tools.plot_runs import plot_runs

    seeds = sum(r.method == CHAMPION for r in mine)
    title = (
        f"{config.name}, {cell.label()}: seed {seed}, the median {method_name(CHAMPION)} "
        f"translation RMSE of {seeds} seed(s)"
    )
    path = into / TRAJECTORIES_NAME
    plot_runs(log, folders, path, title)
    return path


def write_report(
    out: Path,
    config: SweepConfig,
    rows: list[ResultRow],
    code_versions: tuple[str, ...] = (),
    into: Path | None = None,
) -> list[Path]:
    """Write tables.md and a figure per axis of the sweep folder `out` into `into` (default
    `out`); return their paths."""
    into = out if into is None else into
    written = [into / TABLES_NAME]
    write_text(written[0], render_tables(config, rows, code_versions))
    named = config.name if config.name == config.scenario else f"{config.name} ({config.scenario})"
    for axis in config.axes:
        title = (
            f"{named}, C = {config.num_classes}, {held_factor(config, axis)}; "
            f"a box per method over {len(config.seeds)} seed(s)"
        )
        path = into / figure_name(axis.name)
        written.append(
            box_figure(rows, config.methods, axis, axis_cells(config, axis), path, title)
        )
    trajectories = trajectory_figure(out, config, rows, into)
    return written if trajectories is None else [*written, trajectories]


def report(out: Path) -> list[Path]:
    """Redo the tables and figures of the sweep folder `out` from its results.csv, together."""
    out = Path(out)
    config, code_versions = read_description(out)
    with FileSet(out, REPORT) as files:  # first completes a report a killed sweep left
        rows = read_results(out / RESULTS_NAME)
        written = write_report(out, config, rows, code_versions, into=files.staging)
        files.commit()
    return [out / path.name for path in written]
