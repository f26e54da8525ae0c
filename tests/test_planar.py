"""Planar logs: told from others, and their plane stated as priors that keep GTSAM's Cholesky
from refusing a long planar drive."""

import dataclasses

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import X

from data_tools.scenarios import simulate
from pipeline.backend.planar import is_planar, planar_prior_factors, uses_plane
from pipeline.backend.solver import Isam2Solver
from pipeline.config import load_config
from pipeline.log import read_log


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("planar")
    short = folder / "route.toml"
    short.write_text("[route]\nlength_m = 60.0\n")
    out = {}
    for scenario in ("planar-park", "indoor-tags"):
        out[scenario] = folder / f"{scenario}.mcap"
        simulate(scenario, out[scenario], seed=1, config_path=short, foxglove=False)
    return {name: read_log(path) for name, path in out.items()}


def test_a_planar_log_is_told_from_a_3d_one(logs):
    assert is_planar(logs["planar-park"])
    assert not is_planar(logs["indoor-tags"])  # tags above the camera, a floor's small tilts
    log = logs["planar-park"]
    message = next(m for m in log.detections if m.detections)
    tilted = dataclasses.replace(message.detections[0], elevation=1e-6)
    detections = [
        dataclasses.replace(m, detections=(tilted, *m.detections[1:])) if m is message else m
        for m in log.detections
    ]
    assert not is_planar(dataclasses.replace(log, detections=detections))
    assert uses_plane("auto", log) and uses_plane("always", logs["indoor-tags"])
    assert not uses_plane("never", log) and not uses_plane("auto", logs["indoor-tags"])


def with_step(log, index: int, translation=None, rotation=None):
    """`log` with odometry step `index` moved (everything else as it was)."""
    step = log.odometry[index]
    moved = dataclasses.replace(
        step,
        translation=translation if translation is not None else step.translation,
        rotation=rotation if rotation is not None else step.rotation,
    )
    index %= len(log.odometry)
    odometry = [moved if k == index else s for k, s in enumerate(log.odometry)]
    return dataclasses.replace(log, odometry=odometry)


def with_part(q, axis: int, value: float) -> tuple:
    """`q` ([x, y, z, w]) with its part `axis` (0: x, roll; 1: y, pitch) set to `value`,
    normalised again."""
    q = np.array(q, dtype=float)
    q[axis] = value
    return tuple(q / np.linalg.norm(q))


@pytest.mark.parametrize("index", [0, 7, -1])
def test_one_step_off_the_plane_makes_a_log_not_planar(logs, index):
    """Every detection stays at elevation 0: the odometry alone decides."""
    log = logs["planar-park"]
    step = log.odometry[index]
    x, y, _ = step.translation
    assert not is_planar(with_step(log, index, translation=(x, y, 1e-6)))
    for axis in (0, 1):  # roll, pitch
        assert not is_planar(with_step(log, index, rotation=with_part(step.rotation, axis, 1e-6)))
        assert is_planar(with_step(log, index, rotation=with_part(step.rotation, axis, 1e-17)))
    yaw = 0.3  # a turn about z keeps it planar
    assert is_planar(with_step(log, index, rotation=(0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2))))
    assert is_planar(with_step(log, index, translation=(x, y, 1e-17)))
    assert not is_planar(dataclasses.replace(log, odometry=[]))


def test_the_planes_priors_weigh_height_and_tilt_alone():
    height, tilt = planar_prior_factors(X(0), 0.01, 0.001)
    values = gtsam.Values()
    # heading and position in the plane cost nothing
    values.insert(X(0), gtsam.Pose3(gtsam.Rot3.Yaw(2.5), np.array([30.0, -40.0, 0.0])))
    assert height.error(values) == pytest.approx(0.0, abs=1e-20)
    assert tilt.error(values) == pytest.approx(0.0, abs=1e-20)
    values.update(X(0), gtsam.Pose3(gtsam.Rot3.Ypr(2.5, 0.0, 0.002), np.array([3.0, 4.0, 0.02])))
    assert height.error(values) == pytest.approx(0.5 * (0.02 / 0.01) ** 2, rel=1e-9)
    assert tilt.error(values) == pytest.approx(0.5 * (0.002 / 0.001) ** 2, rel=1e-3)


def drive_straight(planar: bool, poses: int = 1000) -> Isam2Solver:
    """A straight drive of `poses` half-metre steps, odometry alone, each step stating 1 mm and
    1 mrad in height, roll and pitch (a planar robot's), with or without the plane's priors."""
    solver = Isam2Solver(load_config().isam2)
    sigmas = np.array([1e-3, 1e-3, 2e-3, 1e-2, 1e-2, 1e-3])
    noise = gtsam.noiseModel.Diagonal.Sigmas(sigmas)
    solver.add(
        gtsam.PriorFactorPose3(X(0), gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, 1e-6))
    )
    solver.insert(X(0), gtsam.Pose3())
    step = gtsam.Pose3(gtsam.Rot3(), np.array([0.5, 0.0, 0.0]))
    for i in range(1, poses):
        solver.add(gtsam.BetweenFactorPose3(X(i - 1), X(i), step, noise))
        if planar:
            for factor in planar_prior_factors(X(i), 0.01, 0.001):
                solver.add(factor)
        solver.insert(X(i), gtsam.Pose3(gtsam.Rot3(), np.array([0.5 * i, 0.0, 0.0])))
        solver.update()
    return solver


@pytest.mark.slow
def test_a_long_planar_drive_is_refused_by_cholesky_unless_the_plane_is_stated():
    """Pitch's random walk, integrated along the drive, leaves the newest pose's height some
    4096 times less certain than a step says after about 590 steps: GTSAM's Cholesky refuses a
    pivot that lost more than 2^24 of its diagonal. With the plane stated, none."""
    unbounded = drive_straight(planar=False)
    assert unbounded.fallbacks and 500 < unbounded.fallbacks[0].update < 700
    bounded = drive_straight(planar=True)
    assert bounded.fallbacks == []
    height = np.sqrt(bounded.marginal_covariance(X(999))[5, 5])
    assert height < 0.01


def test_cholesky_refuses_a_pivot_that_lost_24_bits_of_its_diagonal():
    """What GTSAM 4.3's Cholesky calls an indeterminate system, on a 2x2 information matrix:
    the second pivot, c - b^2 / a, below 2^-24 of c. Every refusal the back-end met was this."""

    def refused(pivot_share: float) -> bool:
        b = np.sqrt(1.0 - pivot_share)
        graph = gtsam.GaussianFactorGraph()
        graph.add(gtsam.HessianFactor(0, np.array([[1.0, b], [b, 1.0]]), np.zeros(2), 0.0))
        ordering = gtsam.Ordering()
        ordering.push_back(0)
        try:
            graph.eliminateMultifrontal(ordering)
        except RuntimeError as exc:
            assert "Indeterminate linear system" in str(exc)  # and no other refusal
            return True
        return False

    assert not refused(2.0**-23.9)
    assert refused(2.0**-24.1)
