"""`make bench`: speed and memory figures, printed; nothing here asserts anything about time.

Parts (all by default, or `--only read,backend,ratios,crowded,isam2,mixture,viz,frontend`):
- read: `read_log` (the container, every message decoded and checked) on a 50,000-pose log
  (`simulate indoor-tags` chained, as `memory` makes it): best of three, wall and CPU time.
- backend: known, ml, mm, mm-nh and dcsam on a `simulate kitti05-cars` log (2,761 poses, ~10,000
  detections) and on a long aliased city-grid log (`--long-poses`, 10,000 by default): wall
  and CPU time, ratio to known (CPU: the machine may be shared), to the log's real duration,
  back-end time per detection in every tenth of the log and its ratio to known's there, peak
  memory (VmHWM: each method in its own process), RMSE, landmarks.
- ratios: each robust method's time over known's on the logs of the speed targets (the
  README's session, KITTI-05-size at noise 3, the street grid at noise 4, the planar park,
  Victoria Park converted from GTSAM's wheel), in interleaved rounds (`--pairs`, one replay of
  each method a round): each round's ratios, wall and CPU, and their medians against the
  targets (mm-nh <= 3x, ml and mm <= 2x). These machines share their cores: one pair is not a
  measurement.
- crowded: a keyframe of 1,000 detections (`crowded_log.py`, crowded on the landmarks in view
  and spread over the view), replayed with mm-nh: wall time and peak memory, against the
  targets of 60 s and 1 GB.
- isam2: GTSAM's iSAM2 alone on a bare Pose3 chain, ms per update as it grows
  (`bench_isam2.py`: why a long log's last tenth costs more per keyframe than its first).
- mixture: where the max-mixture picks its component, native factors swapped between iSAM2
  updates against a Python CustomFactor deciding at every linearisation.
- viz: replay time without and with a Rerun recording.
- frontend: frames per second of each image stage (VO, tags, object boxes and their stereo
  range) on 1226x370 stereo pairs, one core.
- memory (only when asked, `--only memory`: the replays take minutes): peak memory and time of
  `inspect` and `replay --method known` on logs of 10,000 and 50,000 poses.

`--joint-ages METHOD [--log LOG]`: one replay's joint marginals by who asks and by the age of
their oldest landmark, calls and seconds.

`--tree METHOD [--log LOG] [--keyframes K]`: the Bayes tree after one replay (or its first K
keyframes), and what GTSAM's marginals of some of its landmarks cost there: alone, jointly
with the newest pose, and all of them jointly with it in one query.

`--profile METHOD [--log LOG]`: one replay under cProfile (the KITTI-05-size log by default):
where its time goes (GTSAM's calls, numpy's, the rest of Python) and the functions with the
most time of their own.
"""

from __future__ import annotations

import argparse
import cProfile
import dataclasses
import hashlib
import json
import pstats
import subprocess
import sys
import time
from pathlib import Path

import gtsam
import numpy as np

from data_tools.bench_memory import peak_kb
from pipeline.arguments import method_list

# The methods benched unless --methods names others.
BENCHED_METHODS = ("known", "ml", "mm", "mm-nh", "dcsam")


def run_one(log_path: Path, method: str, overrides: dict[str, dict]) -> dict:
    """One replay in this process: its figures, as a dict."""
    from pipeline.config import load_config
    from pipeline.log import read_log
    from pipeline.replay import compute_metrics, keyframes, new_backend, one_blas_thread

    config = load_config()
    for section, values in overrides.items():
        config = dataclasses.replace(
            config, **{section: dataclasses.replace(getattr(config, section), **values)}
        )
    log = read_log(log_path)
    start, cpu = time.perf_counter(), time.process_time()
    backend = new_backend(log, method, config)
    detections, step_seconds = [], []
    with one_blas_thread():  # as a replay runs
        for odometry, dets in keyframes(log):
            step = time.perf_counter()
            backend.add_keyframe(odometry, dets)
            step_seconds.append(time.perf_counter() - step)
            detections.append(len(dets))
    result = backend.result()
    seconds, cpu_seconds = time.perf_counter() - start, time.process_time() - cpu
    metrics = compute_metrics(log, result, method, seconds)
    stamps = log.pose_stamps_ns()
    return {
        "method": method,
        "seconds": seconds,
        "cpu_seconds": cpu_seconds,
        "log_seconds": (stamps[-1] - stamps[0]) * 1e-9,
        "ms_per_detection": deciles_ms_per_detection(step_seconds, detections),
        "peak_mb": peak_kb("self") / 1024,
        "rmse_m": metrics.get("translation_error_m", {}).get("rmse", float("nan")),
        "landmarks": len(result.landmark_ids),
        "poses": len(detections),
    }


