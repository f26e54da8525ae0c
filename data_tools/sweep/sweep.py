"""`mmslam sweep`: every run of a sweep config not yet finished, then results, tables, figures.

Reads as the steps it takes: load the config, claim the output folder, find the runs already
finished (kept), run the others (in a local process pool or on a Dask cluster), then write
the report of all finished runs (results.csv, tables.md, the figures, run.json) as one set. A
failed run is logged, recorded in its folder's error.txt and left unfinished, so the next
sweep into the same folder tries it again.
"""

from __future__ import annotations

import logging
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from data_tools.sweep.config import SweepConfig, load_sweep_config, to_json, with_seeds
from data_tools.sweep.executors import default_workers, execute
from data_tools.sweep.grid import RUNS_DIR, RunKey, log_path, run_dir, runs
from data_tools.sweep.reporting import DESCRIPTION_NAME, REPORT, read_description, write_report
from data_tools.sweep.results import RESULTS_NAME, row_from_metrics, write_results
from data_tools.sweep.stats import headlines, slowest_run
from data_tools.sweep.tables import headline_text, slowest_text
from data_tools.sweep.work import (
    ERROR_FILE,
    RunOutcome,
    RunTask,
    finished_metrics,
)
from pipeline import provenance
from pipeline.errors import InputError, terminated_on_sigterm
from pipeline.outputs import (
    METRICS,
    FileSet,
    metrics_json,
    refuse_read_only,
    write_outputs,
    write_text,
)
from pipeline.progress import Progress

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class SweepSummary:
    name: str
    out: Path
    total: int  # runs in the sweep
    new: int  # finished by this call
    kept: int  # finished before, skipped
    failed: tuple[str, ...]  # "cell/seed/method: error", runs that raised
    seconds: float
    files: tuple[Path, ...]  # results.csv, tables.md, figures
    method_lines: tuple[str, ...] = ()  # per method: mean translation RMSE, wins against ML
    slowest: str = ""  # the run slowest against its cell's median (`stats.slowest_run`)

    def summary_line(self) -> str:
        line = (
            f"sweep {self.name}: {self.total} runs ({self.new} new, {self.kept} kept"
            f"{f', {len(self.failed)} failed' if self.failed else ''}) in {self.seconds:.0f} s"
            f" -> {', '.join(str(f) for f in self.files)}"
        )
        if self.slowest:
            line += f"; {self.slowest}"
        if self.failed:
            line += f"; first failure: {self.failed[0]} (see its {ERROR_FILE})"
        return line


def code_version() -> str:
    """`git describe --always --dirty` of the mmslam source, or "unknown" outside git."""
    root = Path(__file__).resolve().parents[2]
    try:
        done = subprocess.run(
            ["git", "-C", str(root), "describe", "--always", "--dirty"],
            capture_output=True,
            text=True,
            timeout=10,
            check=True,
        )
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return done.stdout.strip() or "unknown"


def claim_folder(out: Path, config: SweepConfig) -> tuple[str, ...]:
    """Make `out` the folder of this sweep; refuse one holding runs of another set-up.
    Returns the code versions that made the runs already there."""
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: exists and is not a directory")
    refuse_read_only(out, out)
    versions: tuple[str, ...] = ()
    if (out / DESCRIPTION_NAME).exists():
        earlier, versions = read_description(out)
        if earlier.fingerprint != config.fingerprint and (out / RUNS_DIR).exists():
            raise InputError(
                f"--out {out}: holds runs of another set-up (scenario, scenario or back-end "
                "config, classes or covariance differ); choose another folder"
            )
    elif out.exists() and any(out.iterdir()):
        raise InputError(f"--out {out}: not empty and not a sweep's folder")
    out.mkdir(parents=True, exist_ok=True)
    write_text(out / DESCRIPTION_NAME, to_json(config, versions))
    return versions


def note_code_version(out: Path, config: SweepConfig, versions: tuple[str, ...]) -> tuple[str, ...]:
    """Add this code's version to those that made the folder's runs (before making more)."""
    version = code_version()
    if version in versions:
        return versions
    if versions:
        kept = ", ".join(versions)
        logger.warning("%s: runs kept from mmslam %s, new ones by %s", out, kept, version)
    versions = (*versions, version)
    write_text(out / DESCRIPTION_NAME, to_json(config, versions))
    return versions


def make_task(config: SweepConfig, out: Path, key: RunKey) -> RunTask:
    return RunTask(
        key=key,
        scenario=config.scenario,
        scenario_config=config.scenario_config,
        backend_config=config.backend_config,
        num_classes=config.num_classes,
        true_covariance=config.true_covariance,
        log_path=log_path(out, key.cell, key.seed).resolve(),
        run_dir=run_dir(out, key).resolve(),
    )


def record(out: Path, outcome: RunOutcome) -> None:
    """Keep a finished run's metrics on disk (a Dask worker may not share our disk), or a
    failed run's traceback."""
    folder = run_dir(out, outcome.key)
    if outcome.metrics is not None:
        if finished_metrics(folder, outcome.key.method) is None:
            write_outputs(folder, {METRICS: metrics_json(outcome.metrics)})
        return
    folder.mkdir(parents=True, exist_ok=True)
    write_text(folder / ERROR_FILE, outcome.details or outcome.error or "failed\n")


