"""The named mutations of `make mutate` (`data_tools/mutate.py`), read from
`data_tools/mutations.toml`: module by module, each a small plausible bug (a boundary moved, a
check dropped, two values swapped, a result thrown away), the text it replaces, and the tests
that must notice it. A pattern occurs exactly once in its file. `equivalent` marks a survivor
that changes no behaviour, with the reason.

The table is data, not code: a module is a `[[module]]` with its `name`, `path` and `tests`
(pytest's arguments; "@name" stands for the list `name` of the `[tests]` table), and each
mutation a `[[module.mutation]]` with its `name`, `pattern`, `replacement` and, for a survivor
that changes nothing, `equivalent`."""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path

TABLE = Path(__file__).with_name("mutations.toml")


@dataclass(frozen=True)
class Mutation:
    module: str
    path: str
    name: str  # the bug it stands for
    pattern: str
    replacement: str
    equivalent: str | None = None


@dataclass(frozen=True)
class Module:
    tests: tuple[str, ...]  # pytest's arguments
    mutations: tuple[Mutation, ...]


def _expanded(arguments: list[str], sets: dict[str, list[str]], seen: tuple[str, ...] = ()):
    """pytest's arguments with each "@name" replaced by the list `name` of `sets`."""
    out: list[str] = []
    for argument in arguments:
        if not argument.startswith("@"):
            out.append(argument)
            continue
        name = argument[1:]
        if name not in sets:
            raise ValueError(f"{TABLE.name}: no test list {name!r} in [tests]")
        if name in seen:
            raise ValueError(f"{TABLE.name}: the test list {name!r} contains itself")
        out += _expanded(sets[name], sets, (*seen, name))
    return out


def _module(entry: dict, sets: dict[str, list[str]]) -> tuple[str, Module]:
    name, path = entry["name"], entry["path"]
    mutations = tuple(
        Mutation(
            name,
            path,
            m["name"],
            m["pattern"],
            m["replacement"],
            m.get("equivalent"),
        )
        for m in entry.get("mutation", [])
    )
    return name, Module(tuple(_expanded(entry["tests"], sets)), mutations)


def load(path: Path = TABLE) -> dict[str, Module]:
    """The modules of the table at `path`, by name, in its order."""
    table = tomllib.loads(path.read_text())
    sets = table.get("tests", {})
    modules = dict(_module(entry, sets) for entry in table["module"])
    if len(modules) != len(table["module"]):
        raise ValueError(f"{path.name}: a module named twice")
    return modules


MODULES: dict[str, Module] = load()
