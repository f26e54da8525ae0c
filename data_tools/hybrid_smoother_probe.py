"""Why there is no `--method hybrid`: GTSAM's `HybridSmoother` (a pruned hybrid Bayes net, at
most N leaves) timed on a log's association problem, keyframe by keyframe.

    python -m data_tools.hybrid_smoother_probe LOG.mcap [--max-leaves N] [--poses N]

The problem is the one `--method dcsam` solved on the log: its detections' hypotheses (their
candidates and their own landmark; the null left out, so every mode has a factor) and its
final estimate as the linearisation point, which is the smoother's best case: it linearises
once, where the answer already is (it has no incremental relinearisation, `relinearize()`
eliminates everything again), and the candidates need no gate (it gives no marginals).
Prints the time of every 50th update, the total, and dcsam's own replay time on the log.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence

# Modes other than a hybrid factor's own weigh this little (GTSAM 4.3 wants every component of
# a HybridNonlinearFactor on the same variables).
NO_PULL = 1e-12


def main(argv: Sequence[str] | None = None) -> int:
    import gtsam
    from gtsam.symbol_shorthand import L, X

    from pipeline.backend.factors import odometry_factor
    from pipeline.backend.methods.dcsam.method import HybridRecord
    from pipeline.config import load_config
    from pipeline.log import read_log
    from pipeline.replay import keyframes, new_backend

    parser = argparse.ArgumentParser(prog="python -m data_tools.hybrid_smoother_probe")
    parser.add_argument("log")
    parser.add_argument("--max-leaves", type=int, default=10, help="the smoother's pruning")
    parser.add_argument("--poses", type=int, default=None, help="only the first N keyframes")
    args = parser.parse_args(argv)

    log = read_log(args.log)
    start = time.perf_counter()
    backend = new_backend(log, "dcsam", load_config())
    for odometry, detections in keyframes(log):
        backend.add_keyframe(odometry, detections)
    backend.result()
    dcsam_s = time.perf_counter() - start
    estimate = backend.solver.estimate()
    by_pose: dict[int, list] = {}
    for record in backend.records:
        by_pose.setdefault(record.measurement.pose_index, []).append(record)

    smoother = gtsam.HybridSmoother(0.99)
    values = gtsam.Values()  # the smoother wants every variable's value at every update
    anchor = gtsam.noiseModel.Isotropic.Sigma(3, load_config().landmarks.anchor_sigma_m)
    hybrid = 0
    start = time.perf_counter()
    poses = log.num_poses if args.poses is None else min(args.poses, log.num_poses)
    for i in range(poses):
        graph = gtsam.HybridNonlinearFactorGraph()
        if i == 0:
            noise = gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)
            graph.push_back(gtsam.PriorFactorPose3(X(0), gtsam.Pose3(), noise))
        else:
            graph.push_back(odometry_factor(X(i - 1), X(i), log.odometry[i - 1]))
        values.insert(X(i), estimate.atPose3(X(i)))
        for record in by_pose.get(i, []):
            m = record.measurement
            for j in record.landmark_ids:
                if not values.exists(L(j)):
                    values.insert(L(j), estimate.atPoint3(L(j)))
                    graph.push_back(gtsam.PriorFactorPoint3(L(j), values.atPoint3(L(j)), anchor))
            if not isinstance(record, HybridRecord):
                graph.push_back(m.factor(X(i), L(record.landmark_ids[0])))
                continue
            key = (gtsam.symbol("m", hybrid), len(record.landmark_ids))
            hybrid += 1
            for h, j in enumerate(record.landmark_ids):
                components = [
                    (m.factor(X(i), L(j), 1.0 if mode == h else NO_PULL), 0.0)
                    for mode in range(len(record.landmark_ids))
                ]
                components[h] = (components[h][0], float(record.constants[h]))
                graph.push_back(gtsam.HybridNonlinearFactor(key, components))
        update = time.perf_counter()
        smoother.update(graph, values, args.max_leaves)
        if i % 50 == 0 or i == poses - 1:
            print(
                f"pose {i}: {hybrid} hybrid factors, update {time.perf_counter() - update:.3f} s,"
                f" total {time.perf_counter() - start:.1f} s",
                flush=True,
            )
    smoother.optimize()
    print(
        f"HybridSmoother (max {args.max_leaves} leaves): {time.perf_counter() - start:.1f} s for "
        f"{poses} keyframes; dcsam's whole replay: {dcsam_s:.1f} s"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