class _Progress:
    """The sweep's progress (`pipeline.progress`), and a log line per run."""

    def __init__(self, total: int, enabled: bool):
        self.total, self.done = total, 0
        self.shown = Progress(total, "sweep", "run", enabled=enabled and total > 0)

    def update(self, outcome: RunOutcome) -> None:
        self.done += 1
        status = "failed: " + (outcome.error or "") if outcome.metrics is None else "done"
        self.shown.update(note=outcome.key.label())
        logger.info(
            "[%d/%d] %s %s (%.1f s)",
            self.done,
            self.total,
            outcome.key.label(),
            status,
            outcome.seconds,
        )

    def close(self) -> None:
        self.shown.close()


def finished_runs(out: Path, keys: list[RunKey]) -> dict[RunKey, dict[str, Any]]:
    """The metrics of the runs among `keys` already finished in `out`."""
    found = {key: finished_metrics(run_dir(out, key), key.method) for key in keys}
    return {key: metrics for key, metrics in found.items() if metrics is not None}


def run_pending(
    out: Path,
    tasks: list[RunTask],
    metrics: dict[RunKey, dict[str, Any]],
    *,
    workers: int,
    dask_address: str | None,
    progress: bool,
) -> list[str]:
    """Run `tasks`, adding the metrics of each finished one to `metrics`; return the failures."""
    where = f"Dask cluster {dask_address}" if dask_address else f"{workers} local worker(s)"
    logger.info("%d runs to do on %s", len(tasks), where)
    failed: list[str] = []
    bar = _Progress(len(tasks), progress)
    try:
        for outcome in execute(tasks, workers=workers, dask_address=dask_address):
            record(out, outcome)
            if outcome.metrics is not None:
                metrics[outcome.key] = outcome.metrics
            else:
                failed.append(f"{outcome.key.label()}: {outcome.error}")
                logger.warning("run %s failed: %s", outcome.key.label(), outcome.error)
            bar.update(outcome)
    finally:
        bar.close()
    return sorted(failed)


def run_sweep(
    config_path: Path,
    out: Path,
    *,
    workers: int | None = None,
    dask_address: str | None = None,
    seeds: int | None = None,
    progress: bool = True,
) -> SweepSummary:
    """Run every unfinished run of the sweep `config_path` into `out`, then write
    results.csv, tables.md, a figure per axis and run.json there, together. Runs finished
    earlier are kept. `seeds` replaces the config's seeds by 0..seeds-1.

    `workers` local processes (default: the cores), or the workers of the Dask scheduler at
    `dask_address`. Local workers are spawned, so a script that calls this with more than one
    worker needs the usual `if __name__ == "__main__":` guard. SIGTERM stops it as Ctrl-C
    does, raising `Terminated` (a KeyboardInterrupt): the finished runs are kept."""
    with terminated_on_sigterm():
        return _run_sweep(config_path, out, workers, dask_address, seeds, progress)


def _run_sweep(
    config_path: Path,
    out: Path,
    workers: int | None,
    dask_address: str | None,
    seeds: int | None,
    progress: bool,
) -> SweepSummary:
    start, started = time.perf_counter(), provenance.utc_now()
    if workers is not None and (isinstance(workers, bool) or workers < 1):
        raise InputError(f"--workers must be at least 1, got {workers!r}")
    if workers is not None and dask_address is not None:
        raise InputError("--workers and --dask exclude each other: the cluster has its workers")
    config = load_sweep_config(config_path)
    if seeds is not None:
        config = with_seeds(config, seeds)
    out = Path(out)
    code_versions = claim_folder(out, config)

    keys = runs(config)
    metrics = finished_runs(out, keys)
    kept = len(metrics)
    tasks = [make_task(config, out, key) for key in keys if key not in metrics]
    if tasks:
        code_versions = note_code_version(out, config, code_versions)
    logger.info("sweep %s: %d runs, %d finished before", config.name, len(keys), kept)
    failed = run_pending(
        out,
        tasks,
        metrics,
        workers=workers or default_workers(),
        dask_address=dask_address,
        progress=progress,
    )

    rows = [row_from_metrics(key, metrics[key]) for key in keys if key in metrics]
    with FileSet(out, REPORT) as report:  # all or nothing, as a replay's outputs
        write_results(report.path(RESULTS_NAME), rows)
        staged = [report.path(RESULTS_NAME)]
        staged += write_report(out, config, rows, code_versions, into=report.staging)
        record = provenance.run_json(config, [config_path], started, time.perf_counter() - start)
        write_text(report.path(provenance.RUN_RECORD), record)
        staged.append(report.path(provenance.RUN_RECORD))
        report.commit()
    files = [out / path.name for path in staged]
    return SweepSummary(
        name=config.name,
        out=out,
        total=len(keys),
        new=len(metrics) - kept,
        kept=kept,
        failed=tuple(failed),
        seconds=time.perf_counter() - start,
        files=tuple(files),
        method_lines=tuple(headline_text(h) for h in headlines(rows, config.methods)),
        slowest=slowest_text(slowest) if (slowest := slowest_run(rows)) else "",
    )
