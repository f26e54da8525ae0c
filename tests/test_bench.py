"""`make bench`'s profile summary: where a replay's time goes, split by who spends it."""

from __future__ import annotations

import cProfile
import pstats

import gtsam
import numpy as np
import pytest

from data_tools.bench import time_shares


def busy_python(n: int) -> int:
    total = 0
    for i in range(n):
        total += i * i
    return total


def work() -> None:
    isam = gtsam.ISAM2()
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    noise = gtsam.noiseModel.Isotropic.Sigma(6, 0.1)
    graph.add(gtsam.PriorFactorPose3(0, gtsam.Pose3(), noise))
    values.insert(0, gtsam.Pose3())
    for k in range(1, 200):
        graph.add(gtsam.BetweenFactorPose3(k - 1, k, gtsam.Pose3(), noise))
        values.insert(k, gtsam.Pose3())
    isam.update(graph, values)
    np.linalg.eigh(np.eye(200))
    busy_python(1_000_000)


def test_every_profiled_second_is_counted_once_and_each_kind_is_seen():
    profiler = cProfile.Profile()
    profiler.runcall(work)
    stats = pstats.Stats(profiler)
    shares = time_shares(stats)
    own = sum(v[2] for v in stats.stats.values())  # type: ignore[attr-defined]
    assert sum(shares.values()) == pytest.approx(own, rel=1e-9)
    assert shares["gtsam"] > 0 and shares["numpy"] > 0
    # the Python loop is the longest part of `work` by far, and it is counted as Python
    assert shares["python"] > max(shares["gtsam"], shares["numpy"])


def test_the_isam2_chain_bench_reports_each_stretch_of_the_chain():
    from data_tools.bench_isam2 import chain_update_ms

    rows = chain_update_ms(200, 50)
    assert [poses for poses, _ in rows] == [50, 100, 150, 200]
    assert all(np.isfinite(ms) and ms > 0 for _, ms in rows)


def test_a_bayes_tree_s_shape_is_read_from_gtsam_s_drawing():
    from data_tools.bench_isam2 import tree_shape

    # root {x3, x4}; below it {x2 : x3} and {l0, l1 : x3, x4}; below {x2} the clique {x1 : x2}
    dot = """digraph G{
    1[label="x3, x4"];
    1->2
    2[label="x2 : x3"];
    2->4
    4[label="x1 : x2"];
    1->3
    3[label="l0, l1 : x3, x4"];
    }"""
    shape = tree_shape(dot)
    assert shape.cliques == 4
    assert shape.root_frontals == 2 and shape.largest_frontals == 2
    assert shape.depth == {"x3": 0, "x4": 0, "x2": 1, "l0": 1, "l1": 1, "x1": 2}


def test_an_isam2_chain_s_tree_has_every_pose_once_and_the_newest_in_the_root():
    from data_tools.bench_isam2 import bayes_tree_shape

    isam = gtsam.ISAM2()
    noise = gtsam.noiseModel.Isotropic.Sigma(6, 0.1)
    step = gtsam.Pose3(gtsam.Rot3(), gtsam.Point3(1.0, 0.0, 0.0))
    X = gtsam.symbol_shorthand.X
    for k in range(30):
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        if k == 0:
            graph.add(gtsam.PriorFactorPose3(X(0), gtsam.Pose3(), noise))
        else:
            graph.add(gtsam.BetweenFactorPose3(X(k - 1), X(k), step, noise))
        values.insert(X(k), gtsam.Pose3(gtsam.Rot3(), gtsam.Point3(float(k), 0.0, 0.0)))
        isam.update(graph, values)
    shape = bayes_tree_shape(isam)
    assert sorted(shape.depth) == sorted(f"x{k}" for k in range(30))
    assert shape.depth["x29"] == 0
    # a chain's tree is a path: every clique one deeper than its parent
    assert sorted(set(shape.depth.values())) == list(range(shape.cliques))
