"""The README's shell blocks keep working: each is marked in the Markdown source, just before
its fence, with how it is checked:

- `<!-- check: run -->`: run as written, in a fresh folder, the blocks one after another;
- `<!-- check: small -->`: the same, but `mmslam simulate indoor-tags` cut to 150 m
  (configs/scenarios/small-indoor-tags.toml), so that the README's session takes seconds;
- `<!-- check: parse -->`: not run (long runs, a viewer, paths on the reader's machine): each
  `mmslam` line parsed by mmslam's own command line, every other program found, every `make`
  target in the Makefile.

An unmarked block fails. The marks and the parsing are checked fast; running the blocks is
marked slow.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from pipeline.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
SMALL_INDOOR = ROOT / "configs" / "scenarios" / "small-indoor-tags.toml"
MARK = re.compile(r"<!--\s*check:\s*(\w+)\s*-->")
CHECKS = ("run", "small", "parse")
BIN = Path(sys.executable).parent


@dataclass(frozen=True)
class Block:
    check: str | None  # None: unmarked
    line: int  # where the block starts in the README (1-based)
    text: str

    def commands(self) -> list[str]:
        """The block's command lines as the shell reads them: continuations joined, blank and
        comment lines left out."""
        joined = re.sub(r"\\\n\s*", " ", self.text)
        return [line for line in joined.splitlines() if line.strip() and line.strip()[0] != "#"]


def shell_blocks(text: str) -> list[Block]:
    """Every ```sh block of `text`, with the mark on the last non-blank line before it."""
    lines = text.splitlines()
    blocks, k = [], 0
    while k < len(lines):
        if lines[k].strip() == "```sh":
            before = next((lines[j] for j in range(k - 1, -1, -1) if lines[j].strip()), "")
            mark = MARK.fullmatch(before.strip())
            end = lines.index("```", k + 1)
            body = "\n".join(lines[k + 1 : end])
            blocks.append(Block(mark.group(1) if mark else None, k + 1, body))
            k = end
        k += 1
    return blocks


BLOCKS = shell_blocks(README.read_text())


def small(command: str) -> str:
    """`mmslam simulate indoor-tags ...` on the short route."""
    if re.match(r"^mmslam simulate indoor-tags\b", command):
        return f"{command} --config {shlex.quote(str(SMALL_INDOOR))}"
    return command


def makefile_targets() -> set[str]:
    return set(re.findall(r"^([A-Za-z][\w-]*):", (ROOT / "Makefile").read_text(), re.M))


def parse_problems(command: str) -> list[str]:
    """What is wrong with one command line, checked without running it."""
    words = shlex.split(command, comments=True)
    while words and re.fullmatch(r"\w+=\S*", words[0]):  # VAR=value before the program
        words = words[1:]
    if not words:
        return []
    program, args = words[0], words[1:]
    if program == "mmslam":
        try:
            build_parser().parse_args(args)
        except SystemExit as exit_:
            return [f"`{command}`: mmslam refuses it (exit {exit_.code})"]
        return []
    if program == "make":
        missing = [a for a in args if "=" not in a and a not in makefile_targets()]
        return [f"`{command}`: no make target {t}" for t in missing]
    if shutil.which(program, path=f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}") is None:
        return [f"`{command}`: no program {program}"]
    return []


def test_every_shell_block_says_how_it_is_checked():
    assert BLOCKS, "the README has no shell block"
    unmarked = [b.line for b in BLOCKS if b.check not in CHECKS]
    assert unmarked == [], f"README blocks at lines {unmarked} need <!-- check: run|small|parse -->"


@pytest.mark.parametrize("block", BLOCKS, ids=lambda b: f"line{b.line}-{b.check}")
def test_every_mmslam_line_of_the_readme_parses(block):
    """The cheap check of every block, run ones included: each line as mmslam parses it."""
    commands = [small(c) if block.check == "small" else c for c in block.commands()]
    runnable = [c for c in commands if "$(" not in c and "$" not in c.split()[0]]
    if block.check == "parse":
        problems = [p for c in runnable for p in parse_problems(c)]
    else:  # run blocks: their mmslam lines (the shell runs loops and variables)
        problems = [p for c in runnable if c.startswith("mmslam ") for p in parse_problems(c)]
    assert problems == []


def test_a_wrong_command_in_a_block_is_caught():
    assert parse_problems("mmslam replay x.mcap --method nonsense --out o")
    assert parse_problems("make no-such-target")
    assert parse_problems("no-such-program --flag")
    assert parse_problems("mmslam replay x.mcap --method ml --out o") == []


@pytest.mark.slow
@pytest.mark.e2e
def test_the_readme_blocks_run(tmp_path):
    """The `run` and `small` blocks, in README order, in one fresh folder (they build on each
    other: the session's log is the evo block's input), with .venv/bin first on PATH."""
    env = {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}"}
    env["MPLBACKEND"] = "Agg"
    for block in (b for b in BLOCKS if b.check in ("run", "small")):
        commands = [small(c) if block.check == "small" else c for c in block.commands()]
        script = "set -euo pipefail\n" + "\n".join(commands) + "\n"
        done = subprocess.run(
            ["bash", "-c", script], cwd=tmp_path, env=env, capture_output=True, text=True
        )
        assert done.returncode == 0, (
            f"README block at line {block.line} failed:\n{script}\n{done.stdout}\n{done.stderr}"
        )
    # what the session promises is there
    for name in ("tags-mm-nh/metrics.json", "tags.png", "tags.rrd", "tags-all.rrd"):
        assert (tmp_path / "out" / name).exists(), name
    assert (tmp_path / "out" / "tags-evo_trajectories.png").exists()
