"""How far a replay's final estimate is from the optimum of its own graph.

iSAM2 relinearises a variable only once its step passes `[isam2]`'s thresholds, so the estimate
it returns solves the graph as linearised where the variables stood, not the graph itself.
This replays each log, then solves the final graph in batch (Levenberg-Marquardt from iSAM2's
estimate) and prints, for both estimates, the graph's cost (GTSAM's error) and the path's RMSE
against the log's ground truth, and how far apart the two paths are. Where both paths miss a
target alike, the estimator misses it, not the solver. No assertions: this prints figures.

    python -m data_tools.optimality LOG [LOG ...] [--methods known,mm-nh] [--config F]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from gtsam.symbol_shorthand import X

from pipeline.arguments import method_list
from pipeline.config import Config, load_config
from pipeline.errors import InputError, SolverError
from pipeline.log import read_log
from pipeline.replay import check_inputs, compute_metrics, run_backend, solver_failures
from pipeline.viz.sink import NullSink


@dataclass(frozen=True)
class Optimality:
    """One replay's final estimate against its graph's optimum."""

    method: str
    poses: int
    cost: float  # the graph's error at iSAM2's estimate
    optimum_cost: float  # at the batch optimum
    rmse_m: float  # the path's translation RMSE against the ground truth (nan without it)
    optimum_rmse_m: float
    largest_move_m: float  # the largest distance between a pose's two estimates


def translation_rmse(metrics: dict) -> float:
    return float(metrics.get("translation_error_m", {}).get("rmse", float("nan")))


def check_optimality(log_path: Path, method: str, config: Config) -> Optimality:
    """Replay `log_path` by `method`, then compare iSAM2's final estimate with the optimum."""
    log = read_log(log_path)
    check_inputs(log, method)
    with solver_failures():  # what GTSAM throws ends as one SolverError line
        backend = run_backend(log, method, config, NullSink(), progress=False)
        result = backend.result()
        cost, optimum_cost, optimum = backend.solver.batch_optimum()
    poses = [optimum.atPose3(X(i)) for i in range(len(result.poses))]
    moves = [
        np.linalg.norm(a.translation() - b.translation())
        for a, b in zip(result.poses, poses, strict=True)
    ]
    at_optimum = dataclasses.replace(result, poses=poses)
    return Optimality(
        method=method,
        poses=len(poses),
        cost=cost,
        optimum_cost=optimum_cost,
        rmse_m=translation_rmse(compute_metrics(log, result, method, 0.0)),
        optimum_rmse_m=translation_rmse(compute_metrics(log, at_optimum, method, 0.0)),
        largest_move_m=float(max(moves, default=0.0)),
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("logs", nargs="+", type=Path)
    parser.add_argument("--methods", type=method_list, default=["known"], help="default: known")
    parser.add_argument("--config", type=Path, help="back-end keys over configs/default.toml")
    args = parser.parse_args(argv)
    try:
        config = load_config(args.config)
        header = f"{'log':<44}{'method':<8}{'poses':>7}{'cost':>11}{'optimum':>11}"
        print(f"{header}{'RMSE m':>9}{'opt. m':>9}{'moved m':>9}")
        for log_path in args.logs:
            for method in args.methods:
                r = check_optimality(log_path, method, config)
                print(
                    f"{str(log_path)[-43:]:<44}{method:<8}{r.poses:>7}{r.cost:>11.1f}"
                    f"{r.optimum_cost:>11.1f}{r.rmse_m:>9.3f}{r.optimum_rmse_m:>9.3f}"
                    f"{r.largest_move_m:>9.3f}"
                )
    except (InputError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except SolverError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
