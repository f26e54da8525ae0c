"""Scenario configuration: a TOML file of defaults, read into typed frozen dataclasses.

Each scenario has its defaults in `configs/scenarios/<name>.toml`. A user's file (`--config F`)
needs only the keys it changes; unknown keys, missing keys and wrong types are `InputError`s
naming the key and the file. Fields typed `Path` are resolved against the directory of the file
that set them, so a default path and a user's path both mean what they say where they are
written.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import sys
import tomllib
import types
import typing
from pathlib import Path
from typing import Any, TypeVar

from pipeline.errors import InputError

CONFIG_DIR = Path(__file__).resolve().parents[2] / "configs" / "scenarios"
INSTALLED_CONFIG_DIR = Path(sys.prefix) / "share" / "mmslam" / "configs" / "scenarios"

T = TypeVar("T")


def default_config_path(scenario: str) -> Path:
    """Where the defaults of `scenario` live (the source tree first, then an installed copy)."""
    path = CONFIG_DIR / f"{scenario}.toml"
    return path if path.exists() else INSTALLED_CONFIG_DIR / f"{scenario}.toml"


def read_toml(path: Path) -> dict[str, Any]:
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except FileNotFoundError:
        raise InputError(f"config {path}: no such file") from None
    except IsADirectoryError:
        raise InputError(f"config {path}: is a directory") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"config {path}: not valid TOML ({exc})") from None


def _is_dataclass_type(kind: Any) -> bool:
    return isinstance(kind, type) and dataclasses.is_dataclass(kind)


def _resolve_paths(table: dict[str, Any], cls: type, base: Path) -> None:
    """Make the `Path` fields of `table` absolute, relative to `base` (in place)."""
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        if f.name not in table:
            continue
        kind, value = hints[f.name], table[f.name]
        if kind is Path and isinstance(value, str):
            table[f.name] = str((base / value).resolve())
        elif _is_dataclass_type(kind) and isinstance(value, dict):
            _resolve_paths(value, kind, base)


def _merge(base: dict[str, Any], override: dict[str, Any], path: Path, prefix: str = "") -> None:
    for key, value in override.items():
        if key not in base:
            raise InputError(f"config {path}: unknown key '{prefix}{key}'")
        if isinstance(base[key], dict):
            if not isinstance(value, dict):
                raise InputError(f"config {path}: '{prefix}{key}' must be a table")
            _merge(base[key], value, path, f"{prefix}{key}.")
        else:
            base[key] = value  # arrays (of numbers or of tables) are replaced whole


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
    origin = typing.get_origin(kind)
    if origin is tuple:
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
    if origin in (typing.Union, types.UnionType):
        raise TypeError(f"config field '{key}': unions are not supported")
    return _scalar(value, kind, path, key)


def build(cls: type[T], table: dict[str, Any], path: Path, prefix: str = "") -> T:
    """A config dataclass from a TOML table, checked key by key."""
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    for key in table:
        if key not in names:
            raise InputError(f"config {path}: unknown key '{prefix}{key}'")
    kwargs = {}
    for f in dataclasses.fields(cls):  # type: ignore[arg-type]
        if f.name not in table:
            raise InputError(f"config {path}: missing key '{prefix}{f.name}'")
        kwargs[f.name] = _value(table[f.name], hints[f.name], path, f"{prefix}{f.name}")
    return cls(**kwargs)


def load(cls: type[T], scenario: str, override: Path | None = None) -> T:
    """The defaults of `scenario` as `cls`, with the keys of `override` (if given) put over them."""
    default = default_config_path(scenario)
    table = read_toml(default)
    _resolve_paths(table, cls, default.parent)
    source = default
    if override is not None:
        source = Path(override)
        user = copy.deepcopy(read_toml(source))
        _resolve_paths(user, cls, source.parent)
        _merge(table, user, source)
    return build(cls, table, source)


def require(condition: bool, path: Path | str, message: str) -> None:
    """A config check: raise `InputError` naming the file unless `condition` holds."""
    if not condition:
        raise InputError(f"config {path}: {message}")
