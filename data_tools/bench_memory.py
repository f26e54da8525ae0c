"""Peak memory and time of `mmslam inspect` and `mmslam replay --method known` on long logs.

The logs are `simulate indoor-tags` (1,501 poses) chained to 10,000 and 50,000 poses
(`data_tools/long_log.py`). Each command runs in its own process; its peak resident memory is
its high-water mark of resident memory (VmHWM). A replay that runs past `--timeout` is stopped
and reported with the memory it had reached.

    python -m data_tools.bench_memory [--poses 10000,50000] [--timeout 1800] [--out out/bench]
"""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from data_tools.long_log import write_long_log

# `mmslam`, reporting its peak resident memory as it exits. Not wait4's ru_maxrss: Linux counts
# into it the parent's memory at the fork, when the parent is larger than what it starts.
PEAK_REPORTING = """
import atexit, sys
from data_tools.bench_memory import peak_kb
atexit.register(lambda: sys.stderr.write(f"peak_kb {peak_kb('self')}\\n"))
from pipeline.cli import main
sys.exit(main(sys.argv[1:]))
"""


def peak_kb(pid: int | str) -> int:
    """The high-water mark of a process's resident memory (kB), from /proc."""
    with open(f"/proc/{pid}/status") as status:
        return next(int(line.split()[1]) for line in status if line.startswith("VmHWM:"))


def measure(arguments: list[str], timeout_s: float) -> tuple[float, float, str]:
    """(seconds, peak MB, how it ended) of `mmslam ARGUMENTS` in a process of its own."""
    command = [sys.executable, "-c", PEAK_REPORTING, *arguments]
    reached: list[int] = []

    def stop() -> None:
        reached.append(peak_kb(process.pid))
        process.send_signal(signal.SIGKILL)

    start = time.perf_counter()
    with tempfile.TemporaryFile() as errors:
        process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=errors)
        timer = threading.Timer(timeout_s, stop)
        timer.start()
        try:
            code = process.wait()
        finally:
            timer.cancel()
        seconds = time.perf_counter() - start
        errors.seek(0)
        lines = errors.read().decode(errors="replace").strip().splitlines()
    reached += [int(line.split()[1]) for line in lines if line.startswith("peak_kb ")]
    said = [line for line in lines if not line.startswith("peak_kb ")]
    if code == -signal.SIGKILL:
        ended = f"stopped after {timeout_s:.0f} s"
    else:
        ended = f"exit {code}: {said[-1] if said else ''}" if code else "done"
    return seconds, (reached[-1] if reached else float("nan")) / 1024, ended


def long_log(out: Path, poses: int) -> Path:
    source = out / "indoor-tags-seed1.mcap"
    if not source.exists():
        from data_tools.scenarios import simulate

        simulate("indoor-tags", source, seed=1)
    path = out / f"indoor-tags-seed1-chained-{poses}.mcap"
    if not path.exists():
        write_long_log(source, path, poses)
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--poses", default="10000,50000")
    parser.add_argument("--timeout", type=float, default=1800.0, help="per replay (s)")
    parser.add_argument("--out", type=Path, default=Path("out/bench"))
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    print(
        f"\n== memory on long logs (indoor-tags chained; replay stopped after {args.timeout:g} s)"
    )
    print(f"{'poses':>8}{'log MB':>8}  {'command':<16}{'time s':>9}{'peak MB':>9}  ended")
    for poses in (int(p) for p in args.poses.split(",")):
        log = long_log(args.out, poses)
        size = log.stat().st_size / 2**20
        replay_out = str(args.out / f"replay-known-{poses}")
        runs = {
            "inspect": ["inspect", str(log)],
            "replay known": [
                "replay",
                str(log),
                "--method",
                "known",
                "--quiet",
                "--out",
                replay_out,
            ],
        }
        for name, command in runs.items():
            seconds, peak, ended = measure(command, args.timeout)
            print(
                f"{poses:>8}{size:>8.1f}  {name:<16}{seconds:>9.1f}{peak:>9.0f}  {ended}",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
