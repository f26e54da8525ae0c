"""`results.csv`: a row per run (cell, seed, method, every metric, runtime), written and read
here only. Floats are written in Python's shortest round-trip form, so reading gives back the
very numbers written.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import astuple, dataclass, fields
from pathlib import Path
from typing import Any

from data_tools.sweep.grid import RunKey
from pipeline.errors import InputError
from pipeline.outputs import write_text

RESULTS_NAME = "results.csv"


@dataclass(frozen=True)
class ResultRow:
    cell: str
    odom_noise_scale: float
    misclassification: float
    seed: int
    method: str
    translation_max: float  # m, statistics of the run's per-pose absolute errors
    translation_mean: float
    translation_median: float
    translation_rmse: float
    rotation_max: float  # rad
    rotation_mean: float
    rotation_median: float
    rotation_rmse: float
    correct: int  # detections by their final association
    wrong: int
    null: int
    unlabelled: int
    switches: int
    num_poses: int
    num_detections: int
    num_landmarks: int
    runtime_s: float  # the replay's, as metrics.json says


COLUMNS: tuple[str, ...] = tuple(f.name for f in fields(ResultRow))
_TYPES = {f.name: {"str": str, "int": int, "float": float}[str(f.type)] for f in fields(ResultRow)}


def row_from_metrics(key: RunKey, metrics: dict[str, Any]) -> ResultRow:
    t, r, a = metrics["translation_error_m"], metrics["rotation_error_rad"], metrics["association"]
    return ResultRow(
        cell=key.cell.name,
        odom_noise_scale=key.cell.odom_noise_scale,
        misclassification=key.cell.misclassification,
        seed=key.seed,
        method=key.method,
        translation_max=float(t["max"]),
        translation_mean=float(t["mean"]),
        translation_median=float(t["median"]),
        translation_rmse=float(t["rmse"]),
        rotation_max=float(r["max"]),
        rotation_mean=float(r["mean"]),
        rotation_median=float(r["median"]),
        rotation_rmse=float(r["rmse"]),
        correct=int(a["correct"]),
        wrong=int(a["wrong"]),
        null=int(a["null"]),
        unlabelled=int(a.get("unlabelled", 0)),
        switches=int(metrics.get("switches", 0)),
        num_poses=int(metrics["num_poses"]),
        num_detections=int(metrics["num_detections"]),
        num_landmarks=int(metrics["num_landmarks"]),
        runtime_s=float(metrics["runtime_s"]),
    )


def _text(value: Any) -> str:
    return repr(value) if isinstance(value, float) else str(value)


def results_text(rows: list[ResultRow]) -> str:
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(COLUMNS)
    writer.writerows([_text(v) for v in astuple(row)] for row in rows)
    return buffer.getvalue()


def write_results(path: Path, rows: list[ResultRow]) -> None:
    """Write `rows` to `path` atomically."""
    write_text(path, results_text(rows))


def _parse(value: str, kind: type, path: Path, line: int, column: str) -> Any:
    try:
        parsed = kind(value)
    except ValueError:
        raise InputError(
            f"{path} line {line}: '{column}' must be {kind.__name__}, got {value!r}"
        ) from None
    if kind is float and not math.isfinite(parsed):
        raise InputError(f"{path} line {line}: '{column}' must be finite, got {value!r}")
    return parsed


def read_results(path: Path) -> list[ResultRow]:
    """The rows of a results.csv; any missing column or bad number is an `InputError`."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    reader = csv.DictReader(io.StringIO(text))
    missing = [c for c in COLUMNS if c not in (reader.fieldnames or [])]
    if missing:
        raise InputError(f"{path}: missing column '{missing[0]}'")
    rows = []
    for line, record in enumerate(reader, start=2):
        if None in record or any(record[c] is None for c in COLUMNS):
            raise InputError(f"{path} line {line}: wrong number of fields")
        rows.append(ResultRow(**{c: _parse(record[c], _TYPES[c], path, line, c) for c in COLUMNS}))
    return rows
