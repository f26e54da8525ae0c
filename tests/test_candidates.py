"""Candidate gating (`candidates.py`) on small states built by hand: the search radius, the
exact chi-square gate in R's metric, the cheap bound before it, and `max_candidates`."""

import dataclasses
import math

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import L, X

from pipeline import geometry
from pipeline.backend import association as assoc
from pipeline.backend.candidates import CandidateScorer, PosePrediction, search_regions
from pipeline.backend.landmarks import LandmarkKind
from pipeline.backend.measurements import make_measurement
from pipeline.config import load_config
from pipeline.geometry import bearing_elevation_range
from pipeline.log.messages import RelativePose
from tests.backend_cases import (
    CONFUSION,
    add_landmark,
    add_pose,
    detection_at,
    detection_of,
    hand_context,
    measurement,
    with_settings,
)
from tests.numerics import numerical_jacobian

SIGMAS = np.array([0.01, 0.005, 0.3])  # bearing, elevation, range


def test_the_search_radius_is_sigmas_of_the_predicted_spread_plus_the_margin():
    # A robot at (1, 2, 0) facing +y (yaw 90 degrees) sees a point straight ahead at 10 m.
    pose = gtsam.Pose3(gtsam.Rot3.Yaw(math.pi / 2), np.array([1.0, 2.0, 0.0]))
    prediction = PosePrediction(1, X(0), pose, np.eye(6), np.zeros((6, 6)))
    m = measurement(1, detection_of(pose, [1.0, 12.0, 0.0], sigmas=SIGMAS))
    # the pose: yaw known to 0.01 rad, its forward translation to 0.2 m
    pose_covariance = np.diag([0.0, 0.0, 0.01**2, 0.2**2, 0.0, 0.0])
    (center,), (radius,) = search_regions(prediction, pose_covariance, [m], sigmas=4.0, margin=3.0)
    np.testing.assert_allclose(center, [1.0, 12.0, 0.0], atol=1e-12)
    # In the world: across the line of sight (x) the bearing's 10 m * 0.01 and the yaw's
    # 10 m * 0.01; along it (y) the range's 0.3 and the translation's 0.2; up, 10 * 0.005.
    # The largest variance is along: 0.09 + 0.04 = 0.13.
    assert radius == pytest.approx(4.0 * math.sqrt(0.13) + 3.0, rel=1e-9)
    # without the pose's uncertainty, across and along are 0.01 and 0.09
    _, (bare,) = search_regions(prediction, np.zeros((6, 6)), [m], sigmas=2.0, margin=0.0)
    assert bare == pytest.approx(2.0 * 0.3, rel=1e-9)


def _tag_measurement(pose_index: int, relative: gtsam.Pose3, index: int = 0):
    """A tag's pose relative to the body (use_relative_pose): a pose landmark's measurement."""
    q = relative.rotation().toQuaternion()
    tag = RelativePose(
        translation=tuple(float(v) for v in relative.translation()),
        rotation=(q.x(), q.y(), q.z(), q.w()),  # the contract's order
        covariance=tuple(np.diag([1e-4, 1e-4, 1e-4, 4e-4, 4e-4, 1e-3]).ravel()),
    )
    z = bearing_elevation_range(relative.translation())
    detection = dataclasses.replace(detection_at(z), source="apriltag", relative_pose=tag)
    return make_measurement(pose_index, index, detection, use_relative_pose=True)


def _add_tag(context, pose: gtsam.Pose3, sigma: float) -> int:
    """A pose landmark at `pose`, held by a prior of `sigma` in every tangent direction."""
    landmark = context.landmarks.create(LandmarkKind.POSE, pose.translation())
    context.solver.insert(L(landmark.id), pose)
    noise = gtsam.noiseModel.Isotropic.Sigma(6, sigma)
    context.solver.add(gtsam.PriorFactorPose3(L(landmark.id), pose, noise))
    return landmark.id


