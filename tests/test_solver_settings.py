"""What the solver hands iSAM2 and the rest of the back-end (`backend/solver.py`), checked by
what they do: the per-direction relinearisation thresholds, the movement thresholds, the
landmark an odometry-only update re-eliminates, the estimate carried through the whole tree,
and a variable whose every factor was removed left out of a fresh solve."""

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import L, X

from pipeline.backend import solver as solver_module
from pipeline.backend.solver import Isam2Solver, movement_thresholds
from pipeline.config import load_config
from tests.backend_cases import with_settings

TIGHT = gtsam.noiseModel.Isotropic.Sigma(6, 1e-3)


def isam2_config(**values):
    return with_settings(load_config(), isam2=values).isam2


@pytest.mark.parametrize(
    ("start", "relinearised"),
    [
        # 1 m off in translation: under the 5 m translation threshold, over the rotation's
        (gtsam.Pose3(gtsam.Rot3(), np.array([1.0, 0.0, 0.0])), False),
        # 0.2 rad off in yaw: over the 0.05 rad rotation threshold
        (gtsam.Pose3(gtsam.Rot3.Yaw(0.2), np.zeros(3)), True),
    ],
)
def test_a_pose_is_relinearised_by_its_rotation_and_translation_thresholds(start, relinearised):
    config = isam2_config(
        per_type_thresholds=True,
        pose_rotation_threshold_rad=0.05,
        pose_translation_threshold_m=5.0,
        relinearize_skip=1,
        partial_relinearization_check=False,
    )
    solver = Isam2Solver(config)
    solver.add(gtsam.PriorFactorPose3(X(0), gtsam.Pose3(), TIGHT))
    solver.insert(X(0), start)
    solver.update()  # linearised at `start`: its step is the whole offset
    marked = solver.update()  # nothing new: only a relinearisation marks X(0)
    assert (X(0) in marked) == relinearised


def test_movement_thresholds_are_the_rotation_translation_and_landmark_ones():
    config = isam2_config(
        per_type_thresholds=True,
        pose_rotation_threshold_rad=0.01,
        pose_translation_threshold_m=0.2,
        landmark_threshold_m=0.3,
    )
    thresholds = movement_thresholds(config)
    assert thresholds.pose_rotation == pytest.approx(0.01)
    assert thresholds.pose_translation == pytest.approx(0.2)
    assert thresholds.landmark == pytest.approx(0.3)


def test_an_odometry_update_re_eliminates_the_newest_landmark_of_the_last(monkeypatch):
    roots = []
    real = solver_module.landmarks_last

    def spy(graph, root=None, max_last=None):
        roots.append(root)
        return real(graph, root, max_last)

    monkeypatch.setattr(solver_module, "landmarks_last", spy)
    solver = Isam2Solver(load_config().isam2)
    solver.add(gtsam.PriorFactorPose3(X(0), gtsam.Pose3(), TIGHT))
    solver.insert(X(0), gtsam.Pose3())
    seen = gtsam.noiseModel.Isotropic.Sigma(3, 0.3)
    for j in (4, 2, 7, 5):  # in one update, the newest (7) not the last added
        point = np.array([2.0, float(j), 0.0])
        unit = gtsam.Unit3(point)
        solver.add(gtsam.BearingRangeFactor3D(X(0), L(j), unit, float(np.linalg.norm(point)), seen))
        solver.insert(L(j), point)
    solver.update()
    step = gtsam.Pose3(gtsam.Rot3(), np.array([1.0, 0.0, 0.0]))
    solver.add(gtsam.BetweenFactorPose3(X(0), X(1), step, TIGHT))
    solver.insert(X(1), step)
    solver.update()
    assert roots == [None, L(7)]
    assert solver.fallbacks == []


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_estimate_is_carried_through_the_whole_tree(seed):
    """A chain of poses, then a prior on the last that moves every pose a little, under a
    wildfire threshold (5 cm) that stops iSAM2's back-substitution early: the estimate is
    still the whole step from iSAM2's linearisation point (the graph linearised there and
    solved outright), which the stopped one is not."""
    rng = np.random.default_rng(seed)
    config = isam2_config(wildfire_threshold=0.05, relinearize_skip=1)
    solver = Isam2Solver(config)
    graph = gtsam.NonlinearFactorGraph()

    def add(factor):
        solver.add(factor)
        graph.add(factor)

    odometry = gtsam.noiseModel.Isotropic.Sigma(6, 0.05)
    add(gtsam.PriorFactorPose3(X(0), gtsam.Pose3(), TIGHT))
    pose = gtsam.Pose3()
    solver.insert(X(0), pose)
    for k in range(1, 12):
        step = gtsam.Pose3(gtsam.Rot3.Yaw(0.3), np.array([1.0, 0.0, 0.0]))
        add(gtsam.BetweenFactorPose3(X(k - 1), X(k), step, odometry))
        pose = pose.compose(step)
        solver.insert(X(k), pose)
        solver.update()
    shift = gtsam.Pose3(gtsam.Rot3.Yaw(0.02), np.r_[0.15, 0.1, 0.0] + 0.02 * rng.normal(size=3))
    add(gtsam.PriorFactorPose3(X(11), pose.compose(shift), TIGHT))
    solver.update()
    point = solver.isam.getLinearizationPoint()
    optimum = point.retract(graph.linearize(point).optimize())
    stopped = solver.isam.calculateEstimate()
    estimate = solver.estimate()

    def worst(a: gtsam.Values) -> float:
        return max(
            float(
                np.max(np.abs(a.atPose3(X(k)).translation() - optimum.atPose3(X(k)).translation()))
            )
            for k in range(12)
        )

    assert worst(stopped) > 1e-3  # the wildfire threshold did stop it
    assert worst(estimate) < 1e-6


def test_a_fresh_solve_leaves_out_a_variable_whose_factors_were_all_removed():
    solver = Isam2Solver(load_config().isam2)
    solver.add(gtsam.PriorFactorPose3(X(0), gtsam.Pose3(), TIGHT))
    solver.insert(X(0), gtsam.Pose3())
    seen = gtsam.noiseModel.Isotropic.Sigma(3, 0.1)
    point = np.array([2.0, 1.0, 0.0])
    sighting = solver.add(
        gtsam.BearingRangeFactor3D(
            X(0), L(0), gtsam.Unit3(point), float(np.linalg.norm(point)), seen
        )
    )
    prior = solver.add(gtsam.PriorFactorPoint3(L(0), point, seen))
    solver.insert(L(0), point)
    solver.update()
    solver.remove(sighting)
    solver.remove(prior)
    solver.add(gtsam.BetweenFactorPose3(X(0), X(1), gtsam.Pose3(), TIGHT))
    solver.insert(X(1), gtsam.Pose3())
    moved = solver.update(anew=True)
    assert solver.fallbacks == [] and solver.factorization == "CHOLESKY"
    assert L(0) not in moved
    assert not solver.estimate().exists(L(0))
    np.testing.assert_allclose(solver.pose(X(1)).translation(), np.zeros(3), atol=1e-6)
