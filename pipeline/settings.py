"""TOML files into typed frozen dataclasses: the one loader every configuration uses.

A config section is declared once, as a frozen dataclass whose fields carry their type and
valid range (both ends) in the annotation; msgspec decodes a TOML table into it and checks it:

    relinearize_skip: Annotated[int, within(1, 10**6)]
    selection: Literal["between-updates", "custom-factor"]

and the file says the same (`configs/default.toml`):

    relinearize_skip = 1  # valid: in [1, 1e6]
    selection = "between-updates"  # valid: one of between-updates, custom-factor

Defaults live in `configs/` (or `<prefix>/share/mmslam/configs/` for a non-editable install);
a user's file needs only the keys it changes. Unknown keys, missing keys, wrong types and
values outside a key's range are one-line `InputError`s naming the file, the key and the
range. The `# valid: ...` comment on a key's line in `configs/` says the range the declaration
holds (tests/test_settings.py holds them equal). Checks between keys stay with the owner.

Why msgspec rather than pydantic v2: both validate nested typed trees and name the failing
path. msgspec decodes plain dataclasses with `Annotated[..., Meta(...)]` constraints (the
configs stay frozen dataclasses, so `dataclasses.replace` and their `repr`, which the sweeps'
fingerprints hash, do not change), it is a single small C extension with no dependencies, and
it is several times faster than pydantic at decoding JSON into typed objects, which the log
reader does for every message of a log (`python -m data_tools.bench`). Its errors say
"Expected `int` <= 1000 - at `$.isam2.relinearize_skip`"; this module turns them into the
house's one line, with the declared range and the value read.
"""

from __future__ import annotations

import copy
import math
import os
import re
import stat
import sys
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, TypeVar

import msgspec
import msgspec.inspect as mi
from msgspec import Meta

from pipeline.errors import InputError

CONFIG_DIR = Path(__file__).resolve().parents[1] / "configs"
INSTALLED_CONFIG_DIR = Path(sys.prefix) / "share" / "mmslam" / "configs"

T = TypeVar("T")
# The widest integer a setting may hold: a C `int` (what GTSAM and OpenCV take).
INT_MAX = 2**31 - 1


def within(low: float, high: float, *, low_open: bool = False, high_open: bool = False) -> Meta:
    """A number's range, both ends given: `[low, high]`, either end open if asked."""
    return Meta(
        gt=low if low_open else None,
        ge=None if low_open else low,
        lt=high if high_open else None,
        le=None if high_open else high,
    )


def positive(high: float) -> Meta:
    """`(0, high]`: a scale, a sigma, a length."""
    return within(0.0, high, low_open=True)


PROBABILITY = within(0.0, 1.0, low_open=True, high_open=True)  # (0, 1)
FRACTION = within(0.0, 1.0, low_open=True)  # (0, 1]
UNIT = within(0.0, 1.0)  # [0, 1]


def number_text(value: float) -> str:
    """1000, 0.5, 1e6, 1e-6, 4294967295: as a person writes a bound, to the last digit."""
    text = f"{value:g}"
    if float(text) != value:
        text = repr(value)
    return text.replace("e+0", "e").replace("e+", "e").replace("e-0", "e-")


def bare(info: mi.Type) -> mi.Type:
    """The type itself, without the description or schema extras msgspec wraps it in."""
    while isinstance(info, mi.Metadata):
        info = info.type
    return info


def describe(info: mi.Type) -> str | None:
    """The range a declared type allows, as the configs' `# valid:` comments say it (None: a
    type without one, such as a bool or a free-form string)."""
    info = bare(info)
    if isinstance(info, mi.LiteralType):
        return "one of " + ", ".join(str(v) for v in info.values)
    if isinstance(info, mi.VarTupleType | mi.ListType):
        return describe(info.item_type)
    if isinstance(info, mi.TupleType):
        ranges = {describe(item) for item in info.item_types}
        return ranges.pop() if len(ranges) == 1 else None
    if not isinstance(info, mi.IntType | mi.FloatType):
        return None
    low = info.gt if info.gt is not None else info.ge
    high = info.lt if info.lt is not None else info.le
    if low is not None and high is not None:
        opening = "(" if info.gt is not None else "["
        closing = ")" if info.lt is not None else "]"
        return f"in {opening}{number_text(low)}, {number_text(high)}{closing}"
    if low is not None:
        return f"{'>' if info.gt is not None else '>='} {number_text(low)}"
    if high is not None:
        return f"{'<' if info.lt is not None else '<='} {number_text(high)}"
    return None


