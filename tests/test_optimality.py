"""The batch optimum a replay's final estimate is checked against (`data_tools/optimality.py`)."""

from __future__ import annotations

import dataclasses
import math

import gtsam
import numpy as np
from gtsam.symbol_shorthand import X

from data_tools.optimality import check_optimality, main
from pipeline.backend.solver import Isam2Solver
from pipeline.config import load_config
from tests.synthetic import small_square_log

STEP = gtsam.Pose3(gtsam.Rot3.Yaw(1.2), np.array([2.0, 1.0, 0.0]))
# The loop's measurement disagrees with the two steps by 0.3 rad and 1 m: the optimum spreads it.
LOOP = STEP.compose(STEP).compose(gtsam.Pose3(gtsam.Rot3.Yaw(0.3), np.array([1.0, 0.0, 0.0])))


def gradient_norm(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> float:
    gradient = graph.linearize(values).gradientAtZero()
    return float(gradient.norm())


def test_the_optimum_solves_the_graph_where_isam2_stopped_short():
    """A loop of two 1.2 rad steps started with no rotation at all, relinearisation switched
    off: iSAM2's one Gauss-Newton step is far from the optimum; the batch optimum is a
    stationary point of the graph, and iSAM2 itself is left as it was."""
    config = dataclasses.replace(
        load_config().isam2, per_type_thresholds=False, relinearize_threshold=1e6
    )
    solver = Isam2Solver(config)
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.05] * 3 + [0.2] * 3))
    factors = [
        gtsam.PriorFactorPose3(X(0), gtsam.Pose3(), noise),
        gtsam.BetweenFactorPose3(X(0), X(1), STEP, noise),
        gtsam.BetweenFactorPose3(X(1), X(2), STEP, noise),
        gtsam.BetweenFactorPose3(X(0), X(2), LOOP, noise),
    ]
    for factor in factors:
        solver.add(factor)
    for i in range(3):
        solver.insert(X(i), gtsam.Pose3(gtsam.Rot3(), np.array([2.0 * i, 0.0, 0.0])))
    solver.update()
    estimate = solver.estimate()

    cost, optimum_cost, optimum = solver.batch_optimum()

    graph = gtsam.NonlinearFactorGraph()
    for factor in factors:
        graph.add(factor)
    assert math.isclose(cost, graph.error(estimate), rel_tol=1e-12)
    assert math.isclose(optimum_cost, graph.error(optimum), rel_tol=1e-12)
    assert optimum_cost < 0.5 * cost  # one linearised step missed by far
    assert gradient_norm(graph, optimum) < 1e-4 * gradient_norm(graph, estimate)
    assert solver.estimate().equals(estimate, 1e-12)


def test_a_replay_s_estimate_and_its_optimum_are_compared(tmp_path):
    log = small_square_log(tmp_path / "square.mcap")
    result = check_optimality(log, "known", load_config())

    assert result.poses == 13
    assert 0.0 <= result.optimum_cost <= result.cost * (1 + 1e-9) + 1e-9
    assert math.isfinite(result.rmse_m) and math.isfinite(result.optimum_rmse_m)
    assert result.largest_move_m >= 0.0


def test_the_command_prints_a_row_per_log_and_method(tmp_path, capsys):
    log = small_square_log(tmp_path / "square.mcap")
    assert main([str(log), "--methods", "known,mm-nh"]) == 0
    rows = capsys.readouterr().out.strip().splitlines()
    assert [row.split()[1] for row in rows[1:]] == ["known", "mm-nh"]


def test_a_missing_log_is_one_line_and_status_2(tmp_path, capsys):
    assert main([str(tmp_path / "none.mcap")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "none.mcap" in err[0]


def test_the_estimate_carries_the_back_substitution_through_the_whole_tree():
    """A chain pulled at its end by 5 cm: each earlier pose moves by less than the wildfire
    threshold, so iSAM2's own estimate leaves them where they were, while the solver's is the
    solution without the threshold (an iSAM2 with none, the same updates)."""
    config = load_config().isam2
    complete = dataclasses.replace(config, wildfire_threshold=0.0)
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.01] * 3 + [0.05] * 3))
    step = gtsam.Pose3(gtsam.Rot3(), np.array([1.0, 0.0, 0.0]))
    solvers = Isam2Solver(config), Isam2Solver(complete)
    for solver in solvers:
        solver.add(gtsam.PriorFactorPose3(X(0), gtsam.Pose3(), noise))
        solver.insert(X(0), gtsam.Pose3())
        solver.update()
        for i in range(1, 40):
            solver.add(gtsam.BetweenFactorPose3(X(i - 1), X(i), step, noise))
            solver.insert(X(i), gtsam.Pose3(gtsam.Rot3(), np.array([float(i), 0.0, 0.0])))
            solver.update()
        pull = gtsam.noiseModel.Isotropic.Sigma(3, 0.05)
        solver.add(gtsam.GPSFactor(X(39), np.array([39.0, 0.1, 0.0]), pull))
        solver.update()
    thresholded, unthresholded = solvers

    def path(values: gtsam.Values) -> np.ndarray:
        return np.array([values.atPose3(X(i)).translation() for i in range(40)])

    truncated = path(thresholded.isam.calculateEstimate())
    solution = path(unthresholded.isam.calculateEstimate())
    assert np.max(np.abs(truncated - solution)) > 1e-3  # the threshold did stop it
    np.testing.assert_allclose(path(thresholded.estimate()), solution, atol=1e-9)
