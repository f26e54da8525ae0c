"""The log's one `mmslam` metadata record: written from `LogMetadata`, read back checked."""

from __future__ import annotations

import json
import math
import re
from typing import Any

from pipeline.log import limits
from pipeline.log.codec import parse_json, shown
from pipeline.log.messages import FORMAT_VERSION, METADATA_NAME, LogMetadata

KEYS = ("format_version", "num_classes", "confusion_matrix", "class_names", "source")
_COUNT = re.compile(r"^[1-9][0-9]{0,9}$")  # int() would also take " 2", "+2" and "2_0"


def metadata_record(metadata: LogMetadata) -> dict[str, str]:
    return {
        "format_version": metadata.format_version,
        "num_classes": str(metadata.num_classes),
        "confusion_matrix": json.dumps([list(row) for row in metadata.confusion_matrix]),
        "class_names": json.dumps(list(metadata.class_names)),
        "source": metadata.source,
    }


def find_record(records: list[tuple[str, dict[str, str]]]) -> dict[str, str]:
    """The one record named `mmslam` among a log's (name, record) pairs; ValueError otherwise."""
    ours = [record for name, record in records if name == METADATA_NAME]
    if not ours:
        raise ValueError(f"no metadata record named '{METADATA_NAME}'")
    if len(ours) > 1:
        raise ValueError(f"{len(ours)} metadata records named '{METADATA_NAME}'; one is allowed")
    return ours[0]


def _confusion_matrix(text: str, num_classes: int) -> tuple[tuple[float, ...], ...]:
    matrix = parse_json(text)
    if (
        not isinstance(matrix, list)
        or len(matrix) != num_classes
        or any(not isinstance(row, list) or len(row) != num_classes for row in matrix)
    ):
        raise ValueError(f"confusion_matrix must be {num_classes} x {num_classes}")
    rows = []
    for i, row in enumerate(matrix):
        values = []
        for v in row:
            if isinstance(v, bool) or not isinstance(v, int | float):
                raise ValueError(f"confusion_matrix row {i} holds {shown(v)}, not a number")
            if not 0 <= v <= 1:  # compares big integers without turning them into floats
                raise ValueError(f"confusion_matrix row {i} holds {shown(v)}, outside 0..1")
            values.append(float(v))
        total = math.fsum(values)
        if abs(total - 1.0) > limits.ROW_SUM_TOLERANCE:
            raise ValueError(f"confusion_matrix row {i} sums to {total:.9g}, not 1")
        rows.append(tuple(values))
    return tuple(rows)


def _class_names(text: str, num_classes: int) -> tuple[str, ...]:
    names: Any = parse_json(text)
    if not isinstance(names, list) or len(names) != num_classes:
        raise ValueError(f"class_names must be a list of {num_classes} names")
    for k, name in enumerate(names):
        if not isinstance(name, str) or not 0 < len(name) <= limits.MAX_CLASS_NAME_CHARS:
            raise ValueError(
                f"class_names[{k}] must be a name of 1..{limits.MAX_CLASS_NAME_CHARS} "
                f"characters, got {shown(name)}"
            )
    if len(set(names)) != len(names):
        raise ValueError("class_names names a class twice")
    return tuple(names)


def parse_metadata(record: dict[str, str]) -> LogMetadata:
    """The `mmslam` metadata record, checked; raises ValueError with the reason."""
    for key in KEYS:
        if key not in record:
            raise ValueError(f"metadata '{METADATA_NAME}' lacks '{key}'")
    if record["format_version"] != FORMAT_VERSION:
        raise ValueError(
            f"format_version {shown(record['format_version'])} is not supported (expected "
            f"{FORMAT_VERSION!r})"
        )
    text = record["num_classes"]
    if not _COUNT.match(text) or not int(text) <= limits.MAX_CLASSES:
        raise ValueError(f"num_classes must be 1..{limits.MAX_CLASSES}, got {shown(text)}")
    num_classes = int(text)
    return LogMetadata(
        num_classes=num_classes,
        confusion_matrix=_confusion_matrix(record["confusion_matrix"], num_classes),
        class_names=_class_names(record["class_names"], num_classes),
        source=record["source"],
        format_version=record["format_version"],
    )
