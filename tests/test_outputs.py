"""All-or-nothing outputs: a replay, a comparison, a sweep's report or a log writer stopped
between any two steps of its write (SIGKILL, SIGTERM, Ctrl-C) leaves the old complete set or
the new complete set, and the next run removes what the stopped one left; a read-only output
folder is not written."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from data_tools.sweep.reporting import REPORT
from pipeline import outputs, provenance
from pipeline.cli import main
from pipeline.errors import InputError
from pipeline.outputs import FileSet
from tests.synthetic import small_square_log
from tests.test_sweep import TINY, write

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


# ---------------------------------------------------------------------- mmslam compare


def compare_args(log: Path, methods: str, out: Path, *more: str) -> list[str]:
    return ["compare", str(log), "--methods", methods, "--out", str(out), "--quiet", *more]


def comparison(folder: Path) -> dict[str, object]:
    """A comparison folder: each method's output set, and files of the user's own."""
    if not folder.exists():
        return {}
    return {
        p.name: output_set(p) if p.is_dir() else p.read_bytes() for p in sorted(folder.iterdir())
    }


def temporaries(folder: Path) -> list[str]:
    return sorted(
        str(p.relative_to(folder))
        for p in folder.rglob(".*")
        if p.name.endswith((".part", ".staging", ".commit"))
    )


@pytest.mark.slow
@pytest.mark.e2e
def test_a_compare_killed_between_any_two_steps_leaves_the_old_or_the_new_comparison(
    tmp_path, small_log
):
    """Issue 53: a killed compare left new method folders beside old ones. Now the runs are
    staged beside DIR, and DIR is swapped whole once every run has finished."""
    place = tmp_path / "runs"
    out = place / "cmp"
    assert main(compare_args(small_log, "known,ml", out)) == 0
    (out / "notes.txt").write_text("the user's own file")  # kept, as other methods' folders
    saved = tmp_path / "saved"
    shutil.copytree(out, saved)
    old = comparison(out)
    steps = recorded_steps(compare_args(small_log, "ml,mm-nh", tmp_path / "expected"))
    assert len(steps) == 19  # two runs' 8 steps (into the staging folder), and the swap's 3
    new = {**old, **comparison(tmp_path / "expected")}
    assert set(new) == {"known", "ml", "mm-nh", "notes.txt"} and new != old
    # Each kind of step (replay's own are each killed in the test above): a run's first file
    # and its swap into the staging folder, both runs done, then the comparison's swap.
    kills = [1, 7, 8, 9, 16, 17, 18, 19]
    outcomes = []
    for step in kills:
        shutil.rmtree(out)
        shutil.copytree(saved, out)
        killed = subprocess.run(
            [sys.executable, "-c", KILLED_AT_STEP, str(step),
             *compare_args(small_log, "ml,mm-nh", out)],
            cwd=ROOT,
            capture_output=True,
        )  # fmt: skip
        assert killed.returncode == -signal.SIGKILL
        found = comparison(out)
        assert found in (old, new), f"killed after {steps[step - 1]!r}: a mix of old and new"
        outcomes.append("old" if found == old else "new")
    assert outcomes == ["old"] * 6 + ["new"] * 2, list(zip(kills, outcomes, strict=True))
    assert main(compare_args(small_log, "ml,mm-nh", out)) == 0  # the next run cleans up
    assert comparison(out) == new and temporaries(place) == []


def descendants(pid: int) -> set[int]:
    """The processes below `pid` (children, theirs, ...), from /proc."""
    from tests.test_sweep_stops import children

    found, todo = set(), [pid]
    while todo:
        for child in children(todo.pop()):
            if child not in found:
                found.add(child)
                todo.append(child)
    return found


@pytest.mark.slow
@pytest.mark.e2e
@pytest.mark.parametrize("how", [signal.SIGTERM, signal.SIGKILL], ids=["SIGTERM", "SIGKILL"])
def test_a_stopped_compare_leaves_no_process_no_temporary_and_the_old_comparison(
    tmp_path, small_log, how
):
    """Issue 53: a killed `compare --workers 2` left both workers and the resource tracker
    running under PID 1, writing method folders after their parent had died, and a
    $TMPDIR/mmslam-compare-* folder."""
    from tests.test_sweep_stops import PATIENCE_S, alive
    from tests.waiting import wait_until

    out = tmp_path / "cmp"
    assert main(compare_args(small_log, "known", out)) == 0
    old = comparison(out)
    temporary = tmp_path / "tmp"
    temporary.mkdir()
    command = compare_args(small_log, "ml,mm-nh,gpda", out, "--workers", "2", "--rrd",
                           str(tmp_path / "all.rrd"))  # fmt: skip
    stopped = subprocess.Popen(
        [sys.executable, "-m", "pipeline.cli", *command],
        cwd=ROOT,
        env={**os.environ, "TMPDIR": str(temporary)},
        stderr=subprocess.PIPE,
        text=True,
    )
    # the resource tracker and the two workers, started
    below = wait_until(
        lambda: len(found := descendants(stopped.pid)) >= 3 and found, "workers", PATIENCE_S
    )
    stopped.send_signal(how)
    _, err = stopped.communicate(timeout=PATIENCE_S)
    if how == signal.SIGTERM:
        assert stopped.returncode == 143 and err == "mmslam compare: terminated\n", err
    else:
        assert stopped.returncode == -signal.SIGKILL and err == "", err
    wait_until(lambda: not alive(below), "the workers and the resource tracker to die", PATIENCE_S)
    assert comparison(out) == old  # nothing written by workers after their parent died
    assert list(temporary.iterdir()) == []
    assert not (tmp_path / "all.rrd").exists()
    left = temporaries(tmp_path)
    assert len(left) == (0 if how == signal.SIGTERM else 2)  # the staging folder, a .part
    assert main(compare_args(small_log, "known", out, "--rrd", str(tmp_path / "all.rrd"))) == 0
    assert temporaries(tmp_path) == []


# ----------------------------------------------------------------- a sweep's report

TWO_METHODS = TINY.replace('methods = ["known", "ml", "mm-nh"]', 'methods = ["known", "ml"]')
REPORT_FILES = ("results.csv", "tables.md", "fig_noise.png", "fig_mis.png",
                "fig_trajectories.png", "run.json")  # fmt: skip


def report_set(out: Path) -> dict[str, object]:
    """The report's files, run.json without what differs run to run."""
    found: dict[str, object] = {}
    for name in REPORT_FILES:
        path = out / name
        if path.exists():
            found[name] = path.read_bytes()
            if name == provenance.RUN_RECORD:
                record = json.loads(path.read_bytes())
                found[name] = {k: record[k] for k in ("config", "inputs")}
    return found


