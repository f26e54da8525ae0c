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
