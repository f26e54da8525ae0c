"""TOML files into typed frozen dataclasses: the one loader every configuration uses.

Defaults live in `configs/` (or `<prefix>/share/mmslam/configs/` for a non-editable install);
a user's file needs only the keys it changes. Unknown keys, missing keys, wrong types and
values outside a key's valid range are `InputError`s naming the key and the file. Supported
field types: `int`, `float` (finite), `bool`, `str`, `Path` (resolved against the directory
of the file that sets it), fixed or variable tuples of those, nested dataclasses, tuples of
dataclasses (arrays of tables), and `dict` (a free-form table, such as a name mapping, that its
owner checks; a user's file replaces it whole).

A number or word field declares its valid range beside its type, and the config file says the
same in a `# valid: ...` comment on the key's line (tests/test_settings.py holds them equal):

    relinearize_skip: int = setting(at_least(1))          # relinearize_skip = 1  # valid: >= 1
    selection: str = setting(one_of("a", "b"))            # selection = "a"  # valid: one of a, b

A tuple's range holds for each of its items. Checks between keys stay with the config's owner.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import sys
import tomllib
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from pipeline.errors import InputError

CONFIG_DIR = Path(__file__).resolve().parents[1] / "configs"
INSTALLED_CONFIG_DIR = Path(sys.prefix) / "share" / "mmslam" / "configs"

T = TypeVar("T")
VALID = "valid"  # the dataclass field metadata key of a range


@dataclass(frozen=True)
class Valid:
    """A setting's valid range: numbers in an interval (ends open or closed, either may be
    missing), or one of some words; no bound at all means anything of the field's type."""

    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    choices: tuple[str, ...] = ()

    def holds(self, value: Any) -> bool:
        if self.choices:
            return value in self.choices
        if self.low is not None and (value <= self.low if self.low_open else value < self.low):
            return False
        return self.high is None or (value < self.high if self.high_open else value <= self.high)

    def describe(self) -> str:
        if self.choices:
            return "one of " + ", ".join(self.choices)
        low, high = self.low, self.high
        if low is not None and high is not None:
            opening = "(" if self.low_open else "["
            closing = ")" if self.high_open else "]"
            return f"in {opening}{low:g}, {high:g}{closing}"
        if low is not None:
            return f"{'>' if self.low_open else '>='} {low:g}"
        if high is not None:
            return f"{'<' if self.high_open else '<='} {high:g}"
        return "any"


ANY = Valid()
POSITIVE = Valid(low=0.0, low_open=True)
FRACTION = Valid(low=0.0, high=1.0, low_open=True)  # (0, 1]
PROBABILITY = Valid(low=0.0, high=1.0, low_open=True, high_open=True)  # (0, 1)


def at_least(low: float) -> Valid:
    return Valid(low=low)


def between(low: float, high: float, *, low_open: bool = False, high_open: bool = False) -> Valid:
    return Valid(low=low, high=high, low_open=low_open, high_open=high_open)


def one_of(*choices: str) -> Valid:
    return Valid(choices=choices)


def setting(valid: Valid) -> Any:
    """A dataclass field with a valid range (and no default: defaults live in `configs/`)."""
    return dataclasses.field(metadata={VALID: valid})


def valid_range(cls: type, name: str) -> Valid | None:
    """The range declared for field `name` of dataclass `cls`, if any."""
    field = next(f for f in dataclasses.fields(cls) if f.name == name)
    return field.metadata.get(VALID)


def check_range(value: Any, valid: Valid, path: Path | str, key: str) -> None:
    """Raise `InputError` naming the file and the key unless `value` is within `valid`."""
    if not valid.holds(value):
        raise InputError(f"config {path}: '{key}' must be {valid.describe()}, got {value!r}")


def config_path(relative: str) -> Path:
    """A file of `configs/` (`default.toml`, `scenarios/kitti05-cars.toml`): the source tree's,
    else an installed copy."""
    path = CONFIG_DIR / relative
    return path if path.exists() else INSTALLED_CONFIG_DIR / relative


def read_toml(path: Path) -> dict[str, Any]:
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except FileNotFoundError:
        raise InputError(f"config {path}: no such file") from None
    except IsADirectoryError:
        raise InputError(f"config {path}: is a directory") from None
    except OSError as exc:
        raise InputError(f"config {path}: cannot be read ({exc.strerror})") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"config {path}: not valid TOML ({exc})") from None
    except UnicodeDecodeError:
        raise InputError(f"config {path}: not UTF-8 text") from None