def test_a_keyframe_s_search_regions_are_each_detection_s_own():
    """Stacked over a keyframe's detections of both kinds, each region is the one its
    detection gets alone, which is R p + t and sigmas times the largest spread, worked out
    here one detection at a time."""
    rng = np.random.default_rng(3)
    pose = gtsam.Pose3(gtsam.Rot3.Ypr(0.4, 0.05, -0.02), np.array([3.0, -1.0, 0.2]))
    prediction = PosePrediction(1, X(0), pose, np.eye(6), np.zeros((6, 6)))
    A = rng.normal(size=(6, 6))
    pose_covariance = 1e-3 * A @ A.T
    points = [
        measurement(1, detection_of(pose, p, sigmas=SIGMAS), k)
        for k, p in enumerate(rng.uniform([0, -10, -1], [30, 10, 2], (5, 3)))
    ]
    tags = [
        _tag_measurement(
            1, gtsam.Pose3(gtsam.Rot3.Yaw(0.2 * k), np.array([4.0 + k, k - 1.0, 0.3])), 5 + k
        )
        for k in range(3)
    ]
    keyframe = [points[0], tags[0], *points[1:3], tags[1], *points[3:], tags[2]]
    centers, radii = search_regions(prediction, pose_covariance, keyframe, 4.0, 3.0)
    R, t = pose.rotation().matrix(), pose.translation()
    for m, center, radius in zip(keyframe, centers, radii, strict=True):
        (alone_center,), (alone_radius,) = search_regions(
            prediction, pose_covariance, [m], 4.0, 3.0
        )
        np.testing.assert_allclose(center, alone_center, rtol=0, atol=1e-12)
        assert radius == pytest.approx(alone_radius, rel=1e-12)
        p_body = m.body_point
        J = R @ np.hstack([-geometry.skew(p_body), np.eye(3)])
        if m.relative_rotation is None:
            G = R @ np.linalg.inv(geometry.bearing_elevation_range_jacobian(p_body))
            own = G @ m.covariance @ G.T
        else:
            R_z = R @ m.relative_rotation
            own = R_z @ m.covariance[3:, 3:] @ R_z.T
        spread = math.sqrt(np.linalg.eigvalsh(J @ pose_covariance @ J.T + own)[-1])
        np.testing.assert_allclose(center, R @ p_body + t, rtol=0, atol=1e-12)
        assert radius == pytest.approx(4.0 * spread + 3.0, rel=1e-12)


@pytest.mark.parametrize("keep_joint", [False, True])
def test_a_keyframe_scored_at_once_gives_each_detection_what_it_gets_alone(keep_joint):
    """The keyframe's pairs are scored in one batch: each detection's candidates, weights and
    distances are those it gets scored on its own, on random maps (to round-off)."""
    for seed in range(4):
        rng = np.random.default_rng(seed)
        context = hand_context()
        add_pose(context, 0, gtsam.Pose3(), [0.02, 0.02, 0.05, 0.3, 0.3, 0.1])
        positions = rng.uniform([2, -12, -1], [30, 12, 1], (40, 3))
        for p in positions:
            add_landmark(context, p, rng.uniform(0.2, 1.5), classes=rng.dirichlet([1, 1]))
        tags = [
            gtsam.Pose3(gtsam.Rot3.Yaw(rng.uniform(-1, 1)), np.append(rng.uniform(3, 8, 2), 0.5))
            for _ in range(6)
        ]
        for tag in tags:
            _add_tag(context, tag, rng.uniform(0.05, 0.3))
        context.solver.update()
        step = gtsam.Pose3(gtsam.Rot3.Yaw(0.05), np.array([1.0, 0.1, 0.0]))
        prediction = PosePrediction(
            1, X(0), step, step.inverse().AdjointMap(), np.diag([1e-4] * 3 + [1e-2] * 3)
        )
        seen = positions[rng.choice(len(positions), 10, replace=False)]
        keyframe = [
            measurement(
                1,
                detection_of(
                    step,
                    p + rng.normal(0, 0.5, 3),
                    class_id=int(rng.integers(2)),
                    sigmas=rng.uniform(0.5, 2.0, 3) * np.array([0.01, 0.01, 0.1]),
                ),
                k,
            )
            for k, p in enumerate(seen)
        ]
        for tag in tags[:3]:  # the tags seen, among the points
            relative = step.between(tag).compose(gtsam.Pose3.Expmap(rng.normal(0, 0.02, 6)))
            keyframe.insert(int(rng.integers(len(keyframe))), _tag_measurement(1, relative))
        s = scorer(context, keep_joint)
        together, _ = s.score(prediction, keyframe, full=True)
        for m, c in zip(keyframe, together, strict=True):
            (alone,), _ = s.score(prediction, [m], full=True)
            assert c.landmark_ids.tolist() == alone.landmark_ids.tolist()
            assert c.searched == alone.searched
            np.testing.assert_allclose(c.weights, alone.weights, rtol=1e-9, atol=1e-12)
            np.testing.assert_allclose(c.mahalanobis_sq, alone.mahalanobis_sq, rtol=1e-9)
            np.testing.assert_allclose(c.fit_sq, alone.fit_sq, rtol=1e-12)
        assert sum(len(c) > 1 for c in together) >= 1  # some detection had rivals to weigh
        tag_candidates = [
            len(c) for m, c in zip(keyframe, together, strict=True) if m.kind is LandmarkKind.POSE
        ]
        assert sum(tag_candidates) >= 3  # the tags were scored too


# --- the exact gate: a pose known to a micrometre, landmarks known to LANDMARK_SIGMA --------

LANDMARK_SIGMA = 0.5
RANGE = 10.0
GAMMA_SIGMAS = np.array([0.01, 0.01, 0.1])


