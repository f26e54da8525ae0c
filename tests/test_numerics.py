"""The test helpers of tests/numerics.py: numerical Jacobians and perturbed inputs."""

import dataclasses
import math

import gtsam
import numpy as np
import pytest

from pipeline.backend.planar import is_planar
from pipeline.log import (
    Detection,
    Detections,
    GroundTruthPose,
    LogMetadata,
    LogWriter,
    Odometry,
    RelativePose,
    read_log,
)
from tests.numerics import numerical_jacobian, perturbed
from tests.synthetic import Scene, square_loop, write_scene

RELATIVE = 1e-9
# A relative change drawn as 1e-9 N(0, 1) stays below 6e-9 in a few thousand draws (the
# chance of one beyond 6 sigma is 2e-9 a draw); round-off adds 1e-16.
BOUND = 6 * RELATIVE


def relative_change(new, old) -> np.ndarray:
    new, old = np.asarray(new, dtype=float), np.asarray(old, dtype=float)
    nonzero = old != 0.0
    return (new[nonzero] - old[nonzero]) / old[nonzero]


def test_numerical_jacobian_of_a_linear_map_is_the_map():
    A = np.array([[1.0, 2.0, -1.0], [0.5, 0.0, 3.0]])
    J = numerical_jacobian(lambda x: A @ x, np.array([0.3, -0.2, 1.0]))
    # central differences are exact for a linear map up to round-off (1e-16 / 1e-6 step)
    np.testing.assert_allclose(J, A, atol=1e-9)


def test_an_array_moves_by_the_relative_size_asked():
    values = np.linspace(-50.0, 50.0, 4001)
    moved = perturbed(values, RELATIVE, seed=1)
    change = relative_change(moved, values) / RELATIVE
    assert np.max(np.abs(change)) < BOUND / RELATIVE
    # 4000 draws of N(0, 1): their spread is 1 within 5 % (the standard error is 1.1 %)
    assert np.std(change) == pytest.approx(1.0, rel=0.05)
    assert abs(np.mean(change)) < 0.1
    # 0 times anything is exactly 0 in IEEE arithmetic: a zero stays a zero on any machine
    assert not np.any(moved[values == 0.0])


def test_a_seed_gives_one_perturbation_and_another_seed_another():
    values = np.array([1.0, 2.0, 3.0])
    again = perturbed(values, RELATIVE, seed=4)
    # the same draw the same way: alike to round-off; another draw differs by ~1e-9
    np.testing.assert_allclose(perturbed(values, RELATIVE, seed=4), again, rtol=1e-15, atol=0)
    assert np.max(np.abs(relative_change(perturbed(values, RELATIVE, seed=5), again))) > 1e-11
    with pytest.raises(TypeError):
        perturbed(values, RELATIVE)  # no seed: which draw would be left to chance


def test_a_log_needs_somewhere_to_go(tmp_path):
    log = write_scene(tmp_path / "a.mcap", small_scene())
    with pytest.raises(ValueError, match="out"):
        perturbed(log, RELATIVE, seed=0)


def small_scene() -> Scene:
    landmarks = np.array([[4.0, 3.0, 0.5], [6.0, -3.0, -0.5], [9.0, 1.0, 1.0]])
    return Scene(square_loop(8.0, 1.0, laps=0.5), landmarks, np.array([0, 1, 0]))


def assert_positive_definite_and_near(new, old) -> None:
    new = np.reshape(new, (math.isqrt(len(new)),) * 2)
    old = np.reshape(old, new.shape)
    np.testing.assert_allclose(new, new.T, rtol=1e-15, atol=0)  # symmetric to round-off
    np.linalg.cholesky(new)  # raises where not positive definite
    # D C D moves an entry by (1 + e_i)(1 + e_j): twice the bound at most
    assert np.max(np.abs(relative_change(new, old))) < 2 * BOUND


