"""GTSAM's own iSAM2 on a bare Pose3 chain, without mmslam: milliseconds per update as the
chain grows. No assertions: this prints figures.

    python -m data_tools.bench_isam2 [--poses 20000] [--every 2500]

Each update adds one pose and its odometry factor, as a keyframe with no detection does. The
time per update grows with the chain, whatever the relinearisation and caching parameters:
in GTSAM 4.3 every update (`ISAM2::recalculateIncremental`) ends by destroying a temporary
Bayes tree whose roots are the re-eliminated top, with every orphaned subtree attached below
it, and `BayesTree::~BayesTree` walks every clique it reaches (a breadth-first queue of shared
pointers, written to avoid deep recursion): the whole tree, at every update. `py-spy record
--native` on this script at 20,000 poses puts 74 % of the time in `~BayesTree`. This is why a
long log's last tenth costs more per keyframe than its first (issue 35's 26,661-pose chain:
7.1x), and why a replay's back-end time grows faster than its log.
"""

from __future__ import annotations

import argparse
import sys
import time

import gtsam
import numpy as np

from pipeline.provenance import library_versions


def chain_update_ms(poses: int, every: int) -> list[tuple[int, float]]:
    """(poses so far, mean ms per update over the last `every` updates), every `every` poses."""
    isam = gtsam.ISAM2(gtsam.ISAM2Params())
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-3] * 3 + [0.1] * 3))
    step = gtsam.Pose3(gtsam.Rot3.Yaw(0.01), gtsam.Point3(1.0, 0.0, 0.0))
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    graph.add(gtsam.PriorFactorPose3(0, gtsam.Pose3(), noise))
    values.insert(0, gtsam.Pose3())
    isam.update(graph, values)
    pose, out = gtsam.Pose3(), []
    start = time.perf_counter()
    for k in range(1, poses + 1):
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        graph.add(gtsam.BetweenFactorPose3(k - 1, k, step, noise))
        pose = pose.compose(step)
        values.insert(k, pose)
        isam.update(graph, values)
        if k % every == 0:
            out.append((k, 1e3 * (time.perf_counter() - start) / every))
            start = time.perf_counter()
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--poses", type=int, default=20_000)
    parser.add_argument("--every", type=int, default=2_500)
    args = parser.parse_args(argv)
    version = library_versions()["gtsam"]
    print(f"\n== GTSAM {version} iSAM2 alone, a bare Pose3 chain: ms per update")
    rows = chain_update_ms(args.poses, args.every)
    first = rows[0][1]
    print(f"{'poses':>8}{'ms/update':>11}{'x first':>9}")
    for poses, ms in rows:
        print(f"{poses:>8}{ms:>11.3f}{ms / first:>9.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