def pinned_pose_context(config=None):
    """Pose 0 at the origin, known to 1e-6; the new pose predicted at it exactly."""
    context = hand_context(config)
    add_pose(context, 0, gtsam.Pose3(), 1e-6)
    prediction = PosePrediction(1, X(0), gtsam.Pose3(), np.eye(6), np.zeros((6, 6)))
    return context, prediction


def ahead(bearing: float) -> np.ndarray:
    return RANGE * np.array([math.cos(bearing), math.sin(bearing), 0.0])


def scorer(context, keep_joint: bool = False) -> CandidateScorer:
    a = context.config.association
    return CandidateScorer(context.solver, context.landmarks, CONFUSION, a, keep_joint)


# For a landmark at range r ahead, the rows of H_l (bearing, elevation, range) are orthogonal
# with lengths 1/r, 1/r, 1: an isotropic landmark covariance s^2 I gives
# R = diag(s^2 / r^2 + sb^2, s^2 / r^2 + se^2, s^2 + sr^2), and a landmark off by angle a in
# bearing has d^2 = a^2 / R_bb.
R_BEARING = LANDMARK_SIGMA**2 / RANGE**2 + GAMMA_SIGMAS[0] ** 2


@pytest.mark.parametrize("keep_joint", [False, True])
def test_a_landmark_just_inside_the_gate_passes_and_one_just_outside_does_not(keep_joint):
    context, prediction = pinned_pose_context()
    s = scorer(context, keep_joint)
    gate = assoc.chi2_gate(3, s.confidence)
    # either side of the gate by 2 % in d^2: far beyond the pose's 1e-6 and round-off
    inside_angle = math.sqrt(0.98 * gate * R_BEARING)
    outside_angle = -math.sqrt(1.02 * gate * R_BEARING)
    inside = add_landmark(context, ahead(inside_angle), LANDMARK_SIGMA)
    outside = add_landmark(context, ahead(outside_angle), LANDMARK_SIGMA)
    context.solver.update()
    m = measurement(1, detection_of(gtsam.Pose3(), ahead(0.0), sigmas=GAMMA_SIGMAS))
    (candidates,), _ = s.score(prediction, [m])
    assert candidates.searched == 2  # the spatial search found both ...
    assert candidates.landmark_ids.tolist() == [inside]  # ... the gate kept one
    assert candidates.mahalanobis_sq[0] == pytest.approx(0.98 * gate, rel=1e-6)
    assert outside not in candidates.landmark_ids


def test_the_gate_s_confidence_is_the_joint_one_when_the_keyframe_is_decided_jointly():
    context, _ = pinned_pose_context()
    a = context.config.association
    assert scorer(context).confidence == a.chi2_confidence
    assert scorer(context, keep_joint=True).confidence == a.joint_candidate_confidence


def tie(pose_key: int, landmark_key: int, total: np.ndarray, sigma: float):
    """A factor saying t + l = total: the pose's translation and the landmark move against
    each other (no sensor does that; it makes R larger than its pose and landmark parts)."""

    def error(_, values, H):
        pose, landmark = values.atPose3(pose_key), values.atPoint3(landmark_key)
        if H is not None:
            H[0] = np.hstack([np.zeros((3, 3)), pose.rotation().matrix()])
            H[1] = np.eye(3)
        return pose.translation() + landmark - total

    noise = gtsam.noiseModel.Isotropic.Sigma(3, sigma)
    return gtsam.CustomFactor(noise, [pose_key, landmark_key], error)


def correlated_context(correlation: str):
    """Pose 0 known to 0.5 m and 0.02 rad, a landmark 10 m off; the new pose predicted 2 m
    ahead. "seen": the landmark was seen precisely from pose 0, so the two move together (R
    far below its parts' sum); "tied": they move against each other (R above it)."""
    context = hand_context()
    pose0 = gtsam.Pose3()
    landmark_position = np.array([10.0, 3.0, 0.5])
    if correlation == "seen":
        add_pose(context, 0, pose0, [0.02, 0.02, 0.02, 0.5, 0.5, 0.5])
        j = add_landmark(context, landmark_position, 1000.0)  # a new landmark's weak anchor
        context.add_factor(measurement(0, detection_of(pose0, landmark_position)), j)
    else:
        add_pose(context, 0, pose0, [1e-3, 1e-3, 1e-3, 0.5, 0.5, 0.5])
        j = add_landmark(context, landmark_position, 0.5)
        context.solver.add(tie(X(0), L(j), landmark_position, 0.01))
    context.solver.update()
    step = gtsam.Pose3(gtsam.Rot3.Yaw(0.1), np.array([2.0, 0.0, 0.0]))
    process = np.diag([1e-6, 1e-6, 1e-6, 1e-4, 1e-4, 1e-4])
    pose1 = pose0.compose(step)
    prediction = PosePrediction(1, X(0), pose1, step.inverse().AdjointMap(), process)
    return context, prediction, j, landmark_position


