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

The joint marginals the association asks for cost by how far apart their variables sit in the
Bayes tree (`joint_marginal_ms`): with the newest pose in the root, a landmark seen long ago
sits deep, and GTSAM computes the shortcut of its clique to the root again at every joint
query (a single marginal is cached after its first call; the joint costs as much again). Two
old landmarks seen together share a deep ancestor, and their joint costs a small fraction.
On a replay's loopy map the depth is small but some cliques hold a hundred variables or more
(`tree_shape`; `python -m data_tools.bench --tree METHOD --log LOG`): each step of a shortcut
through them is a dense elimination that size, which is what a joint with an old landmark
pays there.
"""

from __future__ import annotations

import argparse
import re
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

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


def timed_ms(query: Callable[[], object], repeats: int = 10) -> tuple[float, float]:
    """ms of a query's first call, and of each call after it on average."""
    start = time.perf_counter()
    query()
    first = time.perf_counter()
    for _ in range(repeats):
        query()
    return 1e3 * (first - start), 1e3 * (time.perf_counter() - first) / repeats


def joint_marginal_ms(poses: int) -> dict[str, tuple[float, float]]:
    """The first call's ms and the later calls' (`timed_ms`) of some marginal queries on a
    chain of `poses` poses that saw a landmark every 50 poses (each from three poses): the
    oldest landmark's marginal, joints of the newest pose with the newest and the oldest
    landmark, and of the two oldest landmarks."""
    X, L = gtsam.symbol_shorthand.X, gtsam.symbol_shorthand.L
    isam = gtsam.ISAM2(gtsam.ISAM2Params())
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-3] * 3 + [0.1] * 3))
    seen = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.01, 0.01, 0.1]))
    step = gtsam.Pose3(gtsam.Rot3.Yaw(0.001), gtsam.Point3(1.0, 0.0, 0.0))
    pose = gtsam.Pose3()
    for k in range(poses):
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        if k == 0:
            graph.add(gtsam.PriorFactorPose3(X(0), pose, noise))
        else:
            pose = pose.compose(step)
            graph.add(gtsam.BetweenFactorPose3(X(k - 1), X(k), step, noise))
        values.insert(X(k), pose)
        j = k // 50
        if k % 50 < 3:  # landmark j, 5 m to the left of where pose 50 j was, seen three times
            point = gtsam.Point3(50.0 * j, 5.0, 0.0)
            if k % 50 == 0:
                values.insert(L(j), point)
            body = pose.transformTo(point)
            bearing = gtsam.Unit3(body)
            graph.add(gtsam.BearingRangeFactor3D(X(k), L(j), bearing, np.linalg.norm(body), seen))
        isam.update(graph, values)
    last, recent, old = X(poses - 1), L((poses - 1) // 50), L(0)
    return {
        "marginal of the oldest landmark": timed_ms(lambda: isam.marginalCovariance(old)),
        "joint: newest pose, newest landmark": timed_ms(
            lambda: isam.jointMarginalCovariance([last, recent])
        ),
        "joint: newest pose, oldest landmark": timed_ms(
            lambda: isam.jointMarginalCovariance([last, old])
        ),
        "joint: the two oldest landmarks": timed_ms(
            lambda: isam.jointMarginalCovariance([old, L(1)])
        ),
    }


@dataclass(frozen=True)
class TreeShape:
    """A Bayes tree's shape: how many cliques, the frontal variables of its largest root and
    of its largest clique, and each variable's depth (its clique's distance from a root)."""

    cliques: int
    root_frontals: int
    largest_frontals: int
    depth: dict[str, int]  # variable name ("x12", "l3") -> depth of the clique it is frontal in


_NODE = re.compile(r'^(\d+)\[label="([^"]*)"\];$')
_EDGE = re.compile(r"^(\d+)->(\d+)$")


def tree_shape(dot: str) -> TreeShape:
    """The shape of a Bayes tree from GTSAM's `saveGraph` text: a node per clique labelled
    "frontals : separator" (a root has no separator), an edge from each parent to its child."""
    frontals: dict[str, list[str]] = {}
    parent: dict[str, str] = {}
    for line in dot.splitlines():
        line = line.strip()
        if node := _NODE.match(line):
            names = node.group(2).split(":")[0]
            frontals[node.group(1)] = [n.strip() for n in names.split(",") if n.strip()]
        elif edge := _EDGE.match(line):
            parent[edge.group(2)] = edge.group(1)
    depths: dict[str, int] = {}
    for clique in frontals:  # each walk stops at a clique already measured
        path = []
        while clique not in depths and clique in parent:
            path.append(clique)
            clique = parent[clique]
        depth = depths.setdefault(clique, 0)
        for below in reversed(path):
            depth += 1
            depths[below] = depth
    roots = [c for c in frontals if c not in parent]
    return TreeShape(
        cliques=len(frontals),
        root_frontals=max((len(frontals[c]) for c in roots), default=0),
        largest_frontals=max((len(f) for f in frontals.values()), default=0),
        depth={name: depths[c] for c, names in frontals.items() for name in names},
    )


def bayes_tree_shape(isam: gtsam.ISAM2) -> TreeShape:
    """`tree_shape` of an iSAM2's Bayes tree (written by GTSAM to a file, read back)."""
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "tree.dot"
        isam.saveGraph(str(path))
        return tree_shape(path.read_text())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--poses", type=int, default=20_000)
    parser.add_argument("--every", type=int, default=2_500)
    parser.add_argument("--joint-poses", type=int, default=5_000)
    args = parser.parse_args(argv)
    version = library_versions()["gtsam"]
    print(f"\n== GTSAM {version} iSAM2 alone, a bare Pose3 chain: ms per update")
    rows = chain_update_ms(args.poses, args.every)
    first = rows[0][1]
    print(f"{'poses':>8}{'ms/update':>11}{'x first':>9}")
    for poses, ms in rows:
        print(f"{poses:>8}{ms:>11.3f}{ms / first:>9.1f}")
    print(f"\n== GTSAM {version} marginals on a {args.joint_poses:,}-pose chain: ms a query")
    print(f"  {'':<40}{'first':>9}{'again':>9}")
    for what, (first_ms, again_ms) in joint_marginal_ms(args.joint_poses).items():
        print(f"  {what:<40}{first_ms:>9.3f}{again_ms:>9.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
