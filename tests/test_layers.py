"""The layers: the log format and the back-end import nothing of what is built on them (viewers,
Foxglove files, the command line, the data tools). Read from the source, every import counted:
inside functions and `TYPE_CHECKING` blocks too, where a circle would hide."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LOWER_LAYERS = ("pipeline/log", "pipeline/backend")
ABOVE = ("pipeline.viz", "pipeline.foxglove", "pipeline.cli", "data_tools")


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported_modules(path: Path) -> list[tuple[int, str]]:
    """Each module `path` imports, with its line: `from . import x` resolved against the
    module's package, `from a import b` as `a.b` too (b may be a module)."""
    package = module_name(path).split(".")
    if path.name != "__init__.py":
        package = package[:-1]
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = package[: len(package) - node.level + 1] if node.level else []
            module = ".".join([*base, *([node.module] if node.module else [])])
            found.append((node.lineno, module))
            found += [(node.lineno, f"{module}.{alias.name}") for alias in node.names]
    return found


def is_above(module: str) -> bool:
    return any(module == name or module.startswith(name + ".") for name in ABOVE)


def lower_modules() -> list[Path]:
    return sorted(p for layer in LOWER_LAYERS for p in (ROOT / layer).rglob("*.py"))


@pytest.mark.parametrize("path", lower_modules(), ids=lambda p: str(p.relative_to(ROOT)))
def test_lower_layers_import_nothing_above_them(path):
    wrong = [f"line {line}: {name}" for line, name in imported_modules(path) if is_above(name)]
    assert wrong == [], f"{path.relative_to(ROOT)} imports from a layer above it"


def test_the_check_sees_every_kind_of_import(tmp_path, monkeypatch):
    """A module under pipeline/log importing upwards in each way is caught."""
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    (tmp_path / "pipeline" / "log").mkdir(parents=True)
    source = tmp_path / "pipeline" / "log" / "x.py"
    source.write_text(
        "import pipeline.viz\n"
        "from ..foxglove import log_topics\n"
        "def f():\n"
        "    from pipeline import cli\n"
        "    import data_tools.scenarios\n"
        "from pipeline.log import codec\n"
        "from . import writer\n"
    )
    assert lower_modules() == [source]
    names = {name for _, name in imported_modules(source)}
    assert {name for name in names if is_above(name)} == {
        "pipeline.viz",
        "pipeline.foxglove",
        "pipeline.foxglove.log_topics",
        "pipeline.cli",
        "data_tools.scenarios",
    }
    assert "pipeline.log.writer" in names  # a relative import, resolved