def exact_innovation(context, prediction, j, landmark_position, gamma):
    """R = J Sigma J^T + Gamma for the new pose and the landmark, J by central differences
    and Sigma from iSAM2's joint marginal of pose 0 and the landmark carried to pose 1."""
    joint = context.solver.joint_covariance([X(0), L(j)])
    A = prediction.transport
    sigma = np.zeros((9, 9))
    sigma[:6, :6] = A @ joint[:6, :6] @ A.T + prediction.process
    sigma[:6, 6:] = A @ joint[:6, 6:]
    sigma[6:, :6] = sigma[:6, 6:].T
    sigma[6:, 6:] = joint[6:, 6:]

    def seen(pose, point):
        return bearing_elevation_range(pose.transformTo(point))

    H_x = numerical_jacobian(
        lambda p: seen(p, landmark_position), prediction.pose, gtsam.Pose3.retract, 6
    )
    H_l = numerical_jacobian(lambda q: seen(prediction.pose, q), landmark_position)
    J = np.hstack([H_x, H_l])
    return J @ sigma @ J.T + gamma, J


@pytest.mark.parametrize("correlation", ["seen", "tied"])
def test_the_cheap_bound_never_excludes_what_the_exact_gate_keeps(correlation):
    context, prediction, j, landmark_position = correlated_context(correlation)
    gamma = np.diag(GAMMA_SIGMAS**2)
    R, J = exact_innovation(context, prediction, j, landmark_position, gamma)
    pose_covariance = prediction.covariance(context.solver.marginal_covariance(X(0)))
    landmark_covariance = context.solver.marginal_covariance(L(j))
    uncorrelated = J[:, :6] @ pose_covariance @ J[:, :6].T
    uncorrelated += J[:, 6:] @ landmark_covariance @ J[:, 6:].T + gamma
    s = scorer(context)
    gate = assoc.chi2_gate(3, s.confidence)
    truth = bearing_elevation_range(prediction.pose.transformTo(landmark_position))
    # detections off the prediction by a sigma of bearing and of range together, scaled to
    # d^2 from well inside the gate to well outside it, each scored on its own
    direction = GAMMA_SIGMAS * np.array([1.0, 0.0, 1.0])
    unit_d2 = direction @ np.linalg.solve(R, direction)
    # the cases are ones where the correlation matters: the marginals' sum, which leaves it
    # out, puts the detection at 0.9 of the gate at a third of it or less when the two move
    # together, and beyond the gate when they move apart
    uncorrelated_d2 = direction @ np.linalg.solve(uncorrelated, direction) / unit_d2
    if correlation == "seen":
        assert 0.9 * uncorrelated_d2 < 0.3
    else:
        assert 0.9 * uncorrelated_d2 > 1.0
    for fraction in (0.1, 0.5, 0.9, 0.97, 1.03, 1.1, 2.0, 10.0):
        z = truth - direction * math.sqrt(fraction * gate / unit_d2)
        detection = detection_at(z, sigmas=GAMMA_SIGMAS)
        (candidates,), _ = s.score(prediction, [measurement(1, detection)])
        kept = candidates.landmark_ids.tolist() == [j]
        assert kept == (fraction < 1.0), fraction
        if kept and not np.isnan(candidates.mahalanobis_sq[0]):
            assert candidates.mahalanobis_sq[0] == pytest.approx(fraction * gate, rel=1e-4)


@pytest.mark.parametrize("max_candidates", [2, 3, 8])
def test_max_candidates_keeps_the_nearest(max_candidates):
    config = with_settings(load_config(), association={"max_candidates": max_candidates})
    context, prediction = pinned_pose_context(config)
    # five landmarks within the gate, made in an order that is not their distance's
    angles = [0.04, -0.01, 0.05, 0.02, -0.03]
    ids = [add_landmark(context, ahead(a), LANDMARK_SIGMA) for a in angles]
    context.solver.update()
    m = measurement(1, detection_of(gtsam.Pose3(), ahead(0.0), sigmas=GAMMA_SIGMAS))
    (candidates,), _ = scorer(context).score(prediction, [m])
    nearest = [j for _, j in sorted(zip(np.abs(angles), ids, strict=True))][:max_candidates]
    assert sorted(candidates.landmark_ids.tolist()) == sorted(nearest)
    assert candidates.searched == len(angles)
    # the weights: semantic alike, so proportional to exp(-d^2 / 2), d^2 = angle^2 / R_bb
    chosen = np.array([angles[ids.index(j)] for j in candidates.landmark_ids])
    expected = np.exp(-0.5 * chosen**2 / R_BEARING)
    np.testing.assert_allclose(candidates.weights, expected / expected.sum(), rtol=1e-6)