def holds(info: mi.Type, value: Any) -> bool:
    """Whether `value` (a number) is within the range of the declared type `info`."""
    info = bare(info)
    if isinstance(info, mi.LiteralType):
        return value in info.values
    if not isinstance(info, mi.IntType | mi.FloatType):
        return True
    if isinstance(value, float) and not math.isfinite(value):
        return False
    return not (
        (info.gt is not None and value <= info.gt)
        or (info.ge is not None and value < info.ge)
        or (info.lt is not None and value >= info.lt)
        or (info.le is not None and value > info.le)
    )


def number_type(kind: type, meta: Meta) -> mi.Type:
    """The inspected type of `Annotated[kind, meta]`: a range to check a value against by hand
    (`check_range`) where a file's keys are not a dataclass of their own."""
    return mi.type_info(Annotated[kind, meta])


def check_range(value: Any, info: mi.Type, path: Path | str, key: str) -> None:
    """Raise `InputError` naming the file and the key unless `value` is within `info`."""
    if not holds(info, value):
        raise InputError(f"config {path}: '{key}' must be {describe(info)}, got {value!r}")


def fields_of(cls: type) -> dict[str, mi.Type]:
    """The declared fields of config dataclass `cls`: name -> inspected type."""
    info = mi.type_info(cls)
    return {f.name: f.type for f in info.fields}


def leaves(cls: type, prefix: str = "") -> dict[str, mi.Type]:
    """Every setting of a config dataclass, nested sections (and arrays of tables) flattened:
    dotted key -> type."""
    found = {}
    for name, info in fields_of(cls).items():
        if isinstance(info, mi.VarTupleType) and isinstance(info.item_type, mi.DataclassType):
            info = info.item_type  # [[vehicles]]: each table's keys as `vehicles.name`
        if isinstance(info, mi.DataclassType):
            found.update(leaves(info.cls, f"{prefix}{name}."))
        else:
            found[prefix + name] = info
    return found


def config_path(relative: str) -> Path:
    """A file of `configs/` (`default.toml`, `scenarios/kitti05-cars.toml`): the source tree's,
    else an installed copy."""
    path = CONFIG_DIR / relative
    return path if path.exists() else INSTALLED_CONFIG_DIR / relative


# A config file at most: the largest of configs/ is under 20 KB. Checked before it is read whole,
# so that `--config /dev/zero` or a 2 GB file is refused at once.
MAX_CONFIG_BYTES = 2**20
# Arrays and tables nested in one another at most (configs/ nest three deep): tomllib recurses
# once a level, and so do the merge and the checks, so a file of 500 `[` is refused before them.
MAX_NESTING = 32
# A key's length at most: an error line names the key.
MAX_KEY_CHARS = 100
SHOWN_CHARS = 40  # of a bad value in an error line: a 10 MB string must not make a 10 MB line

# What can open or close a level of nesting in TOML text, and what hides brackets: strings
# (multi-line ones first) and comments.
_TOML_TOKEN = re.compile(
    r'"""(?:[^\\]|\\.)*?"""|\'\'\'.*?\'\'\'|"(?:[^"\\\n]|\\.)*"|\'[^\'\n]*\'|#[^\n]*|[\[\]{}]',
    re.DOTALL,
)


def shown(value: Any) -> str:
    """A bad value, as an error line shows it: its repr, cut short."""
    text = repr(value)
    return text if len(text) <= SHOWN_CHARS else text[: SHOWN_CHARS - 3] + "..."


def _read_bounded(path: Path, what: str) -> bytes:
    """The bytes of `path`, refused unread past `MAX_CONFIG_BYTES` (a pipe or a device is read
    no further than that)."""
    limit = f"{what} {path}: larger than {MAX_CONFIG_BYTES // 2**20} MiB; not a config file"
    try:
        with open(path, "rb") as f:
            status = os.fstat(f.fileno())
            if stat.S_ISREG(status.st_mode) and status.st_size > MAX_CONFIG_BYTES:
                raise InputError(limit)
            data = f.read(MAX_CONFIG_BYTES + 1)
    except FileNotFoundError:
        raise InputError(f"{what} {path}: no such file") from None
    except IsADirectoryError:
        raise InputError(f"{what} {path}: is a directory") from None
    except OSError as exc:
        raise InputError(f"{what} {path}: cannot be read ({exc.strerror})") from None
    if len(data) > MAX_CONFIG_BYTES:
        raise InputError(limit)
    return data