@pytest.fixture(scope="module")
def sweep_reports(tmp_path_factory) -> tuple[Path, Path, dict, dict]:
    """A sweep folder holding the runs of three methods and the report of two (the old), and
    the report of three (the new): (the sweep file, the folder, old, new)."""
    folder = tmp_path_factory.mktemp("sweep")
    config, fewer = write(folder, TINY), write(folder, TWO_METHODS, "fewer.toml")
    out = folder / "out"
    assert main(["sweep", str(config), "--out", str(out), "--workers", "2", "--quiet"]) == 0
    new = report_set(out)
    assert main(["sweep", str(fewer), "--out", str(out), "--quiet"]) == 0
    old = report_set(out)
    assert set(old) == set(new) == set(REPORT_FILES) and old["results.csv"] != new["results.csv"]
    return config, out, old, new


def restore_report(out: Path, old: dict, saved: Path) -> None:
    """Put the old report back, and delete what a stopped writer left."""
    for leftover in map(out.joinpath, temporaries(out)):
        if leftover.is_dir():
            outputs.remove_tree(leftover)
        else:
            leftover.unlink(missing_ok=True)  # in a folder removed before it
    for name in REPORT_FILES:
        shutil.copy2(saved / name, out / name)
    assert report_set(out) == old


STOPS = [
    (signal.SIGTERM, step)
    for step in ("renamed results.csv", "wrote fig_mis.png", "staged", "marked",
                 "moved fig_noise.png", "moved tables.md", "committed")
] + [(signal.SIGINT, "renamed results.csv"), (signal.SIGINT, "moved fig_noise.png")]  # fmt: skip


@pytest.mark.e2e
@pytest.mark.parametrize(("how", "at"), STOPS, ids=[f"{h.name}-{a}" for h, a in STOPS])
def test_a_sweep_stopped_while_it_writes_its_report_leaves_one_whole_report(
    tmp_path, sweep_reports, how, at
):
    """Issue 53: SIGTERM while the report was written left no line, exit -15, figures missing
    and a .part file; SIGTERM or Ctrl-C as results.csv was replaced left 75 rows in it while
    tables.md, the figures and run.json described 50."""
    config, out, old, new = sweep_reports
    saved = tmp_path / "old"
    saved.mkdir()
    for name in REPORT_FILES:
        (saved / name).write_bytes(out.joinpath(name).read_bytes())

    def stop(name: str) -> None:
        if name == at:
            os.kill(os.getpid(), how)  # as a user or a scheduler would: a real signal

    # Ctrl-C as a terminal's user sends it: a suite started in the background by a shell
    # without job control inherits SIGINT ignored, and the sweep then rightly goes on.
    interrupts = signal.signal(signal.SIGINT, signal.default_int_handler)
    outputs.step_hook = stop
    try:
        status = main(["sweep", str(config), "--out", str(out), "--quiet"])
    finally:
        outputs.step_hook = None
        signal.signal(signal.SIGINT, interrupts)
        found = report_set(out)
        left = temporaries(out)
        restore_report(out, old, saved)
    assert status == (143 if how == signal.SIGTERM else 130)
    before_moves = at in ("renamed results.csv", "wrote fig_mis.png", "staged")
    assert found == (old if before_moves else new), f"stopped after {at!r}"
    assert left == []