def deciles_ms_per_detection(step_seconds: list[float], detections: list[int]) -> list[float]:
    """Milliseconds of back-end time per detection in each tenth of the log (by keyframe)."""
    steps, counts = np.array(step_seconds), np.array(detections)
    parts = np.array_split(np.arange(len(steps)), 10)
    return [1e3 * steps[p].sum() / max(counts[p].sum(), 1) for p in parts]


def run_in_subprocess(log_path: Path, method: str, overrides: dict) -> dict:
    command = [sys.executable, "-m", "data_tools.bench", "--run-one", str(log_path), method,
               json.dumps(overrides)]  # fmt: skip
    out = subprocess.run(command, check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def simulated_log(out: Path, scenario: str, seed: int = 0, config: str = "", **options) -> Path:
    """A log of `scenario` (over a config of TOML text, if given), made once."""
    from data_tools.scenarios import simulate

    tag = "".join(f"-{k}{v}" for k, v in sorted(options.items()))
    if config:
        tag += "-" + hashlib.sha256(config.encode()).hexdigest()[:8]
    path = out / f"{scenario}-seed{seed}{tag}.mcap"
    if not path.exists():
        config_path = None
        if config:
            config_path = out / f"{path.stem}.toml"
            config_path.write_text(config)
        simulate(scenario, path, seed=seed, config_path=config_path, foxglove=False, **options)
    return path


def print_table(rows: list[dict], reference: dict) -> None:
    """Totals, then the cost per detection of each tenth of the log and its ratio to the
    reference's (known's) in the same tenth."""
    print(
        f"{'method':<22}{'wall s':>8}{'cpu s':>8}{'x known':>8}{'x real time':>12}"
        f"{'last/first':>11}{'peak MB':>9}{'RMSE m':>8}{'landmarks':>10}"
    )
    for r in rows:
        deciles = r["ms_per_detection"]
        print(
            f"{r['label']:<22}{r['seconds']:>8.1f}{r['cpu_seconds']:>8.1f}"
            f"{r['cpu_seconds'] / reference['cpu_seconds']:>8.2f}"
            f"{r['log_seconds'] / r['seconds']:>11.1f}x{deciles[-1] / deciles[0]:>11.2f}"
            f"{r['peak_mb']:>9.0f}{r['rmse_m']:>8.3f}{r['landmarks']:>10}"
        )
    print("ms per detection by tenth of the log (and x known in the same tenth):")
    for r in rows:
        pairs = zip(r["ms_per_detection"], reference["ms_per_detection"], strict=True)
        cells = " ".join(f"{mine:6.2f} ({mine / theirs:4.1f})" for mine, theirs in pairs)
        print(f"  {r['label']:<20}{cells}")


def bench_log(log_path: Path, title: str, methods: tuple[str, ...]) -> None:
    print(f"\n== back-end on {log_path} ({title})")
    rows = []
    for method in methods:
        rows.append({**run_in_subprocess(log_path, method, {}), "label": method})
        print(f"  {method}: {rows[-1]['seconds']:.1f} s", flush=True)
    known = next((r for r in rows if r["method"] == "known"), rows[0])
    print_table(rows, known)


def bench_backend(out: Path, methods: tuple[str, ...], long_poses: int) -> None:
    log_path = simulated_log(out, "kitti05-cars")
    bench_log(log_path, "kitti05-cars, 2,761 poses, ~10,000 detections", methods)
    print("targets: mm-nh <= 3x known in total, <= 4x in every tenth, ~25x real time; ml, mm <= 2x")
    # An aliased city driven for long: 3 m a keyframe.
    length = 3.0 * long_poses
    long_path = simulated_log(out, "city-grid", config=f"[route]\nlength_m = {length}\n")
    bench_log(long_path, f"city-grid, {long_poses:,} poses", methods)
    print("target: known's last-10 %/first-10 % cost per detection <= 4")


def victoria_park_log(out: Path) -> Path:
    """GTSAM's Victoria Park as a contract log (`mmslam convert`), made once."""
    import gtsam

    from data_tools.landmarks2d import convert_landmarks2d

    path = out / "victoria_park.mcap"
    if not path.exists():
        convert_landmarks2d(Path(gtsam.__file__).parent / "Data" / "victoria_park.txt", path)
    return path


# The logs of the speed targets: (title, scenario, options); Victoria Park's is converted.
RATIO_LOGS = (
    ("README session", "indoor-tags",
     {"seed": 2, "odom_noise_scale": 4.0, "misclassification": 0.1, "true_covariance": True}),
    ("KITTI-05-size, noise 3", "kitti05-cars", {"odom_noise_scale": 3.0}),
    ("street grid, noise 4", "city-grid", {"odom_noise_scale": 4.0}),
    ("planar park", "planar-park", {}),
)  # fmt: skip
RATIO_TARGETS = {"ml": 2.0, "mm": 2.0, "mm-nh": 3.0}


def bench_ratios(out: Path, pairs: int, methods: tuple[str, ...]) -> None:
    """Each method against known on each log of the speed targets, in interleaved rounds: the
    median of the rounds' ratios, wall and CPU."""
    logs = [(t, simulated_log(out, s, **{"seed": 0, **o})) for t, s, o in RATIO_LOGS]
    logs.append(("Victoria Park", victoria_park_log(out)))
    robust = [m for m in methods if m != "known"]
    print(f"\n== time over known's, median of {pairs} interleaved rounds (wall; CPU)")
    for title, log_path in logs:
        ratios: dict[str, list[tuple[float, float]]] = {m: [] for m in robust}
        for _ in range(pairs):
            known = run_in_subprocess(log_path, "known", {})
            for method in robust:
                r = run_in_subprocess(log_path, method, {})
                ratios[method].append(
                    (r["seconds"] / known["seconds"], r["cpu_seconds"] / known["cpu_seconds"])
                )
        cells = []
        for method, rounds in ratios.items():
            wall, cpu = (float(np.median(column)) for column in zip(*rounds, strict=True))
            target = RATIO_TARGETS.get(method)
            cells.append(
                f"{method} {wall:.2f}x ({cpu:.2f}x)"
                + (f" {'within' if wall <= target else 'over'} {target:g}x" if target else "")
            )
        print(f"  {title} (known {known['seconds']:.1f} s): " + "; ".join(cells), flush=True)


def bench_crowded(out: Path) -> None:
    """mm-nh on a keyframe of 1,000 detections, crowded on the landmarks in view and spread
    over the view: wall time and peak memory."""
    from data_tools.crowded_log import main as crowded_log

    print("\n== a keyframe of 1,000 detections, mm-nh (targets: 60 s, 1 GB)")
    for name, options in (("crowded", []), ("spread", ["--spread"])):
        log_path = out / f"{name}-1000.mcap"
        if not log_path.exists():
            crowded_log(["--detections", "1000", *options, "--out", str(log_path)])
        r = run_in_subprocess(log_path, "mm-nh", {})
        size = f"{r['seconds']:.1f} s, {r['peak_mb']:.0f} MB, {r['landmarks']} landmarks"
        print(f"  {name}: {size}", flush=True)


def time_shares(stats: pstats.Stats) -> dict[str, float]:
    """Seconds spent inside GTSAM's wrapped calls, inside numpy's compiled functions, and in
    the rest (Python, and the C calls it makes otherwise), from a profile's own times."""
    shares = {"gtsam": 0.0, "numpy": 0.0, "python": 0.0}
    for (path, _, name), (_, _, own, _, _) in stats.stats.items():  # type: ignore[attr-defined]
        if "gtsam" in name or "gtsam" in path:
            shares["gtsam"] += own
        elif "numpy" in name or "numpy" in path:
            shares["numpy"] += own
        else:
            shares["python"] += own
    return shares


def joint_ages(log_path: Path, method: str) -> None:
    """Every joint marginal one replay asks iSAM2 for, by who asks and by how many keyframes
    ago the oldest landmark in it was last seen: calls and seconds (the Bayes tree makes a
    joint with a landmark seen long ago expensive; `bench_isam2.joint_marginal_ms`)."""
    from pipeline.backend.movement import is_landmark_key, key_index
    from pipeline.backend.solver import Isam2Solver
    from pipeline.config import load_config
    from pipeline.log import read_log
    from pipeline.replay import keyframes, new_backend

    log = read_log(log_path)
    backend = new_backend(log, method, load_config())
    calls: list[tuple[str, int, float]] = []
    asked = Isam2Solver.joint_covariance

    def timed(solver: Isam2Solver, keys: list[int]) -> np.ndarray:
        start = time.perf_counter()
        out = asked(solver, keys)
        seconds = time.perf_counter() - start
        last_seen = backend.context.last_seen
        ages = [
            backend.num_poses - last_seen.get(key_index(k), -(10**9))
            for k in keys
            if is_landmark_key(k)
        ]
        calls.append((sys._getframe(1).f_code.co_name, max(ages, default=0), seconds))
        return out

    Isam2Solver.joint_covariance = timed  # type: ignore[method-assign]
    try:
        for odometry, detections in keyframes(log):
            backend.add_keyframe(odometry, detections)
    finally:
        Isam2Solver.joint_covariance = asked  # type: ignore[method-assign]
    print(f"== joint marginals of {method} on {log_path}, by the age of their oldest landmark")
    print(f"{'asked by':<16}{'keyframes ago':>16}{'calls':>8}{'seconds':>9}")
    spans = [(0, 30), (31, 100), (101, 1000), (1001, 10**9)]
    for who in sorted({c[0] for c in calls}):
        for low, high in spans:
            mine = [c for c in calls if c[0] == who and low <= c[1] <= high]
            span = f"{low}-{high}" if high < 10**9 else f"> {low - 1}"
            print(f"{who:<16}{span:>16}{len(mine):>8}{sum(c[2] for c in mine):>9.2f}")


def tree_costs(log_path: Path, method: str, limit: int | None = None, sample: int = 20) -> None:
    """The Bayes tree after replaying `log_path` (its first `limit` keyframes), and the ms of
    marginal queries there for `sample` of its landmarks spread over their ids; then the same
    for the same graph eliminated anew in batch (COLAMD's ordering of the whole graph): why a
    joint with an old landmark costs what it costs, and whether another ordering would help."""
    from pipeline.config import load_config
    from pipeline.log import read_log
    from pipeline.replay import keyframes, new_backend

    log = read_log(log_path)
    backend = new_backend(log, method, load_config())
    for k, (odometry, detections) in enumerate(keyframes(log)):
        if limit is not None and k >= limit:
            break
        backend.add_keyframe(odometry, detections)
    L = gtsam.symbol_shorthand.L
    isam = backend.solver.isam
    ids = [j for j in sorted(backend.landmarks.landmarks) if isam.valueExists(L(j))]
    chosen = [ids[i] for i in np.unique(np.linspace(0, len(ids) - 1, sample).astype(int))]
    print(f"== {method} on {log_path}, after {backend.num_poses} poses")
    _print_tree_costs("iSAM2's tree", backend, ids, chosen)
    backend.solver.update(anew=True)
    _print_tree_costs("the same graph eliminated anew", backend, ids, chosen)


def _print_tree_costs(what: str, backend, ids: list[int], chosen: list[int]) -> None:
    from data_tools.bench_isam2 import bayes_tree_shape, timed_ms

    isam = backend.solver.isam
    X, L = gtsam.symbol_shorthand.X, gtsam.symbol_shorthand.L
    newest = X(backend.num_poses - 1)
    shape = bayes_tree_shape(isam)
    depths = np.array([shape.depth[f"l{j}"] for j in ids])
    print(
        f"{what}: {shape.cliques} cliques; the root holds {shape.root_frontals} variables, the "
        f"largest clique {shape.largest_frontals}; landmarks' depth mean {depths.mean():.1f}, "
        f"max {depths.max()}"
    )
    print(f"  {'ms of a query (first, again)':<32}{'marginal':>18}{'joint with newest pose':>26}")
    for j in chosen:
        marginal = timed_ms(lambda j=j: isam.marginalCovariance(L(j)), repeats=3)
        joint = timed_ms(lambda j=j: isam.jointMarginalCovariance([newest, L(j)]), repeats=3)
        ago = backend.num_poses - 1 - backend.context.last_seen.get(j, 0)
        print(
            f"  l{j:<6} depth {shape.depth[f'l{j}']:>4}, seen {ago:>5} ago"
            f"{marginal[0]:>9.2f}{marginal[1]:>9.2f}{joint[0]:>13.2f}{joint[1]:>13.2f}"
        )
    together = timed_ms(
        lambda: isam.jointMarginalCovariance([newest, *[L(j) for j in chosen]]), repeats=3
    )
    print(
        f"  all {len(chosen)} in one joint with the newest pose: {together[0]:.2f}, "
        f"{together[1]:.2f} ms"
    )


def profile_one(log_path: Path, method: str, top: int = 25) -> None:
    """One replay of `log_path` by `method` under cProfile, summarised."""
    profiler = cProfile.Profile()
    figures = profiler.runcall(run_one, log_path, method, {})
    stats = pstats.Stats(profiler)
    shares = time_shares(stats)
    total = sum(shares.values())
    print(f"== {method} on {log_path}: {figures['seconds']:.1f} s under the profiler")
    print("  " + ", ".join(f"{k} {v:.1f} s ({100 * v / total:.0f} %)" for k, v in shares.items()))
    stats.sort_stats("tottime").print_stats(top)


def bench_mixture(out: Path) -> None:
    # True covariance: the gates let in several candidates, so the mixtures have work to do.
    log_path = simulated_log(
        out, "indoor-tags", seed=1, odom_noise_scale=4.0, misclassification=0.1,
        true_covariance=True,
    )  # fmt: skip
    print(f"\n== max-mixture selection on {log_path} (indoor-tags, noise x4, true covariance)")
    # A CustomFactor revisits its choice only when iSAM2 relinearises: compare at skip 1.
    tight = {"relinearize_threshold": 0.01, "relinearize_skip": 1, "per_type_thresholds": False}
    rows = []
    for selection in ("between-updates", "custom-factor"):
        overrides = {"mixture": {"selection": selection}, "isam2": tight}
        rows.append({**run_in_subprocess(log_path, "mm-nh", overrides), "label": selection})
    print_table(rows, rows[0])
    print("(x known column: relative to between-updates)")


def bench_read(out: Path, poses: int = 50_000, repeats: int = 3) -> None:
    """Reading (and checking) a long log: the best of a few reads, wall and CPU time."""
    from data_tools.bench_memory import long_log
    from pipeline.log import read_log

    path = long_log(out, poses)
    walls, cpus = [], []
    for _ in range(repeats):
        start, cpu = time.perf_counter(), time.process_time()
        log = read_log(path)
        walls.append(time.perf_counter() - start)
        cpus.append(time.process_time() - cpu)
    print(f"\n== reading {path} ({log.num_poses} poses, {log.num_detections} detections)")
    print(f"read_log, best of {repeats}: {min(walls):.2f} s wall, {min(cpus):.2f} s CPU")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out/bench"))
    parser.add_argument("--only", default="read,backend,ratios,crowded,isam2,mixture,viz,frontend")
    parser.add_argument("--methods", type=method_list, default=list(BENCHED_METHODS))
    parser.add_argument(
        "--long-poses", type=int, default=10000, help="poses of the long log (default 10,000)"
    )
    parser.add_argument("--pairs", type=int, default=3, help="rounds of ratios (default 3)")
    parser.add_argument("--run-one", nargs=3, metavar=("LOG", "METHOD", "OVERRIDES"))
    parser.add_argument("--profile", metavar="METHOD", help="profile one replay (cProfile)")
    parser.add_argument(
        "--joint-ages", metavar="METHOD", help="one replay's joint marginals, by landmark age"
    )
    parser.add_argument(
        "--tree", metavar="METHOD", help="the Bayes tree after a replay, and its marginals' cost"
    )
    parser.add_argument("--keyframes", type=int, help="--tree: replay only this many keyframes")
    parser.add_argument(
        "--log",
        type=Path,
        help="the log of --profile, --joint-ages, --tree (default: KITTI-05-size)",
    )
    args = parser.parse_args(argv)
    if args.tree:
        args.out.mkdir(parents=True, exist_ok=True)
        tree_costs(args.log or simulated_log(args.out, "kitti05-cars"), args.tree, args.keyframes)
        return 0
    if args.joint_ages:
        args.out.mkdir(parents=True, exist_ok=True)
        joint_ages(args.log or simulated_log(args.out, "kitti05-cars"), args.joint_ages)
        return 0
    if args.profile:
        args.out.mkdir(parents=True, exist_ok=True)
        profile_one(args.log or simulated_log(args.out, "kitti05-cars"), args.profile)
        return 0
    if args.run_one:
        log_path, method, overrides = args.run_one
        print(json.dumps(run_one(Path(log_path), method, json.loads(overrides))))
        return 0
    args.out.mkdir(parents=True, exist_ok=True)
    parts = set(args.only.split(","))
    if "read" in parts:
        bench_read(args.out)
    if "backend" in parts:
        bench_backend(args.out, tuple(args.methods), args.long_poses)
    if "ratios" in parts:
        bench_ratios(args.out, args.pairs, tuple(args.methods))
    if "crowded" in parts:
        bench_crowded(args.out)
    if "isam2" in parts:
        from data_tools import bench_isam2

        bench_isam2.main([])
    if "mixture" in parts:
        bench_mixture(args.out)
    if "viz" in parts:
        from data_tools import bench_viz

        bench_viz.main([])
    if "frontend" in parts:
        from data_tools import bench_frontend, bench_objects

        bench_frontend.main([])
        bench_objects.main([])
    if "memory" in parts:
        from data_tools import bench_memory

        bench_memory.main(["--out", str(args.out)])
    return 0


if __name__ == "__main__":
    sys.exit(main())
