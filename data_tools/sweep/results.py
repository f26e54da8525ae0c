"""`results.csv`: a row per run (cell, seed, method, every metric, runtime), written and read
here only. Floats are written in Python's shortest round-trip form, so reading gives back the
very numbers written.

The optional columns (the one-to-one association scores, merges, the back-end's noise scales,
its solver fallbacks)
are None, an empty field, wherever a run's metrics.json lacks them: runs made before the
back-end recorded them are kept, not re-run, and a results.csv written before the columns
existed reads with them empty.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import astuple, dataclass, fields
from pathlib import Path
from typing import Any

from data_tools.sweep.grid import RunKey
from pipeline.backend.noise import MEASUREMENT_COMPONENTS, ODOMETRY_AXES
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
    # metrics.json's association_one_to_one: landmarks matched to true ones one to one, so a
    # duplicate's detections count as wrong; null = detections of real landmarks left to none
    one_to_one_correct: int | None = None
    one_to_one_wrong: int | None = None
    one_to_one_null: int | None = None
    one_to_one_precision: float | None = None
    one_to_one_recall: float | None = None
    landmarks_per_true: float | None = None
    false_positives_used: int | None = None
    true_landmarks_seen: int | None = None
    merges: int | None = None
    # metrics.json's noise_scales: variance scales of the odometry per direction and of each
    # measurement component at the end of the run (learnt online, or as configured), and the
    # moves that learnt them
    variance_scale_roll: float | None = None
    variance_scale_pitch: float | None = None
    variance_scale_yaw: float | None = None
    variance_scale_forward: float | None = None
    variance_scale_lateral: float | None = None
    variance_scale_vertical: float | None = None
    variance_scale_bearing: float | None = None
    variance_scale_elevation: float | None = None
    variance_scale_range: float | None = None
    noise_moves: int | None = None
    # metrics.json's solver_fallbacks: graphs Cholesky refused (each a bug), by what followed
    fallbacks_batch: int | None = None
    fallbacks_qr: int | None = None


COLUMNS: tuple[str, ...] = tuple(f.name for f in fields(ResultRow))
OPTIONAL: frozenset[str] = frozenset(f.name for f in fields(ResultRow) if "None" in str(f.type))
_KINDS = {"str": str, "int": int, "float": float, "int | None": int, "float | None": float}
_TYPES = {f.name: _KINDS[str(f.type)] for f in fields(ResultRow)}
ONE_TO_ONE = {  # column: key in metrics.json's association_one_to_one
    "one_to_one_correct": "correct",
    "one_to_one_wrong": "wrong",
    "one_to_one_null": "null",
    "one_to_one_precision": "precision",
    "one_to_one_recall": "recall",
    "landmarks_per_true": "landmarks_per_true",
    "false_positives_used": "false_positives_used",
    "true_landmarks_seen": "true_landmarks_seen",
}
# metrics.json's noise_scales tables, and the columns of each direction's scale
SCALE_COLUMNS = {
    "odometry": {a: f"variance_scale_{a}" for a in ODOMETRY_AXES},
    "measurement": {c: f"variance_scale_{c}" for c in MEASUREMENT_COMPONENTS},
}


def _optional(value: Any, kind: type) -> Any:
    """`value` as `kind`, or None where it is missing or not a finite number."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        return None
    return kind(value)


def optional_columns(metrics: dict[str, Any]) -> dict[str, Any]:
    """The optional columns from a metrics.json; None for each figure it does not hold."""
    one_to_one = metrics.get("association_one_to_one")
    one_to_one = one_to_one if isinstance(one_to_one, dict) else {}
    scales = metrics.get("noise_scales")
    scales = scales if isinstance(scales, dict) else {}
    values = {c: one_to_one.get(key) for c, key in ONE_TO_ONE.items()}
    values["merges"] = metrics.get("merges")
    for table, columns in SCALE_COLUMNS.items():
        by_name = scales.get(table)
        by_name = by_name if isinstance(by_name, dict) else {}
        values.update({column: by_name.get(name) for name, column in columns.items()})
    moves = scales.get("moves")
    values["noise_moves"] = len(moves) if isinstance(moves, list) else None
    fallbacks = metrics.get("solver_fallbacks")
    fallbacks = fallbacks if isinstance(fallbacks, dict) else {}
    values["fallbacks_batch"] = fallbacks.get("batch")
    values["fallbacks_qr"] = fallbacks.get("qr")
    return {c: _optional(v, _TYPES[c]) for c, v in values.items()}


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
        **optional_columns(metrics),
    )


def _text(value: Any) -> str:
    if value is None:
        return ""
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
    """The rows of a results.csv; a missing column (but an optional one) or a bad number is an
    `InputError`. An optional column missing or empty reads as None."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    reader = csv.DictReader(io.StringIO(text))
    present = [c for c in COLUMNS if c in (reader.fieldnames or [])]
    missing = [c for c in COLUMNS if c not in present and c not in OPTIONAL]
    if missing:
        raise InputError(f"{path}: missing column '{missing[0]}'")
    rows = []
    for line, record in enumerate(reader, start=2):
        if None in record or any(record[c] is None for c in present):
            raise InputError(f"{path} line {line}: wrong number of fields")
        values = {
            c: None
            if c in OPTIONAL and record[c] == ""
            else _parse(record[c], _TYPES[c], path, line, c)
            for c in present
        }
        rows.append(ResultRow(**values))
    return rows