@pytest.mark.slow
@pytest.mark.e2e
def test_a_sweep_killed_between_any_two_steps_of_its_report_leaves_one_whole_report(
    tmp_path, sweep_reports
):
    config, out, old, new = sweep_reports
    saved = tmp_path / "old"
    saved.mkdir()
    for name in REPORT_FILES:
        (saved / name).write_bytes(out.joinpath(name).read_bytes())
    args = ["sweep", str(config), "--out", str(out), "--quiet"]
    steps = recorded_steps(args)
    restore_report(out, old, saved)
    assert steps[-1] == "committed" and len(steps) == 23
    # Each kind of step (steps 1 and 2 write sweep.json): a file staged and the last, the
    # staged set, the mark, its first moves, results.csv's and the last, and the end.
    kills = [3, 4, 14, 15, 16, 17, 18, 20, 22, 23]
    outcomes = []
    for step in kills:
        killed = subprocess.run(
            [sys.executable, "-c", KILLED_AT_STEP, str(step), *args], cwd=ROOT, capture_output=True
        )
        assert killed.returncode == -signal.SIGKILL
        found, left = report_set(out), temporaries(out)
        if any(name.endswith(".commit") for name in left):
            # Killed once the set was marked complete, before all of it was moved: what is
            # not moved yet waits in the marked folder, and the next writer of the report (or
            # a reader's `recover`) moves it in first.
            assert len(left) == 1
            FileSet.recover(out, REPORT)
            found = report_set(out)
            outcomes.append("recovered")
        else:
            outcomes.append("old" if found == old else "new")
        assert found in (old, new), f"killed after {steps[step - 1]!r}: a mix of old and new"
        restore_report(out, old, saved)
    # Before the mark, the old report; from the mark on, the new one (moved in by the next).
    found_at = list(zip(kills, outcomes, strict=True))
    assert outcomes == ["old"] * 4 + ["recovered"] * 5 + ["new"], found_at
    print(f"\nreport kill test: {found_at}")
    assert main(args) == 0 and report_set(out) == new and temporaries(out) == []


# ------------------------------------------------------------- read-only output folders


def test_a_read_only_output_folder_is_refused_and_kept(tmp_path, small_log, capsys):
    """Issue 53: `replay --out w2/mine` with `mine` mode 555 swapped it anyway (the folder's
    permissions did not stop a rename in a writable parent) and left the old set behind as a
    `.mine.*.staging` the clean-up could not delete. Refused now, as root too."""
    mine = tmp_path / "w2" / "mine"
    assert main(replay_args(small_log, "ml", mine)) == 0
    before = output_set(mine)
    mine.chmod(0o555)
    try:
        for args in (
            replay_args(small_log, "mm-nh", mine),
            compare_args(small_log, "ml", mine),
            ["sweep", "small", "--out", str(mine), "--quiet"],
            ["simulate", "city-grid", "--out", str(mine / "log.mcap")],
        ):
            assert main(args) == 2, args
            err = capsys.readouterr().err
            assert err.count("\n") == 1 and "read-only folder (mode 555)" in err, err
            assert str(mine) in err
        assert output_set(mine) == before and os.listdir(mine.parent) == ["mine"]
    finally:
        mine.chmod(0o755)


def test_staging_copies_that_a_stopped_run_left_read_only_are_removed(tmp_path, small_log):
    """Copies of a read-only folder that an earlier version swapped out and could not delete
    (mode 555 folders of 444 files), and those a kill left: the next run removes them all."""
    out = tmp_path / "mine"
    for name in (".mine.a1b2c3d4.staging", ".mine.e5f6g7h8.staging"):
        stale = tmp_path / name
        (stale / "sub").mkdir(parents=True)
        (stale / "sub" / "metrics.json").write_text("{}")
        (stale / "sub" / "metrics.json").chmod(0o444)
        (stale / "sub").chmod(0o555)
        stale.chmod(0o555)
    assert main(replay_args(small_log, "ml", out)) == 0
    assert sorted(os.listdir(tmp_path)) == ["mine"]


def test_an_existing_folder_as_a_file_output_is_named_as_given(tmp_path, capsys):
    """Issue 53: `simulate --out` at a folder said ".ro.4xiyk9up.part: Is a directory"."""
    (tmp_path / "ro").mkdir()
    assert main(["simulate", "indoor-tags", "--out", str(tmp_path / "ro")]) == 2
    err = capsys.readouterr().err
    assert err == f"mmslam simulate: error: {tmp_path / 'ro'}: is a directory\n"
    assert os.listdir(tmp_path) == ["ro"]
