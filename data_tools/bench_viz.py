"""What a Rerun recording costs a replay: the same replay without Rerun options and with
`--rrd`, on a `mmslam simulate indoor-tags` log (or `--log`).

    python -m data_tools.bench_viz                  # simulates indoor-tags (seed 1), mm-nh
    python -m data_tools.bench_viz --log out/kitti05.mcap --method mm --repeat 1

Each configuration runs `--repeat` times in this process, alternating; the best run of each is
reported (the least disturbed by other processes): wall-clock time of the whole replay (read,
back-end, outputs, and for `--rrd` the recording's start, finish and close), the back-end loop
alone (`runtime_s`, which includes the sink's per-keyframe work), and CPU time, which counts
Rerun's own threads as well. No assertions: this prints figures.
"""

from __future__ import annotations

import argparse
import logging
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Run:
    name: str
    wall_s: float
    loop_s: float
    cpu_s: float
    rrd_bytes: int = 0


def run_once(log_path: Path, method: str, out: Path, rrd: Path | None) -> Run:
    from pipeline.config import load_config
    from pipeline.replay import replay
    from pipeline.viz import sink_from_options

    config = load_config()
    wall, cpu = time.perf_counter(), time.process_time()
    sink = sink_from_options(rrd, False, None, application="mmslam bench")
    result = replay(log_path, method, out, config, sink=sink, progress=False)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    size = rrd.stat().st_size if rrd is not None else 0
    return Run("--rrd" if rrd else "no Rerun option", wall, result.runtime_s, cpu, size)


def bench(log_path: Path, method: str, repeat: int, scratch: Path) -> tuple[Run, Run]:
    plain: list[Run] = []
    recorded: list[Run] = []
    for k in range(repeat):
        plain.append(run_once(log_path, method, scratch / "plain", None))
        recorded.append(run_once(log_path, method, scratch / "rrd", scratch / f"run{k}.rrd"))
    return min(plain, key=lambda r: r.wall_s), min(recorded, key=lambda r: r.wall_s)


def report(log_path: Path, method: str, plain: Run, recorded: Run, num_poses: int) -> str:
    lines = [
        f"viz: replay {method} of {log_path.name} ({num_poses} poses), without and with --rrd",
        f"{'':18s} {'wall s':>8s} {'loop s':>8s} {'cpu s':>8s} {'rrd MB':>8s}",
    ]
    for r in (plain, recorded):
        lines.append(
            f"{r.name:18s} {r.wall_s:8.2f} {r.loop_s:8.2f} {r.cpu_s:8.2f} {r.rrd_bytes / 1e6:8.1f}"
        )
    extra_ms = 1e3 * (recorded.loop_s - plain.loop_s) / max(num_poses, 1)
    lines.append(
        f"overhead of --rrd: wall x{recorded.wall_s / plain.wall_s:.2f}, "
        f"loop x{recorded.loop_s / plain.loop_s:.2f} ({extra_ms:+.2f} ms a keyframe), "
        f"cpu x{recorded.cpu_s / plain.cpu_s:.2f}"
    )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--log", type=Path, help="a detection log (default: simulate one)")
    parser.add_argument("--method", default="mm-nh")
    parser.add_argument("--seed", type=int, default=1, help="of the simulated log")
    parser.add_argument("--repeat", type=int, default=2)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    from pipeline.log import read_log

    with tempfile.TemporaryDirectory(prefix="mmslam-bench-viz-") as tmp:
        scratch = Path(tmp)
        log_path = args.log
        if log_path is None:
            from data_tools.scenarios import simulate

            log_path = scratch / "indoor-tags.mcap"
            simulate("indoor-tags", log_path, seed=args.seed)
        plain, recorded = bench(log_path, args.method, max(args.repeat, 1), scratch)
        num_poses = read_log(log_path).num_poses
        print(report(log_path, args.method, plain, recorded, num_poses))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
