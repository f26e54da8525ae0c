"""docs/log-format.md's tables of fields, made from the messages' declarations
(`messages.py`): `python -m pipeline.log.doc` writes them into the page between its markers,
and tests/test_log_doc.py holds the page equal to what this makes."""

from __future__ import annotations

import argparse
import sys
import typing
from pathlib import Path

import msgspec
import msgspec.inspect as mi

from pipeline import settings
from pipeline.log import limits, schemas
from pipeline.log.messages import (
    Corners,
    Covariance,
    Detection,
    GroundTruthLandmark,
    Norm,
    OfTheLogsClasses,
    RelativePose,
    RigidTransform,
    UnitQuaternion,
)
from pipeline.settings import number_text

PAGE = Path(__file__).resolve().parents[2] / "docs" / "log-format.md"
BEGIN = "<!-- fields: made by `python -m pipeline.log.doc` from pipeline/log/messages.py -->"
END = "<!-- end of the fields -->"
NESTED = (Detection, RelativePose, GroundTruthLandmark)


def _marker_text(marker: object) -> str:
    if isinstance(marker, Norm):
        return f"length in [{number_text(marker.low)}, {number_text(marker.high)}]"
    if isinstance(marker, UnitQuaternion):
        return f"unit norm (within {number_text(limits.QUATERNION_NORM_TOLERANCE)})"
    if isinstance(marker, Covariance):
        return (
            f"symmetric, positive definite, variances in [{number_text(limits.MIN_VARIANCE)}, "
            f"{number_text(limits.MAX_VARIANCE)}], condition number <= "
            f"{number_text(limits.MAX_CONDITION)}"
        )
    if isinstance(marker, Corners):
        return "u_min <= u_max, v_min <= v_max"
    if isinstance(marker, RigidTransform):
        return "a rotation and a translation, last row [0, 0, 0, 1]"
    if isinstance(marker, OfTheLogsClasses):
        return "below the log's num_classes"
    raise TypeError(marker)


def _markers(cls: type, name: str) -> list[object]:
    kind = typing.get_type_hints(cls, include_extras=True)[name]
    found = []
    for part in (kind, *typing.get_args(kind)):  # the field's type, or the non-None of a union
        if typing.get_origin(part) is typing.Annotated:
            found += [m for m in part.__metadata__ if not isinstance(m, msgspec.Meta)]
    return found


def _field_row(cls: type, field: mi.Field) -> str:
    info = settings.bare(field.type)
    optional = not field.required
    if isinstance(info, mi.UnionType):
        info = settings.bare(next(t for t in info.types if not isinstance(t, mi.NoneType)))
    valid = settings.describe(info)
    if isinstance(info, mi.IntType | mi.FloatType):
        kind = "integer" if isinstance(info, mi.IntType) else "number"
    elif isinstance(info, mi.LiteralType):
        kind = "string"
        valid = "one of " + ", ".join(f'"{v}"' for v in info.values)
    elif isinstance(info, mi.TupleType):
        kind = f"[{len(info.item_types)} numbers]"
    elif isinstance(info, mi.VarTupleType) and isinstance(
        settings.bare(info.item_type), mi.DataclassType
    ):
        kind = f"list of {settings.bare(info.item_type).cls.__name__}"
        valid = None
    elif isinstance(info, mi.VarTupleType):
        kind = f"[{info.min_length} numbers]"
    elif isinstance(info, mi.DataclassType):
        kind = info.cls.__name__
    else:
        kind = type(info).__name__
    unit = _unit(cls, field.name)
    checks = [valid] if valid else []
    if isinstance(info, mi.TupleType | mi.VarTupleType) and valid:
        checks = [f"each {valid}"]
    checks += [_marker_text(m) for m in _markers(cls, field.name)]
    name = f"`{field.name}`" + (" (optional)" if optional else "")
    return f"| {name} | {kind} | {unit or ''} | {'; '.join(checks)} |"


def _unit(cls: type, name: str) -> str | None:
    kind = typing.get_type_hints(cls, include_extras=True)[name]
    for part in (kind, *typing.get_args(kind)):
        if typing.get_origin(part) is typing.Annotated:
            for m in part.__metadata__:
                if isinstance(m, msgspec.Meta) and m.description:
                    return m.description
            inner = typing.get_args(part)[0]
            if typing.get_origin(inner) is tuple:
                for item in typing.get_args(inner)[:1]:
                    if typing.get_origin(item) is typing.Annotated:
                        for m in item.__metadata__:
                            if isinstance(m, msgspec.Meta) and m.description:
                                return m.description
    return None


def _table(cls: type) -> list[str]:
    rows = ["| field | type | unit | valid |", "|---|---|---|---|"]
    rows += [_field_row(cls, f) for f in mi.type_info(cls).fields]
    return rows


def tables() -> str:
    """The page's part between its markers."""
    lines = [BEGIN, ""]
    for topic, (name, cls) in schemas.MESSAGES.items():
        lines += [f"`{topic}` (`{name}`):", "", *_table(cls), ""]
    for cls in NESTED:
        lines += [f"A `{cls.__name__}`:", "", *_table(cls), ""]
    lines.append(END)
    return "\n".join(lines)


def page_with_tables(text: str) -> str:
    start, end = text.index(BEGIN), text.index(END) + len(END)
    return text[:start] + tables() + text[end:]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if the page is not current")
    args = parser.parse_args(argv)
    text = PAGE.read_text()
    current = page_with_tables(text)
    if args.check:
        return 0 if current == text else 1
    PAGE.write_text(current)
    return 0


if __name__ == "__main__":
    sys.exit(main())
