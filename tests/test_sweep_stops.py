"""Sweeps that die cleanly: SIGTERM does what Ctrl-C does, workers die with their sweep however
it dies, the next sweep cleans up and resumes, and a cached log that changed is made again."""

from __future__ import annotations

import hashlib
import logging
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from data_tools.sweep.grid import Cell, RunKey
from data_tools.sweep.work import RunTask, cached_log_is_intact, digest_path, ensure_log
from tests.test_sweep import SMALL_SCENARIO, TINY, write
from tests.waiting import wait_until

ROOT = Path(__file__).resolve().parents[1]
PATIENCE_S = 120.0  # a guard against hanging, not a measure: every wait below ends on an event


def children(pid: int) -> set[int]:
    """The processes whose parent is `pid`, from /proc."""
    found = set()
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                found.add(int(entry.name))
    return found


def alive(pids: set[int]) -> set[int]:
    """Those of `pids` still running (a zombie has finished)."""
    running = set()
    for pid in pids:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if state != "Z":
            running.add(pid)
    return running


def sweep_command(config: Path, out: Path, quiet: bool = True) -> list[str]:
    """The sweep as a user starts it; `quiet`: errors only (-q), no result lines either."""
    return [sys.executable, "-m", "pipeline.cli", "sweep", str(config), "--out", str(out),
            "--workers", "2", *(["--quiet"] if quiet else [])]  # fmt: skip


def start_sweep(folder: Path) -> tuple[subprocess.Popen, Path]:
    """A sweep of 9 runs on two workers, in its own process; once its first run has finished,
    (the process, its output folder)."""
    config = write(folder, TINY)
    out = folder / "out"
    sweep = subprocess.Popen(
        sweep_command(config, out),
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    wait_until(lambda: finished(out), "the first run", PATIENCE_S)
    return sweep, out


def finished(out: Path) -> set[Path]:
    """The runs' metrics swapped into place; not those of a staging folder (`.NAME...staging`,
    which pathlib's `*` matches too) that a killed sweep never swaps in."""
    return set(out.glob("runs/*/*/[!.]*/metrics.json"))


@pytest.mark.slow
@pytest.mark.e2e
@pytest.mark.parametrize("how", [signal.SIGTERM, signal.SIGKILL], ids=["SIGTERM", "SIGKILL"])
def test_a_stopped_sweep_takes_its_workers_with_it_and_resumes(tmp_path, how):
    sweep, out = start_sweep(tmp_path)
    workers = wait_until(lambda: alive(children(sweep.pid)), "the workers", PATIENCE_S)
    sweep.send_signal(how)
    _, err = sweep.communicate(timeout=PATIENCE_S)  # stderr closes once every worker is gone
    if how == signal.SIGTERM:  # as Ctrl-C, in one line, with the status a shell gives SIGTERM
        assert sweep.returncode == 128 + signal.SIGTERM
        assert err.strip().splitlines() == ["mmslam sweep: terminated"]
    else:
        assert sweep.returncode == -signal.SIGKILL
        assert "leaked semaphore" not in err and err == "", err  # the resource tracker's
    wait_until(lambda: not alive(workers), "the workers to die", PATIENCE_S)
    kept = finished(out)
    assert 1 <= len(kept) < 9
    # The next sweep cleans what the stopped one left, keeps its finished runs and does the rest.
    done = subprocess.run(
        sweep_command(tmp_path / "sweep.toml", out, quiet=False),  # its result line
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=PATIENCE_S,
    )
    assert done.returncode == 0, done.stderr
    assert f"({9 - len(kept)} new, {len(kept)} kept)" in done.stdout
    leftovers = [p for p in out.rglob(".*") if p.name.endswith((".part", ".staging"))]
    assert leftovers == []


def test_a_cached_log_that_changed_is_made_again(tmp_path, caplog):
    cell = Cell(1.0, 0.1)
    log_path = tmp_path / "runs" / cell.name / "seed0" / "log.mcap"
    task = RunTask(
        RunKey(cell, 0, "known"), "indoor-tags", SMALL_SCENARIO, None, 2, False, log_path,
        log_path.parent / "known",
    )  # fmt: skip
    ensure_log(task)
    original = log_path.read_bytes()
    assert cached_log_is_intact(log_path)
    assert digest_path(log_path).read_text().split() == [
        hashlib.sha256(original).hexdigest(),
        "log.mcap",
    ]
    ensure_log(task)  # intact: kept as it is
    assert log_path.read_bytes() == original
    for damage in (original[: len(original) // 2], original[:100] + b"X" + original[101:]):
        log_path.write_bytes(damage)
        assert not cached_log_is_intact(log_path)
        # at its own logger: a CLI test's --quiet earlier in the session leaves data_tools quiet
        with caplog.at_level(logging.WARNING, logger="data_tools.sweep.work"):
            ensure_log(task)
        assert "not as it was written; making it again" in caplog.text
        assert log_path.read_bytes() == original  # the same seed makes the same bytes
    digest_path(log_path).unlink()  # a log without its digest is not trusted either
    os.utime(log_path)
    assert not cached_log_is_intact(log_path)
    ensure_log(task)
    assert cached_log_is_intact(log_path)


@pytest.mark.slow
@pytest.mark.e2e
def test_a_worker_killed_as_by_the_out_of_memory_killer_ends_the_sweep_in_one_line(tmp_path):
    """Issue 53: a worker SIGKILLed (as the OOM killer does) gave a 20-line traceback."""
    sweep, out = start_sweep(tmp_path)
    workers = wait_until(lambda: alive(children(sweep.pid)), "the workers", PATIENCE_S)
    spawned = [p for p in workers if b"spawn_main" in Path(f"/proc/{p}/cmdline").read_bytes()]
    os.kill(spawned[0], signal.SIGKILL)
    _, err = sweep.communicate(timeout=PATIENCE_S)
    assert sweep.returncode == 1
    assert err.splitlines() == [
        "mmslam sweep: error: a worker process died abruptly (killed, out of memory, or a "
        "crash); the runs finished so far are kept: run the sweep again to resume"
    ]
    wait_until(
        lambda: not alive(workers), "the other worker and the resource tracker to die", PATIENCE_S
    )
    assert 1 <= len(finished(out)) < 9
