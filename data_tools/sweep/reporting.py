"""The report of a sweep folder: tables.md and a box plot per axis, made from its results.csv
and sweep.json alone (so they can be redone without running anything: see `report.py`).
"""

from __future__ import annotations

from pathlib import Path

from data_tools.sweep.config import SweepConfig, code_versions_of, from_json
from data_tools.sweep.grid import axis_cells
from data_tools.sweep.plots import box_figure
from data_tools.sweep.results import RESULTS_NAME, ResultRow, read_results
from data_tools.sweep.tables import held_factor, render_tables
from pipeline.errors import InputError
from pipeline.outputs import write_text

DESCRIPTION_NAME = "sweep.json"
TABLES_NAME = "tables.md"


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


def write_report(
    out: Path, config: SweepConfig, rows: list[ResultRow], code_versions: tuple[str, ...] = ()
) -> list[Path]:
    """Write tables.md and a figure per axis into `out`; return their paths."""
    written = [out / TABLES_NAME]
    write_text(written[0], render_tables(config, rows, code_versions))
    named = config.name if config.name == config.scenario else f"{config.name} ({config.scenario})"
    for axis in config.axes:
        title = (
            f"{named}, C = {config.num_classes}, {held_factor(config, axis)}; "
            f"a box per method over {len(config.seeds)} seed(s)"
        )
        path = out / figure_name(axis.name)
        written.append(
            box_figure(rows, config.methods, axis, axis_cells(config, axis), path, title)
        )
    return written


def report(out: Path) -> list[Path]:
    """Redo the tables and figures of the sweep folder `out` from its results.csv."""
    out = Path(out)
    config, code_versions = read_description(out)
    return write_report(out, config, read_results(out / RESULTS_NAME), code_versions)
