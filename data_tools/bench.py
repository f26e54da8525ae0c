"""`make bench`: speed and memory figures, printed; nothing here asserts anything about time.

Parts (all by default, or `--only backend,mixture,viz,frontend`):
- backend: every association method on a `simulate kitti05-cars` log (2,761 poses, ~10,000
  detections): replay time and its ratio to `known`, time per detection in the first and last
  10 % of the log, peak memory (each method in its own process).
- mixture: where the max-mixture picks its component, native factors swapped between iSAM2
  updates against a Python CustomFactor deciding at every linearisation.
- viz: replay time without and with a Rerun recording.
- frontend: frames per second of each image stage (VO, tags, object boxes and their stereo
  range) on 1226x370 stereo pairs, one core.
- memory (only when asked, `--only memory`: the replays take minutes): peak memory and time of
  `inspect` and `replay --method known` on logs of 10,000 and 50,000 poses.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

METHODS = ("known", "ml", "gpda", "mm", "mm-nh")


def run_one(log_path: Path, method: str, overrides: dict[str, dict]) -> dict:
    """One replay in this process: its figures, as a dict."""
    from pipeline.backend.slam import Backend
    from pipeline.config import load_config
    from pipeline.log import read_log
    from pipeline.replay import compute_metrics, keyframes

    config = load_config()
    for section, values in overrides.items():
        config = dataclasses.replace(
            config, **{section: dataclasses.replace(getattr(config, section), **values)}
        )
    log = read_log(log_path)
    start = time.perf_counter()
    backend = Backend(config, np.asarray(log.metadata.confusion_matrix), method)
    detections = []
    for odometry, dets in keyframes(log):
        backend.add_keyframe(odometry, dets)
        detections.append(len(dets))
    result = backend.result()
    seconds = time.perf_counter() - start
    metrics = compute_metrics(log, result, method, seconds)
    steps, counts = np.array(backend.step_seconds), np.array(detections)
    tenth = len(steps) // 10
    per_detection = [
        steps[part].sum() / max(counts[part].sum(), 1)
        for part in (slice(0, tenth), slice(len(steps) - tenth, None))
    ]
    return {
        "method": method,
        "seconds": seconds,
        "first_ms_per_detection": 1e3 * per_detection[0],
        "last_ms_per_detection": 1e3 * per_detection[1],
        "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "rmse_m": metrics["translation_error_m"]["rmse"] if metrics else float("nan"),
        "landmarks": len(result.landmark_ids),
        "wrong": metrics["association"]["wrong"] if metrics else -1,
    }


def run_in_subprocess(log_path: Path, method: str, overrides: dict) -> dict:
    command = [sys.executable, "-m", "data_tools.bench", "--run-one", str(log_path), method,
               json.dumps(overrides)]  # fmt: skip
    out = subprocess.run(command, check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def simulated_log(out: Path, scenario: str, seed: int = 0, **options) -> Path:
    from data_tools.scenarios import simulate

    tag = "".join(f"-{k}{v}" for k, v in sorted(options.items()))
    path = out / f"{scenario}-seed{seed}{tag}.mcap"
    if not path.exists():
        simulate(scenario, path, seed=seed, **options)
    return path


def print_table(rows: list[dict], reference: float) -> None:
    print(
        f"{'method':<22}{'time s':>9}{'x known':>9}{'ms/det first 10%':>18}"
        f"{'last 10%':>10}{'last/first':>11}{'peak MB':>9}{'RMSE m':>8}{'landmarks':>10}"
    )
    for r in rows:
        ratio = r["last_ms_per_detection"] / r["first_ms_per_detection"]
        print(
            f"{r['label']:<22}{r['seconds']:>9.1f}{r['seconds'] / reference:>9.2f}"
            f"{r['first_ms_per_detection']:>18.3f}{r['last_ms_per_detection']:>10.3f}"
            f"{ratio:>11.2f}{r['peak_mb']:>9.0f}{r['rmse_m']:>8.3f}{r['landmarks']:>10}"
        )


def bench_backend(out: Path, methods: tuple[str, ...]) -> None:
    log_path = simulated_log(out, "kitti05-cars")
    print(f"\n== back-end on {log_path} (kitti05-cars, 2,761 poses, ~10,000 detections)")
    rows = []
    for method in methods:
        rows.append({**run_in_subprocess(log_path, method, {}), "label": method})
        print(f"  {method}: {rows[-1]['seconds']:.1f} s", flush=True)
    fast = {"association": {"joint_marginals": False}}
    for method in ("mm-nh",):
        row = run_in_subprocess(log_path, method, fast)
        rows.append({**row, "label": f"{method} (no joint)"})
    known = next(r["seconds"] for r in rows if r["label"] == "known")
    print_table(rows, known)
    print("targets: mm-nh <= 1.5x known; last-10 % cost <= 1.5x first-10 % cost")


def bench_mixture(out: Path) -> None:
    # True covariance: the gates let in several candidates, so the mixtures have work to do.
    log_path = simulated_log(
        out, "indoor-tags", seed=1, odom_noise_scale=4.0, misclassification=0.1,
        true_covariance=True,
    )  # fmt: skip
    print(f"\n== max-mixture selection on {log_path} (indoor-tags, noise x4, true covariance)")
    # A CustomFactor revisits its choice only when iSAM2 relinearises: compare at skip 1.
    tight = {"relinearize_threshold": 0.01, "relinearize_skip": 1}
    rows = []
    for selection in ("between-updates", "custom-factor"):
        overrides = {"mixture": {"selection": selection}, "isam2": tight}
        rows.append({**run_in_subprocess(log_path, "mm-nh", overrides), "label": selection})
    print_table(rows, rows[0]["seconds"])
    print("(x known column: relative to between-updates)")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out/bench"))
    parser.add_argument("--only", default="backend,mixture,viz,frontend")
    parser.add_argument("--methods", default=",".join(METHODS))
    parser.add_argument("--run-one", nargs=3, metavar=("LOG", "METHOD", "OVERRIDES"))
    args = parser.parse_args(argv)
    if args.run_one:
        log_path, method, overrides = args.run_one
        print(json.dumps(run_one(Path(log_path), method, json.loads(overrides))))
        return 0
    args.out.mkdir(parents=True, exist_ok=True)
    parts = set(args.only.split(","))
    if "backend" in parts:
        bench_backend(args.out, tuple(args.methods.split(",")))
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