def nesting(text: str) -> int:
    """How deep arrays and inline tables nest in TOML `text` (a table header counts as one
    level, an array of tables as two), without parsing it: brackets in strings and comments do
    not count."""
    depth = deepest = 0
    for token in _TOML_TOKEN.finditer(text):
        bracket = token.group()
        if bracket in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif bracket in "]}":
            depth = max(depth - 1, 0)
    return deepest


def _check_tree(table: dict[str, Any], path: Path, what: str) -> None:
    """Refuse what dotted keys (`a.b.c...`) nest deeper than `MAX_NESTING`, and keys too long
    to name in an error line; without recursion, as the tree may be deep."""
    stack: list[tuple[Any, int]] = [(table, 1)]
    while stack:
        value, depth = stack.pop()
        if depth > MAX_NESTING:
            raise InputError(f"{what} {path}: tables nested deeper than {MAX_NESTING} levels")
        if isinstance(value, dict):
            for key, item in value.items():
                if len(key) > MAX_KEY_CHARS:
                    raise InputError(
                        f"{what} {path}: a key of {len(key)} characters ({shown(key)}); "
                        f"keys are at most {MAX_KEY_CHARS}"
                    )
                stack.append((item, depth + 1))
        elif isinstance(value, list):
            stack.extend((item, depth + 1) for item in value)


def read_toml(path: Path, what: str = "config") -> dict[str, Any]:
    """A TOML file's tables; any problem an `InputError` naming the file as `what` it is. The
    file's size, its nesting and its keys' length are bounded (`MAX_CONFIG_BYTES`,
    `MAX_NESTING`, `MAX_KEY_CHARS`) before anything recurses into it."""
    data = _read_bounded(Path(path), what)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise InputError(f"{what} {path}: not UTF-8 text") from None
    if nesting(text) > MAX_NESTING:
        raise InputError(f"{what} {path}: arrays or tables nested deeper than {MAX_NESTING} levels")
    try:
        table = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{what} {path}: not valid TOML ({exc})") from None
    _check_tree(table, path, what)
    return table


def require(condition: bool, path: Path | str, message: str) -> None:
    """A config check: raise `InputError` naming the file unless `condition` holds."""
    if not condition:
        raise InputError(f"config {path}: {message}")


def _refuse_unknown(table: dict[str, Any], info: mi.Type, path: Path, prefix: str) -> None:
    """msgspec passes over keys a dataclass does not have: refuse them here, by their path."""
    if isinstance(info, mi.DataclassType):
        names = {f.name: f.type for f in info.fields}
        for key, value in table.items():
            if key not in names:
                raise InputError(f"config {path}: unknown key '{prefix}{key}'")
            if isinstance(value, dict):
                _refuse_unknown(value, names[key], path, f"{prefix}{key}.")
            elif isinstance(value, list):
                item = names[key]
                if isinstance(item, mi.VarTupleType | mi.ListType):
                    for i, entry in enumerate(value):
                        if isinstance(entry, dict):
                            _refuse_unknown(entry, item.item_type, path, f"{prefix}{key}[{i}].")


def merge(base: dict[str, Any], override: dict[str, Any], cls: type, path: Path) -> None:
    """Put the keys of `override` over `base` (in place), refusing keys `cls` does not have."""
    _refuse_unknown(override, mi.type_info(cls), path, "")
    _merge(base, override, mi.type_info(cls), path, "")


def _merge(
    base: dict[str, Any], override: dict[str, Any], info: mi.Type, path: Path, prefix: str
) -> None:
    names = {f.name: f.type for f in info.fields}
    for key, value in override.items():
        kind = names[key]
        if isinstance(kind, mi.DataclassType) and isinstance(base.get(key), dict):
            if not isinstance(value, dict):
                raise InputError(f"config {path}: '{prefix}{key}' must be a table")
            _merge(base[key], value, kind, path, f"{prefix}{key}.")
        else:
            base[key] = value  # arrays and free-form tables (`dict` fields) are replaced whole


_AT = re.compile(r"^(?P<what>.*) - at `\$(?P<where>[^`]*)`$")
_STEP = re.compile(r"\.([A-Za-z0-9_-]+)|\[(\d+)\]")


def _steps(where: str) -> list[str | int]:
    return [name if name else int(index) for name, index in _STEP.findall(where)]


def _dotted(steps: list[str | int]) -> str:
    text = ""
    for step in steps:
        text += f"[{step}]" if isinstance(step, int) else (f".{step}" if text else step)
    return text


