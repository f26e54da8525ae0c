"""One run of a sweep, as a worker does it: make (or reuse) the log, replay it, return metrics.

`run_task` is a top-level function of picklable arguments, so that a process pool and a Dask
cluster can both call it. The log of a (cell, seed) is made once, under a file lock, and shared
by that cell and seed's methods; its SHA-256 is recorded beside it, and a log that no longer
matches (cut short, overwritten, corrupted on disk) is made again before it is used. A run is
finished when its `metrics.json` is complete on disk; the replay swaps in its output folder
whole, so a half-done run never looks finished.
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import logging
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from data_tools.sweep.grid import RunKey
from pipeline.errors import first_line
from pipeline.outputs import METRICS, write_text

logger = logging.getLogger(__name__)

STATISTICS = ("max", "mean", "median", "rmse")
ASSOCIATION = ("correct", "wrong", "null")
ERROR_FILE = "error.txt"


@dataclass(frozen=True)
class RunTask:
    """Everything a worker needs for one run; paths are the driver's (a shared folder)."""

    key: RunKey
    scenario: str
    scenario_config: Path | None
    backend_config: Path | None
    num_classes: int
    true_covariance: bool
    log_path: Path
    run_dir: Path


@dataclass(frozen=True)
class RunOutcome:
    key: RunKey
    metrics: dict[str, Any] | None  # None when the run failed
    error: str | None  # the exception's type and message, when it failed
    details: str | None  # its traceback
    seconds: float  # wall time on the worker, log included


def complete_metrics(metrics: Any, method: str) -> bool:
    """Whether `metrics` (read from a metrics.json) holds everything a result row needs."""
    if not isinstance(metrics, dict) or metrics.get("method") != method:
        return False
    try:
        groups = ("translation_error_m", "rotation_error_rad")
        numbers = [metrics[group][s] for group in groups for s in STATISTICS]
        numbers += [metrics["association"][a] for a in ASSOCIATION]
        numbers += [metrics[k] for k in ("runtime_s", "num_poses", "num_detections")]
        numbers.append(metrics["num_landmarks"])
    except (KeyError, TypeError):
        return False
    return all(isinstance(n, int | float) and not isinstance(n, bool) for n in numbers)


def finished_metrics(run_dir: Path, method: str) -> dict[str, Any] | None:
    """The metrics of a finished run in `run_dir`, or None if it has not finished."""
    try:
        metrics = json.loads((run_dir / METRICS).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return metrics if complete_metrics(metrics, method) else None


def digest_path(log_path: Path) -> Path:
    """Where the SHA-256 of a cached log is kept (sha256sum's format: `sha256sum -c` reads it)."""
    return log_path.with_name(log_path.name + ".sha256")


def file_digest(path: Path) -> str:
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


def cached_log_is_intact(log_path: Path) -> bool:
    """Whether the log is there with the digest recorded when it was written."""
    try:
        recorded = digest_path(log_path).read_text(encoding="utf-8").split()[0]
        return file_digest(log_path) == recorded
    except (OSError, IndexError):
        return False


def ensure_log(task: RunTask) -> None:
    """Make the log of the task's cell and seed unless it is there intact (checked against the
    digest recorded when it was made), once, whoever asks first."""
    from data_tools.scenarios import simulate

    task.log_path.parent.mkdir(parents=True, exist_ok=True)
    lock_path = task.log_path.with_name(f".{task.log_path.name}.lock")
    with open(lock_path, "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            if cached_log_is_intact(task.log_path):  # made earlier, or while we waited
                return
            if task.log_path.exists():
                logger.warning("%s: not as it was written; making it again", task.log_path)
            simulate(
                task.scenario,
                task.log_path,
                seed=task.key.seed,
                odom_noise_scale=task.key.cell.odom_noise_scale,
                misclassification=task.key.cell.misclassification,
                stated=task.key.cell.stated_noise(),
                num_classes=task.num_classes,
                true_covariance=task.true_covariance,
                config_path=task.scenario_config,
                foxglove=False,  # only replayed
            )
            digest = file_digest(task.log_path)
            write_text(digest_path(task.log_path), f"{digest}  {task.log_path.name}\n")
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def run_task(task: RunTask) -> RunOutcome:
    """Make the log if needed and replay it with the task's method into its run folder."""
    from pipeline.config import load_config
    from pipeline.replay import replay

    start = time.perf_counter()
    try:
        ensure_log(task)
        result = replay(
            task.log_path,
            task.key.method,
            task.run_dir,
            load_config(task.backend_config),
            progress=False,
        )
        if "translation_error_m" not in result.metrics:
            raise ValueError(f"{task.log_path} has no ground truth to score the run against")
        (task.run_dir / ERROR_FILE).unlink(missing_ok=True)
        return RunOutcome(task.key, result.metrics, None, None, time.perf_counter() - start)
    except Exception as exc:
        message = f"{type(exc).__name__}: {first_line(str(exc))}"
        details = traceback.format_exc()
        return RunOutcome(task.key, None, message, details, time.perf_counter() - start)
