"""All-or-nothing outputs: a replay or a log writer stopped between any two steps of its write
(SIGKILL, or Ctrl-C) leaves the old complete set or the new complete set, and the next run
removes what the stopped one left."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from pipeline import outputs, provenance
from pipeline.cli import main
from pipeline.errors import InputError
from tests.synthetic import small_square_log

ROOT = Path(__file__).resolve().parents[1]
# Runs `mmslam` and SIGKILLs itself when the write reaches step N (counting from 1).
KILLED_AT_STEP = """
import os, signal, sys
from pipeline import outputs, provenance
from pipeline.cli import main
target, steps = int(sys.argv[1]), []
def stop(name):
    steps.append(name)
    if len(steps) == target:
        os.kill(os.getpid(), signal.SIGKILL)
outputs.step_hook = stop
sys.exit(main(sys.argv[2:]))
"""


@pytest.fixture(scope="module")
def small_log(tmp_path_factory) -> Path:
    return small_square_log(tmp_path_factory.mktemp("log") / "small.mcap")


def output_set(folder: Path) -> dict[str, object]:
    """A folder's files by name; metrics.json without its run time and run.json without its
    times and command line (the output folder's name), which differ run to run."""
    files: dict[str, object] = {}
    for path in sorted(folder.iterdir()):
        files[path.name] = path.read_bytes()
        if path.name == outputs.METRICS:
            metrics = json.loads(path.read_bytes())
            metrics.pop("runtime_s")
            files[path.name] = metrics
        elif path.name == provenance.RUN_RECORD:
            record = json.loads(path.read_bytes())
            for key in ("started_utc", "wall_s", "command"):
                record.pop(key)
            files[path.name] = record
    return files


def leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.endswith((".part", ".staging")))


def replay_args(log: Path, method: str, out: Path) -> list[str]:
    return ["replay", str(log), "--method", method, "--out", str(out), "--quiet"]


def recorded_steps(args: list[str]) -> list[str]:
    steps: list[str] = []
    outputs.step_hook = steps.append
    try:
        assert main(args) == 0
    finally:
        outputs.step_hook = None
    return steps


@pytest.mark.slow
@pytest.mark.e2e
def test_a_replay_killed_between_any_two_steps_of_its_write_leaves_one_whole_set(
    tmp_path, small_log
):
    out, place = tmp_path / "runs" / "out", tmp_path / "runs"
    assert main(replay_args(small_log, "ml", out)) == 0
    (out / "notes.txt").write_text("the user's own file")  # kept through every swap
    old = output_set(out)
    new_args = replay_args(small_log, "mm-nh", tmp_path / "expected")
    steps = recorded_steps(new_args)
    new = {**output_set(tmp_path / "expected"), "notes.txt": old["notes.txt"]}
    assert old != new and len(steps) == 8  # five files, staged, swapped, the old set removed
    outcomes = []
    for step in range(1, len(steps) + 1):
        assert main(replay_args(small_log, "ml", out)) == 0  # the old set again
        killed = subprocess.run(
            [
                sys.executable,
                "-c",
                KILLED_AT_STEP,
                str(step),
                *replay_args(small_log, "mm-nh", out),
            ],
            cwd=ROOT,
            capture_output=True,
        )
        assert killed.returncode == -signal.SIGKILL
        found = output_set(out)
        assert found in (old, new), f"killed after {steps[step - 1]!r}: a mix of old and new"
        outcomes.append(("old" if found == old else "new", len(leftovers(place))))
        assert main(replay_args(small_log, "mm-nh", out)) == 0  # the next run cleans up
        assert output_set(out) == new and leftovers(place) == []
    # Killed before the swap: the old set and its staging folder; after: the new set.
    assert [o for o, _ in outcomes] == ["old"] * 6 + ["new"] * 2
    assert [n for _, n in outcomes] == [1] * 7 + [0]
    print(f"\nkill test: {len(outcomes)} kill points, {outcomes}")


