"""`make mutate`: mutation testing of the modules whose bugs a user would not see, by a table of
named mutations (`data_tools/mutations.toml`): each a plausible bug, put into a copy of the
project one at a time, and the module's own tests run against it. A mutation the tests notice
(a failure, an error, a crash, a hang past the time limit) is killed; one they do not notice
survived. Each module's score is killed / all; the table marks the survivors known to change
no behaviour (`equivalent`) with the reason, and the run lists every survivor.

    python -m data_tools.mutate [--module NAME ...] [--mutation NAME ...] [--list]

`--mutation` runs only the mutations of those names (say, a run's survivors once a test was
written for them); the scores printed then count only those.

Not in CI: a run of every module takes hours on two cores (each mutation runs its
module's tests, `-x`, the slow ones left out unless the table asks for them).
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from data_tools.mutations import MODULES, Mutation

ROOT = Path(__file__).resolve().parents[1]
# A mutation whose tests run this many times longer than the unmutated tests (and at least
# MIN_TIMEOUT_S) is taken to hang: killed.
TIMEOUT_FACTOR = 4.0
MIN_TIMEOUT_S = 60.0
EXIT_NO_TESTS = 5  # pytest's status when nothing was collected


@dataclass
class Outcome:
    mutation: Mutation
    killed: bool
    how: str  # "failed", "timeout", "survived"
    seconds: float


def copy_project(target: Path) -> None:
    """The files git knows (committed or not) and the untracked ones it does not ignore."""
    listed = subprocess.run(
        ["git", "ls-files", "--cached", "--others", "--exclude-standard", "-z"],
        cwd=ROOT,
        check=True,
        capture_output=True,
    ).stdout.split(b"\0")
    for name in filter(None, listed):
        source = ROOT / os.fsdecode(name)
        if not source.is_file():  # deleted in the work tree
            continue
        destination = target / os.fsdecode(name)
        destination.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(source, destination)


def run_tests(
    copy: Path, tests: tuple[str, ...], timeout_s: float | None
) -> tuple[int, float, str]:
    """pytest over `tests` in `copy` (its `pipeline` imported, not the installed one): its exit
    status (-1 past the time limit), the seconds taken and the end of what it printed."""
    env = dict(os.environ, PYTHONPATH=str(copy), PYTHONDONTWRITEBYTECODE="1")
    command = [sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", *tests]
    start = time.monotonic()
    try:
        done = subprocess.run(
            command, cwd=copy, env=env, capture_output=True, timeout=timeout_s, check=False
        )
    except subprocess.TimeoutExpired:
        return -1, time.monotonic() - start, ""
    if done.returncode == EXIT_NO_TESTS:
        raise SystemExit(f"mutate: no tests collected by {' '.join(tests)}")
    tail = "\n".join(done.stdout.decode(errors="replace").splitlines()[-15:])
    return done.returncode, time.monotonic() - start, tail


def check_table(mutations: list[Mutation]) -> None:
    """Every pattern must occur exactly once in its file, so that each mutation is the bug it
    names and the table notices when the code moves on."""
    for m in mutations:
        count = (ROOT / m.path).read_text().count(m.pattern)
        if count != 1:
            raise SystemExit(
                f"mutate: {m.path}: the pattern {m.pattern!r} ({m.name}) occurs {count} times"
            )


def mutate_module(copy: Path, name: str, only: set[str] | None = None) -> list[Outcome]:
    """Each mutation of module `name` (those named in `only`, if given) in `copy`, one at a
    time, against the module's tests."""
    module = MODULES[name]
    status, baseline, output = run_tests(copy, module.tests, None)
    if status != 0:
        raise SystemExit(
            f"mutate: {name}: its tests fail before any mutation ({module.tests}):\n{output}"
        )
    timeout = max(MIN_TIMEOUT_S, TIMEOUT_FACTOR * baseline)
    outcomes = []
    for m in module.mutations:
        if only is not None and m.name not in only:
            continue
        path = copy / m.path
        original = path.read_text()
        path.write_text(original.replace(m.pattern, m.replacement, 1))
        try:
            status, seconds, _ = run_tests(copy, module.tests, timeout)
        finally:
            path.write_text(original)
        how = "timeout" if status == -1 else "failed" if status != 0 else "survived"
        outcomes.append(Outcome(m, how != "survived", how, seconds))
        mark = "killed  " if how != "survived" else "SURVIVED"
        print(f"  {mark} {m.name} ({how}, {seconds:.0f} s)", flush=True)
    return outcomes


def report(results: dict[str, list[Outcome]]) -> str:
    lines = ["", "module                                 killed  score  survivors"]
    for name, outcomes in results.items():
        killed = sum(o.killed for o in outcomes)
        score = 100.0 * killed / len(outcomes)
        lines.append(
            f"{name:38s} {killed:3d}/{len(outcomes):<3d} {score:5.1f} %  {len(outcomes) - killed}"
        )
    survivors = [o for outcomes in results.values() for o in outcomes if not o.killed]
    if survivors:
        lines.append("\nsurvivors:")
    for o in survivors:
        m = o.mutation
        verdict = f"equivalent: {m.equivalent}" if m.equivalent else "NOT EXPLAINED"
        lines.append(f"  {m.module}: {m.name} ({verdict})")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m data_tools.mutate", description=__doc__)
    parser.add_argument("--module", action="append", choices=sorted(MODULES), default=None)
    parser.add_argument(
        "--mutation", action="append", default=None, help="only the mutations of these names"
    )
    parser.add_argument("--list", action="store_true", help="list the mutations and stop")
    args = parser.parse_args(argv)
    names = args.module or list(MODULES)
    only = None if args.mutation is None else set(args.mutation)
    mutations = [
        m for name in names for m in MODULES[name].mutations if only is None or m.name in only
    ]
    if only is not None:
        unknown = only - {m.name for m in mutations}
        if unknown:
            parser.error(f"no mutation named {sorted(unknown)[0]!r} in {', '.join(names)}")
        names = [name for name in names if any(m.module == name for m in mutations)]
    check_table(mutations)
    if args.list:
        for m in mutations:
            print(f"{m.module}: {m.name}")
        return 0
    results: dict[str, list[Outcome]] = {}
    with tempfile.TemporaryDirectory(prefix="mmslam-mutate-") as tmp:
        copy = Path(tmp)
        copy_project(copy)
        for name in names:
            module = MODULES[name]
            count = sum(m.module == name for m in mutations)
            print(f"{name}: {count} mutations, tests {' '.join(module.tests)}")
            results[name] = mutate_module(copy, name, only)
    print(report(results))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