def _walk(info: mi.Type, table: Any, steps: list[str | int]) -> tuple[mi.Type | None, Any]:
    """The declared type and the value read at `steps` (None where the path leaves them)."""
    value: Any = table
    for step in steps:
        info = bare(info)
        if isinstance(info, mi.UnionType):  # an optional field: its type, not None
            info = next(t for t in info.types if not isinstance(t, mi.NoneType))
        if isinstance(info, mi.DataclassType) and isinstance(step, str):
            info = next((f.type for f in info.fields if f.name == step), None)
        elif isinstance(info, mi.VarTupleType | mi.ListType):
            info = info.item_type
        elif isinstance(info, mi.TupleType) and isinstance(step, int):
            info = info.item_types[step] if step < len(info.item_types) else None
        else:
            info = None
        try:
            value = value[step]
        except (KeyError, IndexError, TypeError):
            value = None
        if info is None:
            break
    if info is not None:
        info = bare(info)
        if isinstance(info, mi.UnionType):
            info = next(t for t in info.types if not isinstance(t, mi.NoneType))
    return info, value


_TYPE_WORDS = {
    mi.IntType: "int",
    mi.FloatType: "float",
    mi.BoolType: "bool",
    mi.StrType: "str",
    mi.DictType: "a table",
    mi.DataclassType: "a table",
}


def explain(
    error: msgspec.ValidationError,
    cls: type,
    table: dict[str, Any],
    noun: str = "key",
    show: Callable[[Any], str] = shown,
) -> str:
    """One line for msgspec's error: the dotted path of the key (or a message's field), its
    declared range or type, and the value read (as `show` shows it)."""
    text = str(error)
    match = _AT.match(text)
    what, steps = (match["what"], _steps(match["where"])) if match else (text, [])
    if what.startswith("Object missing required field"):
        name = what.split("`")[1]
        return f"missing {noun} '{_dotted([*steps, name])}'"
    key = _dotted(steps)
    info, value = _walk(mi.type_info(cls), table, steps)
    if isinstance(info, mi.TupleType) and isinstance(value, list):
        return f"'{key}' must hold {len(info.item_types)} values, got {len(value)}"
    if isinstance(info, mi.LiteralType):
        return f"'{key}' must be {describe(info)}, got {show(value)}"
    number = isinstance(value, int | float) and not isinstance(value, bool)
    right_type = isinstance(info, mi.FloatType) or isinstance(value, int)
    if isinstance(info, mi.FloatType | mi.IntType) and number and right_type:
        valid = describe(info)
        if isinstance(value, float) and not math.isfinite(value):
            if valid is None:
                return f"'{key}' holds a non-finite number ({value})"
            return f"'{key}' must be finite, {valid}, got {show(value)}"
        if valid is not None:
            return f"'{key}' must be {valid}, got {show(value)}"
        return f"'{key}': {what[:1].lower()}{what[1:]}, got {show(value)}"
    if isinstance(info, mi.VarTupleType | mi.ListType | mi.TupleType):
        return f"'{key}' must be an array, got {show(value)}"
    word = _TYPE_WORDS.get(type(info))
    if word is not None:
        return f"'{key}' must be {word}, got {show(value)}"
    return f"'{key}': {what}"


def build(cls: type[T], table: dict[str, Any], path: Path | str, prefix: str = "") -> T:
    """A config dataclass from a TOML table, checked key by key."""
    _refuse_unknown(table, mi.type_info(cls), Path(path), prefix)
    try:
        return msgspec.convert(table, cls, strict=True)
    except msgspec.ValidationError as error:
        line = explain(error, cls, table)
        if prefix and line.startswith(("'", "missing key '")):
            line = line.replace("'", f"'{prefix}", 1)
        raise InputError(f"config {path}: {line}") from None


def load(cls: type[T], default: Path, override: str | Path | None = None) -> T:
    """`default` as `cls`, with the keys of `override` (if given) put over them."""
    table = read_toml(default)
    source = default
    if override is not None:
        source = Path(override)
        merge(table, copy.deepcopy(read_toml(source)), cls, source)
    return build(cls, table, source)


def load_checked(
    cls: type[T],
    default: Path,
    override: str | Path | None,
    check: Callable[[T, Path | str], None],
) -> T:
    """As `load`, then `check(config, path)` for what the keys' own ranges cannot say; a
    refusal names `override` if given, else `default`."""
    config = load(cls, default, override)
    check(config, override if override is not None else default)
    return config