@pytest.mark.e2e
@pytest.mark.parametrize("step", range(1, 9))
def test_ctrl_c_at_any_step_leaves_one_whole_set_and_nothing_else(tmp_path, small_log, step):
    out = tmp_path / "out"
    assert main(replay_args(small_log, "ml", out)) == 0
    old = output_set(out)
    assert main(replay_args(small_log, "mm-nh", tmp_path / "expected")) == 0
    new = output_set(tmp_path / "expected")
    steps: list[str] = []

    def interrupt(name: str) -> None:
        steps.append(name)
        if len(steps) == step:
            raise KeyboardInterrupt

    outputs.step_hook = interrupt
    try:
        assert main(replay_args(small_log, "mm-nh", out)) == 130
    finally:
        outputs.step_hook = None
    assert output_set(out) == (old if step <= 6 else new), f"stopped after {steps[-1]!r}"
    assert leftovers(tmp_path) == []


@pytest.mark.parametrize("step", [1, 2])
def test_simulate_killed_while_writing_its_log_leaves_the_old_log(tmp_path, step):
    log = tmp_path / "tags.mcap"
    config = ROOT / "configs" / "scenarios" / "small-indoor-tags.toml"
    args = ["simulate", "indoor-tags", "--out", str(log), "--config", str(config)]
    assert main([*args, "--seed", "1"]) == 0
    old = log.read_bytes()
    killed = subprocess.run(
        [sys.executable, "-c", KILLED_AT_STEP, str(step), *args, "--seed", "2"],
        cwd=ROOT,
        capture_output=True,
    )
    assert killed.returncode == -signal.SIGKILL
    if step == 1:  # written, not renamed: the old log, and the new one's temporary beside it
        assert log.read_bytes() == old and len(leftovers(tmp_path)) == 1
    else:
        assert log.read_bytes() != old and leftovers(tmp_path) == []
    assert main([*args, "--seed", "3"]) == 0
    assert leftovers(tmp_path) == []


def test_a_leftover_of_a_live_writer_is_not_touched(tmp_path):
    target = tmp_path / "a.txt"
    live = outputs.AtomicFile(target, "w")
    live.file.write("mine")
    outputs.write_text(target, "first")  # another writer of the same target cleans up
    assert live.temporary.exists()  # but not what a live writer holds
    live.commit()
    assert target.read_text() == "mine" and leftovers(tmp_path) == []


def test_output_folders_that_cannot_be_replaced_whole_are_refused(tmp_path, monkeypatch):
    (tmp_path / "out" / "sub").mkdir(parents=True)
    with pytest.raises(InputError, match="holds the folder 'sub'"):
        outputs.OutputFolder(tmp_path / "out")
    monkeypatch.chdir(tmp_path / "out" / "sub")
    with pytest.raises(InputError, match="holds the current directory"):
        outputs.OutputFolder(tmp_path / "out" / "sub")
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="not a directory"):
        outputs.OutputFolder(tmp_path / "file")
    with pytest.raises(InputError, match="cannot write there"):
        outputs.OutputFolder(tmp_path / "file" / "out")


@pytest.mark.e2e
def test_a_full_disk_ends_in_one_line_and_keeps_the_old_set(tmp_path, small_log):
    """A file-size limit (EFBIG) stands in for a full disk: exit 1, the old outputs kept."""
    out = tmp_path / "out"
    assert main(replay_args(small_log, "ml", out)) == 0
    old = output_set(out)
    exe = Path(sys.executable).with_name("mmslam")
    limited = subprocess.run(
        [
            "sh",
            "-c",
            'ulimit -f 1 && exec "$@"',
            "sh",
            str(exe),
            *replay_args(small_log, "mm-nh", out),
        ],
        capture_output=True,
        text=True,
    )
    assert limited.returncode == 1, limited.stderr
    assert limited.stderr.count("\n") == 1 and "File too large" in limited.stderr
    assert output_set(out) == old and leftovers(tmp_path) == []
    assert os.path.basename(str(out)) in limited.stderr