def require(condition: bool, path: Path | str, message: str) -> None:
    """A config check: raise `InputError` naming the file unless `condition` holds."""
    if not condition:
        raise InputError(f"config {path}: {message}")


def _is_dataclass_type(kind: Any) -> bool:
    return isinstance(kind, type) and dataclasses.is_dataclass(kind)


def _field_types(cls: type) -> dict[str, Any]:
    hints = typing.get_type_hints(cls)
    return {f.name: hints[f.name] for f in dataclasses.fields(cls)}


def _resolve_paths(table: dict[str, Any], cls: type, base: Path) -> None:
    """Make the `Path` fields of `table` absolute, relative to `base` (in place)."""
    for name, kind in _field_types(cls).items():
        value = table.get(name)
        if kind is Path and isinstance(value, str):
            table[name] = str((base / value).resolve())
        elif _is_dataclass_type(kind) and isinstance(value, dict):
            _resolve_paths(value, kind, base)


def merge(base: dict[str, Any], override: dict[str, Any], cls: type, path: Path, prefix="") -> None:
    """Put the keys of `override` over `base` (in place), refusing keys `cls` does not have."""
    types = _field_types(cls)
    for key, value in override.items():
        if key not in types:
            raise InputError(f"config {path}: unknown key '{prefix}{key}'")
        kind = types[key]
        if _is_dataclass_type(kind) and isinstance(base.get(key), dict):
            if not isinstance(value, dict):
                raise InputError(f"config {path}: '{prefix}{key}' must be a table")
            merge(base[key], value, kind, path, f"{prefix}{key}.")
        else:
            base[key] = value  # arrays and free-form tables (`dict` fields) are replaced whole


def _scalar(value: Any, kind: type, path: Path, key: str) -> Any:
    if kind is float:
        ok = isinstance(value, int | float) and not isinstance(value, bool)
        if ok and not math.isfinite(value):
            raise InputError(f"config {path}: '{key}' must be finite, got {value!r}")
    elif kind is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif kind is Path:
        ok = isinstance(value, str)
    else:
        ok = isinstance(value, kind)
    if not ok:
        raise InputError(f"config {path}: '{key}' must be {kind.__name__}, got {value!r}")
    return kind(value)


def _value(value: Any, kind: Any, path: Path, key: str) -> Any:
    if _is_dataclass_type(kind):
        if not isinstance(value, dict):
            raise InputError(f"config {path}: '{key}' must be a table")
        return build(kind, value, path, f"{key}.")
    if kind is dict:
        if not isinstance(value, dict):
            raise InputError(f"config {path}: '{key}' must be a table")
        return dict(value)
    if typing.get_origin(kind) is tuple:
        args = typing.get_args(kind)
        if not isinstance(value, list):
            raise InputError(f"config {path}: '{key}' must be an array")
        if len(args) == 2 and args[1] is Ellipsis:
            item_kinds = [args[0]] * len(value)
        else:
            item_kinds = list(args)
            if len(value) != len(item_kinds):
                raise InputError(
                    f"config {path}: '{key}' must hold {len(item_kinds)} values, got {len(value)}"
                )
        return tuple(
            _value(v, k, path, f"{key}[{i}]")
            for i, (v, k) in enumerate(zip(value, item_kinds, strict=True))
        )
    return _scalar(value, kind, path, key)


def build(cls: type[T], table: dict[str, Any], path: Path, prefix: str = "") -> T:
    """A config dataclass from a TOML table, checked key by key."""
    types = _field_types(cls)
    for key in table:
        if key not in types:
            raise InputError(f"config {path}: unknown key '{prefix}{key}'")
    kwargs = {}
    for name, kind in types.items():
        if name not in table:
            raise InputError(f"config {path}: missing key '{prefix}{name}'")
        value = _value(table[name], kind, path, f"{prefix}{name}")
        valid = valid_range(cls, name)
        if valid is not None:
            items = value if isinstance(value, tuple) else (value,)
            for i, item in enumerate(items):
                key = f"{prefix}{name}" + (f"[{i}]" if isinstance(value, tuple) else "")
                check_range(item, valid, path, key)
        kwargs[name] = value
    return cls(**kwargs)


def load(cls: type[T], default: Path, override: str | Path | None = None) -> T:
    """`default` as `cls`, with the keys of `override` (if given) put over them."""
    table = read_toml(default)
    _resolve_paths(table, cls, default.parent)
    source = default
    if override is not None:
        source = Path(override)
        user = copy.deepcopy(read_toml(source))
        _resolve_paths(user, cls, source.parent)
        merge(table, user, cls, source)
    return build(cls, table, source)