def test_a_log_keeps_its_structure_and_moves_its_continuous_inputs(tmp_path):
    source = write_scene(tmp_path / "scene.mcap", small_scene(), seed=2)
    out = perturbed(source, RELATIVE, seed=3, out=tmp_path / "moved.mcap")
    before, after = read_log(source), read_log(out)
    assert after.metadata == before.metadata
    assert [(o.stamp_ns, o.from_index, o.to_index) for o in after.odometry] == [
        (o.stamp_ns, o.from_index, o.to_index) for o in before.odometry
    ]
    assert after.ground_truth_poses == before.ground_truth_poses  # copied, not computed
    assert after.ground_truth_landmarks == before.ground_truth_landmarks
    changes = []
    for new, old in zip(after.odometry, before.odometry, strict=True):
        changes += [*relative_change(new.translation, old.translation)]
        assert np.linalg.norm(new.rotation) == pytest.approx(1.0, abs=1e-15)
        # a unit quaternion moved by 1e-9 and re-normalised: each component within 2e-8
        np.testing.assert_allclose(new.rotation, old.rotation, atol=4 * BOUND)
        assert_positive_definite_and_near(new.covariance, old.covariance)
    assert len(after.detections) == len(before.detections)
    for new_msg, old_msg in zip(after.detections, before.detections, strict=True):
        assert (new_msg.stamp_ns, new_msg.pose_index) == (old_msg.stamp_ns, old_msg.pose_index)
        assert len(new_msg.detections) == len(old_msg.detections)
        for new, old in zip(new_msg.detections, old_msg.detections, strict=True):
            assert (new.class_id, new.truth_landmark_id, new.source) == (
                old.class_id,
                old.truth_landmark_id,
                old.source,
            )
            vector = [new.bearing, new.elevation, new.range]
            changes += [*relative_change(vector, [old.bearing, old.elevation, old.range])]
            assert_positive_definite_and_near(new.covariance, old.covariance)
    changes = np.array(changes) / RELATIVE
    assert np.max(np.abs(changes)) < BOUND / RELATIVE
    # every input moved (none left as it was), and by draws of spread ~1
    assert np.min(np.abs(changes)) > 0.0
    assert 0.7 < np.std(changes) < 1.3


def test_a_planar_log_stays_planar(tmp_path):
    scene = small_scene()
    scene.landmarks[:, 2] = 0.0  # every landmark in the robot's plane: elevation 0
    source = write_scene(tmp_path / "flat.mcap", scene, odom_noise=0.0, meas_noise=0.0)
    assert is_planar(read_log(source))
    out = perturbed(source, RELATIVE, seed=0, out=tmp_path / "moved.mcap")
    assert is_planar(read_log(out))


def tag_log(path, bearing: float):
    """Two poses, one tag seen from each, with a relative pose; the second at `bearing`."""
    metadata = LogMetadata(2, ((1.0, 0.0), (0.0, 1.0)), ("a", "b"), "tests")
    covariance = tuple(np.diag([0.01, 0.02, 0.03, 1e-4, 2e-4, 3e-4]).ravel())
    q = (0.1, -0.2, 0.3, math.sqrt(1 - 0.14))
    tag = RelativePose((2.0, 0.5, 0.1), q, covariance)
    detection = Detection(
        class_id=1, score=1.0, bearing=0.2, elevation=0.05, range=2.07,
        covariance=tuple(np.diag([1e-4, 1e-4, 1e-2]).ravel()), source="apriltag",
        bbox=(10.0, 20.0, 30.0, 40.0), relative_pose=tag, truth_landmark_id=7,
    )  # fmt: skip
    with LogWriter(path, metadata) as writer:
        writer.write(GroundTruthPose(0, 0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)))
        writer.write(Detections(0, 0, (detection,)))
        writer.write(Odometry(10, 0, 1, (1.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0), covariance))
        writer.write(GroundTruthPose(10, 1, (1.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)))
        writer.write(Detections(10, 1, (dataclasses.replace(detection, bearing=bearing),)))
    return path


def test_a_tag_s_relative_pose_moves_too_and_a_bearing_of_pi_stays_valid(tmp_path):
    source = tag_log(tmp_path / "tags.mcap", bearing=math.pi)
    bearings = []
    for seed in range(6):
        out = perturbed(source, RELATIVE, seed=seed, out=tmp_path / f"moved{seed}.mcap")
        before, after = read_log(source), read_log(out)  # the reader refuses |bearing| > pi
        bearings.append(after.detections[1].detections[0].bearing)
        for new_msg, old_msg in zip(after.detections, before.detections, strict=True):
            new, old = new_msg.detections[0], old_msg.detections[0]
            assert (new.score, new.bbox) == (old.score, old.bbox)  # copied
            rp, old_rp = new.relative_pose, old.relative_pose
            change = relative_change(rp.translation, old_rp.translation)
            assert 0.0 < np.max(np.abs(change)) < BOUND
            assert np.linalg.norm(rp.rotation) == pytest.approx(1.0, abs=1e-15)
            assert_positive_definite_and_near(rp.covariance, old_rp.covariance)
            # the rotation moved by about 1e-9 rad, no more
            R_new = gtsam.Rot3.Quaternion(rp.rotation[3], *rp.rotation[:3])
            R_old = gtsam.Rot3.Quaternion(old_rp.rotation[3], *old_rp.rotation[:3])
            angle = np.linalg.norm(gtsam.Rot3.Logmap(R_old.between(R_new)))
            assert 0.0 < angle < 4 * BOUND
    # some draws pushed the bearing outwards (held at pi, a value set), some inwards
    assert max(bearings) == math.pi and min(bearings) < math.pi
