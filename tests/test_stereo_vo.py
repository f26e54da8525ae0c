"""Stereo visual odometry: its parts on exact synthetic data, then whole runs on a small
ray-cast corridor (exact motion known), on the rendered demo sequence, and on the real KITTI clip
of ../shared/data/real (with its GPS/INS poses), every frame and with frames left out (faster
motion, sharper turns)."""

from __future__ import annotations

import dataclasses
import functools

import cv2
import numpy as np
import pytest

from data_tools.bench_frontend import REAL_CLIP, odometry_figures
from pipeline.datasets.camera import StereoIntrinsics
from pipeline.datasets.kitti import KittiSequence, camera_poses_to_body
from pipeline.frontend import geometry as g
from pipeline.frontend.config import load_frontend_config
from pipeline.frontend.stereo_vo import (
    StereoFeatures,
    StereoOdometry,
    common_offset_fit,
    detect_corners,
    direction_covariance,
    disparity_offset_jacobian,
    fit_covariance,
    match_stereo,
    offset_second_moment,
    refine_pose,
    solve_pnp,
    stereo_features,
    unseen_covariance,
)
from tests import real_data

CAMERA = StereoIntrinsics(
    width=320, height=240, fx=260.0, fy=260.0, cx=159.5, cy=119.5, baseline=0.4
)
CHI2_6DOF_999 = 22.46


def config():
    return load_frontend_config()


# --- a textured corridor, ray cast -----------------------------------------------------------


@functools.cache
def texture() -> np.ndarray:
    """Smooth random grey texture (float32, 0..255), tiled over every surface."""
    rng = np.random.default_rng(7)
    total = np.zeros((512, 512), np.float32)
    for sigma, weight in ((1.5, 0.5), (4.0, 1.0), (12.0, 1.0)):
        layer = cv2.GaussianBlur(rng.normal(size=(512, 512)).astype(np.float32), (0, 0), sigma)
        total += weight * layer / layer.std()
    return np.clip(128 + 40 * total, 0, 255).astype(np.float32)


# Corridor in a camera-aligned world frame (x right, y down, z forward): walls at x = +-2,
# floor at y = 1.4, ceiling at y = -1.6, end wall at z = 40. (normal axis, offset, (u, v) axes)
PLANES = (
    (0, -2.0, (2, 1)),
    (0, 2.0, (2, 1)),
    (1, 1.4, (0, 2)),
    (1, -1.6, (0, 2)),
    (2, 40.0, (0, 1)),
)
TEXELS_PER_METRE = 60.0


def render(world_from_camera: np.ndarray, supersample: int = 2) -> np.ndarray:
    """The corridor as seen by a camera (grey uint8), anti-aliased by supersampling."""
    s = supersample
    u, v = np.meshgrid(
        (np.arange(CAMERA.width * s) - (s - 1) / 2) / s,
        (np.arange(CAMERA.height * s) - (s - 1) / 2) / s,
    )
    rays = np.stack(
        [(u - CAMERA.cx) / CAMERA.fx, (v - CAMERA.cy) / CAMERA.fy, np.ones_like(u)], axis=-1
    )
    rays = rays @ world_from_camera[:3, :3].T
    origin = world_from_camera[:3, 3]
    depth = np.full(u.shape, np.inf)
    map_u = np.zeros(u.shape, np.float32)
    map_v = np.zeros(u.shape, np.float32)
    for k, (axis, offset, (a, b)) in enumerate(PLANES):
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (offset - origin[axis]) / rays[..., axis]
        hit = (t > 0) & (t < depth)
        points = origin + t[..., None] * rays
        depth = np.where(hit, t, depth)
        # Each plane gets its own part of the (wrapped) texture.
        map_u = np.where(hit, points[..., a] * TEXELS_PER_METRE + 97 * k, map_u)
        map_v = np.where(hit, points[..., b] * TEXELS_PER_METRE + 61 * k, map_v)
    fine = cv2.remap(
        texture(),
        map_u.astype(np.float32),
        map_v.astype(np.float32),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_WRAP,
    )
    image = cv2.resize(fine, (CAMERA.width, CAMERA.height), interpolation=cv2.INTER_AREA)
    return np.clip(np.round(image), 0, 255).astype(np.uint8)


def stereo_pair(world_from_camera: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    right = world_from_camera.copy()
    right[:3, 3] += world_from_camera[:3, 0] * CAMERA.baseline
    return render(world_from_camera), render(right)


def drive(frames: int, speed: float = 0.3, yaw_rate: float = 0.012) -> list[np.ndarray]:
    """Camera poses along the corridor: forward, turning slowly, bobbing a little."""
    poses = []
    for i in range(frames):
        pose = np.eye(4)
        pose[:3, :3] = g.so3_exp([0.004 * np.sin(i), yaw_rate * i, 0.0])
        pose[:3, 3] = [0.3 * np.sin(0.2 * i), 0.02 * np.cos(i), speed * i]
        poses.append(pose)
    return poses


@functools.cache
def corridor(frames: int = 9) -> tuple[list[np.ndarray], list[tuple[np.ndarray, np.ndarray]]]:
    poses = drive(frames)
    return poses, [stereo_pair(p) for p in poses]


# --- parts -----------------------------------------------------------------------------------


def test_corners_spread_one_per_cell_strongest_first():
    _, [(left, _), *_] = corridor()
    pixels = detect_corners(left, threshold=10, cell=32, max_count=40)
    assert 10 < len(pixels) <= 40
    cells = {(int(u // 32), int(v // 32)) for u, v in pixels}
    assert len(cells) == len(pixels)


def test_stereo_match_recovers_a_known_shift():
    _, [(left, _), *_] = corridor()
    shift = 6.3
    right = cv2.warpAffine(left, np.array([[1.0, 0.0, -shift], [0.0, 1.0, 0.0]]), (320, 240))
    pixels = detect_corners(left, 10, 16, 200)
    pixels = pixels[(pixels[:, 0] > 20) & (pixels[:, 0] < 300)]
    disparity, good = match_stereo(left, right, pixels, config().vo)
    assert good.mean() > 0.9
    assert np.median(np.abs(disparity[good] - shift)) < 0.05


def synthetic_correspondences(rng, count: int, sigma: float):
    pose = g.se3_exp([0.02, -0.05, 0.01, 0.3, -0.1, 1.2])
    points = np.column_stack(
        [rng.uniform(-4, 4, count), rng.uniform(-2, 2, count), rng.uniform(4, 20, count)]
    )
    local = (points - pose[:3, 3]) @ pose[:3, :3]
    pixels = g.project(local, CAMERA) + rng.normal(0, sigma, (count, 2))
    return pose, points, pixels


def test_refined_pose_covariance_matches_its_scatter():
    rng = np.random.default_rng(11)
    sigma = 0.5
    pose, points, _ = synthetic_correspondences(rng, 60, 0.0)
    point_covariances = np.zeros((60, 3, 3))
    local = (points - pose[:3, 3]) @ pose[:3, :3]
    errors, covariances = [], []
    for _ in range(300):
        pixels = g.project(local, CAMERA) + rng.normal(0, sigma, (60, 2))
        start = pose @ g.se3_exp(rng.normal(0, 0.01, 6))
        fit = refine_pose(start, points, point_covariances, pixels, CAMERA, sigma, 6)
        delta = np.linalg.inv(pose) @ fit.camera_pose
        errors.append(np.concatenate([g.so3_log(delta[:3, :3]), delta[:3, 3]]))
        covariances.append(fit.covariance)
    errors = np.array(errors)
    predicted = np.mean(covariances, axis=0)
    ratio = np.var(errors, axis=0) / np.diag(predicted)
    # The covariance never claims less than the pixel noise allows: chi2/dof is floored at 1,
    # so with the right noise model it is at or a little above the true scatter.
    assert np.all(ratio > 0.6) and np.all(ratio < 1.3), ratio


def test_covariance_grows_with_the_residuals():
    pose, points, pixels_small = synthetic_correspondences(np.random.default_rng(1), 80, 0.5)
    _, _, pixels_large = synthetic_correspondences(np.random.default_rng(1), 80, 1.5)
    no_point_noise = np.zeros((80, 3, 3))
    small = refine_pose(pose, points, no_point_noise, pixels_small, CAMERA, 0.5, 6)
    large = refine_pose(pose, points, no_point_noise, pixels_large, CAMERA, 0.5, 6)
    # Three times the noise: about nine times the variance (the fit's chi2 scales it).
    ratio = np.trace(large.covariance) / np.trace(small.covariance)
    assert 6.0 < ratio < 13.0
    assert large.inliers.mean() > 0.95


def test_outliers_do_not_widen_the_gate_when_the_start_is_given():
    # 40 points seen right, 60 tracked to random places: started on the 40 (as RANSAC's inliers
    # start it), the fit keeps to them. The gate's scale is that of the inliers' residuals; were
    # it that of all points, it would open to the outliers and pull the pose away.
    rng = np.random.default_rng(3)
    pose, points, pixels = synthetic_correspondences(rng, 100, 0.5)
    pixels[40:] = rng.uniform([0, 0], [320, 240], (60, 2))
    start = np.arange(100) < 40
    fit = refine_pose(pose, points, np.zeros((100, 3, 3)), pixels, CAMERA, 0.5, 6, start)
    assert fit.inliers[:40].sum() >= 38 and fit.inliers[40:].sum() <= 2
    error = relative_error(fit.camera_pose, pose)
    assert np.linalg.norm(error[3:]) < 0.05 and np.linalg.norm(error[:3]) < 0.005


def test_a_motion_most_tracks_disagree_with_is_refused():
    rng = np.random.default_rng(4)
    _, points, pixels = synthetic_correspondences(rng, 100, 0.3)
    features = StereoFeatures(pixels, points, np.zeros((100, 3, 3)))
    c = config().vo
    assert solve_pnp(features, pixels, CAMERA, c) is not None
    # 45 tracks right, 55 wrong: RANSAC still finds the 45, and the motion is refused.
    wrong = pixels.copy()
    wrong[45:] = rng.uniform([0, 0], [320, 240], (55, 2))
    assert solve_pnp(features, wrong, CAMERA, c) is None
    loose = dataclasses.replace(c, min_inlier_fraction=0.4)
    fit = solve_pnp(features, wrong, CAMERA, loose)
    assert fit is not None and fit.inliers.sum() >= 43


def test_direction_covariance_by_hand():
    # 2 m straight ahead, its direction known to 0.01 rad: 2 cm across it, nothing along it.
    np.testing.assert_allclose(
        direction_covariance(np.array([0.0, 0.0, 2.0]), 0.01),
        np.diag([4e-4, 4e-4, 0.0]),
        atol=1e-15,
    )
    # 3 m along x: the cross terms vanish too, y and z get (0.01 * 3)^2.
    np.testing.assert_allclose(
        direction_covariance(np.array([3.0, 0.0, 0.0]), 0.01),
        np.diag([0.0, 9e-4, 9e-4]),
        atol=1e-15,
    )


def test_unseen_covariance_by_hand():
    c = dataclasses.replace(
        config().vo,
        min_sigma_rotation=0.001,
        min_sigma_translation=0.005,
        rotation_sigma_fraction=0.01,
        direction_sigma=0.01,
    )
    # 2 m forward while turning 0.1 rad about the optical axis (which leaves R^T t = t).
    motion = np.eye(4)
    motion[:3, :3] = g.so3_exp(np.array([0.0, 0.0, 0.1]))
    motion[:3, 3] = [0.0, 0.0, 2.0]
    # The disparity offset moves the fit 3 cm forward per pixel; its second moment is 4 px^2.
    sensitivity = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.03])
    covariance = unseen_covariance(motion, sensitivity, 4.0, c)
    rotation = 0.001**2 + (0.01 * 0.1) ** 2  # the floor and 1 % of the turn
    across = 0.005**2 + (0.01 * 2.0) ** 2  # the floor and 0.01 rad of the 2 m
    along = 0.005**2 + 4.0 * 0.03**2  # the floor and the offset's 3 cm/px * 2 px
    np.testing.assert_allclose(
        covariance, np.diag([rotation] * 3 + [across, across, along]), atol=1e-15
    )


def test_offset_second_moment_by_hand():
    # No estimate yet: the prior's variance.
    assert offset_second_moment(0.5, 0.0, 0.0) == pytest.approx(0.25)
    # Estimates of 1 px with information 96 (sigma ~0.1 px): the prior's 4 and 96 make 100,
    # the mean 0.96, its variance 0.01.
    assert offset_second_moment(0.5, 96.0, 96.0) == pytest.approx(0.96**2 + 0.01)
    # The sign of the offset does not matter.
    assert offset_second_moment(0.5, 96.0, -96.0) == pytest.approx(0.96**2 + 0.01)


def test_disparity_offset_jacobian_by_hand():
    # A point at (1, 0, 10) seen from 1 m further on: u = fx x / (z - 1). One pixel more of
    # disparity d = fx b / z = 10.4 pulls it along its ray by the factor d / (d + 1): u moves
    # by fx x t / (d (z - t)^2) = 260 * 1 * 1 / (10.4 * 81) px.
    points = np.array([[1.0, 0.0, 10.0], [0.0, 0.0, 10.0]])
    local = points - np.array([0.0, 0.0, 1.0])
    point_jacobian = g.projection_jacobian(local, CAMERA)
    offset = disparity_offset_jacobian(points, point_jacobian, CAMERA)
    np.testing.assert_allclose(offset[0], [260.0 / (10.4 * 81.0), 0.0], rtol=1e-12)
    # On the optical axis the ray is the line of sight: nothing moves.
    np.testing.assert_allclose(offset[1], [0.0, 0.0], atol=1e-15)
    # Seen from where it was triangulated, no point moves.
    at_keyframe = disparity_offset_jacobian(points, g.projection_jacobian(points, CAMERA), CAMERA)
    np.testing.assert_allclose(at_keyframe, 0.0, atol=1e-12)


def test_common_offset_fit_by_hand():
    # Three points each show two pose components alone (J^T W J = I); a fourth sees no pose
    # but twice the offset. Residuals: 0.5 px on the first pose component, 2 px at the fourth.
    jacobian = np.zeros((4, 2, 6))
    for k in range(6):
        jacobian[k // 2, k % 2, k] = 1.0
    weight = np.broadcast_to(np.eye(2), (4, 2, 2))
    offset = np.array([[1.0, 0.0], [0.0, 0.0], [0.0, 0.0], [2.0, 0.0]])
    residual = np.array([[0.5, 0.0], [0.0, 0.0], [0.0, 0.0], [2.0, 0.0]])
    fit = common_offset_fit(jacobian, weight, residual, offset, np.eye(6), 0.5)
    # The pose absorbs the first point's share: s = -e0. The Schur complement g^T W g + s^T
    # J^T W g = 5 - 1 = 4; the offset (g^T W r + s^T J^T W r) / 4 = (4.5 - 0.5) / 4 = 1 px,
    # known with information 4 / 0.5.
    np.testing.assert_allclose(fit.sensitivity, [-1.0, 0, 0, 0, 0, 0], atol=1e-15)
    assert fit.estimate == pytest.approx(1.0)
    assert fit.information == pytest.approx(8.0)
    # An offset the pose absorbs whole cannot be told: no information, nothing estimated.
    offset[3] = 0.0
    absorbed = common_offset_fit(jacobian, weight, residual, offset, np.eye(6), 0.5)
    assert absorbed.information == 0.0 and absorbed.estimate == 0.0


def test_a_disparity_offset_is_estimated_and_its_effect_predicted():
    # Stereo points triangulated with disparities 1 px short (a rig's calibration error): the
    # fit lands -1 px x its sensitivity to the offset from the truth (so the truth is +1 x it
    # from the fit), and finds the offset, 1 px, from near and far points disagreeing.
    rng = np.random.default_rng(8)
    count = 120
    pixels0 = rng.uniform([20, 20], [300, 220], (count, 2))
    disparity = CAMERA.fx * CAMERA.baseline / rng.uniform(3.0, 20.0, count)
    truth = g.triangulate(np.column_stack([pixels0, disparity]), CAMERA)
    short = stereo_features(pixels0, disparity - 1.0, CAMERA, 0.5)
    pose = g.se3_exp(np.array([0.01, -0.02, 0.005, 0.1, 0.0, 1.5]))
    pixels = g.project((truth - pose[:3, 3]) @ pose[:3, :3], CAMERA)
    fit = refine_pose(pose, short.points, short.covariances, pixels, CAMERA, 0.5, 10)
    assert fit.inliers.mean() > 0.95
    assert fit.disparity_offset.estimate == pytest.approx(1.0, abs=0.1)
    error = relative_error(fit.camera_pose, pose)  # as the covariance: right perturbation
    predicted = fit.disparity_offset.sensitivity
    assert np.linalg.norm(error - predicted) < 0.2 * np.linalg.norm(predicted)


def test_fit_covariance_by_hand():
    information = np.diag([400.0, 400.0, 100.0, 4.0, 4.0, 1.0])
    # Residuals a quarter of the prior's variance: the inverse information times 0.25.
    np.testing.assert_allclose(
        fit_covariance(information, 0.25, 0.05),
        np.diag([0.25 / 400, 0.25 / 400, 0.25 / 100, 0.25 / 4, 0.25 / 4, 0.25]),
    )
    # Residuals that agree too well to be believed: the scale stops at its minimum.
    np.testing.assert_allclose(
        fit_covariance(information, 0.001, 0.05), np.diag(0.05 / np.diag(information))
    )
    # Correlated information stays symmetric; a singular one knows nothing.
    information[0, 3] = information[3, 0] = 20.0
    covariance = fit_covariance(information, 2.0, 0.05)
    np.testing.assert_allclose(covariance, 2.0 * np.linalg.inv(information))
    np.testing.assert_allclose(covariance, covariance.T)
    np.testing.assert_allclose(fit_covariance(np.zeros((6, 6)), 1.0, 0.05), np.eye(6))


def test_the_residual_variance_shrinks_the_covariance_too():
    # Residuals of 0.25 px with a prior of 0.5 px: about a quarter of the variance the prior
    # alone gives (it is no longer floored at the prior).
    pose, points, pixels = synthetic_correspondences(np.random.default_rng(5), 80, 0.25)
    no_point_noise = np.zeros((80, 3, 3))
    measured = refine_pose(pose, points, no_point_noise, pixels, CAMERA, 0.5, 6, None, 0.05)
    prior_only = refine_pose(pose, points, no_point_noise, pixels, CAMERA, 0.5, 6, None, 1.0)
    ratio = np.trace(measured.covariance) / np.trace(prior_only.covariance)
    assert 0.15 < ratio < 0.4
    assert measured.chi2_per_dof == pytest.approx(ratio, rel=1e-6)


def test_uncertain_points_widen_the_covariance():
    pose, points, pixels = synthetic_correspondences(np.random.default_rng(2), 80, 0.3)
    sharp = refine_pose(pose, points, np.zeros((80, 3, 3)), pixels, CAMERA, 0.3, 6)
    depth_noise = np.zeros((80, 3, 3))
    depth_noise[:, 2, 2] = 0.5**2  # 0.5 m along the keyframe's optical axis
    blurred = refine_pose(pose, points, depth_noise, pixels, CAMERA, 0.3, 6)
    assert np.trace(blurred.covariance[3:, 3:]) > 2 * np.trace(sharp.covariance[3:, 3:])


# --- whole runs ------------------------------------------------------------------------------


def relative_error(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    delta = np.linalg.inv(estimate) @ truth
    return np.concatenate([g.so3_log(delta[:3, :3]), delta[:3, 3]])


def body_motion(world_from_camera_a: np.ndarray, world_from_camera_b: np.ndarray) -> np.ndarray:
    camera_motion = np.linalg.inv(world_from_camera_a) @ world_from_camera_b
    return g.BODY_FROM_CAMERA @ camera_motion @ np.linalg.inv(g.BODY_FROM_CAMERA)


def run(frames, keyframes_config=None):
    c = config()
    odometry = StereoOdometry(CAMERA, c.vo, keyframes_config or c.keyframes)
    steps = [odometry.process(i, *pair) for i, pair in enumerate(frames)]
    return odometry, steps


def test_corridor_keyframe_motions_match_the_truth():
    poses, frames = corridor()
    keyframes = dataclasses.replace(config().keyframes, min_translation=0.8, max_frames=10)
    odometry, steps = run(frames, keyframes)
    steps = [s for s in steps if s is not None]
    last = odometry.finish()
    steps += [last] if last is not None else []
    assert len(steps) >= 2
    previous = 0
    for step in steps:
        assert not step.lost
        truth = body_motion(poses[previous], poses[step.frame_index])
        error = relative_error(step.motion, truth)
        assert np.linalg.norm(error[3:]) < 0.02, (step.frame_index, error)
        assert np.linalg.norm(error[:3]) < np.radians(0.2), (step.frame_index, error)
        assert error @ np.linalg.solve(step.covariance, error) < CHI2_6DOF_999
        previous = step.frame_index
    assert previous == len(frames) - 1  # finish() made the last frame a keyframe


def test_keyframes_follow_the_motion_thresholds():
    _, frames = corridor()
    keyframes = dataclasses.replace(config().keyframes, min_translation=0.55, max_frames=10)
    _, steps = run(frames, keyframes)
    # 0.3 m a frame: a keyframe every second frame.
    assert [s.frame_index for s in steps if s is not None] == [2, 4, 6, 8]


def test_a_sudden_jump_is_found_again_by_descriptors():
    # Frames 0, 1, 2, then 7: the constant-velocity prediction is 1.2 m short, too far off for
    # Lucas-Kanade; the keyframe's corners are found by ORB descriptors instead.
    poses, frames = corridor()
    keyframes = dataclasses.replace(config().keyframes, min_translation=5.0, max_frames=20)
    odometry, steps = run([frames[0], frames[1], frames[2], frames[7]], keyframes)
    last = steps[-1]  # too far to track on: the descriptors' fit, and a new keyframe
    assert last is not None and not last.lost
    assert odometry.recovered_count == 2  # the first frame (no motion yet), and the jump
    truth = body_motion(poses[0], poses[7])
    error = relative_error(last.motion, truth)
    assert np.linalg.norm(error[3:]) < 0.03
    assert error @ np.linalg.solve(last.covariance, error) < CHI2_6DOF_999


def test_lost_tracking_falls_back_to_constant_velocity():
    poses, frames = corridor()
    blank = np.full_like(frames[0][0], 128)
    frames = [*frames[:4], (blank, blank)]
    _, steps = run(frames)
    lost = steps[-1]
    assert lost is not None and lost.lost
    c = config().vo
    assert np.all(np.diag(lost.covariance)[3:] >= c.lost_sigma_translation**2 * 0.999)
    # The guess repeats the last frame-to-frame motion (0.3 m forward).
    assert np.linalg.norm(lost.motion[:3, 3]) == pytest.approx(
        np.linalg.norm(body_motion(poses[0], poses[4])[:3, 3]), rel=0.1
    )


def test_rendered_sequence_relative_poses(rendered_demo_sequence):
    sequence = KittiSequence(rendered_demo_sequence)
    truth = camera_poses_to_body(sequence.gt_poses)
    c = load_frontend_config()
    odometry = StereoOdometry(sequence.intrinsics, c.vo, c.keyframes)
    previous, count = 0, 0
    for index in range(len(sequence)):
        step = odometry.process(index, *sequence[index])
        if step is None:
            continue
        motion = np.linalg.inv(truth[previous]) @ truth[step.frame_index]
        error = relative_error(step.motion, motion)
        # Measured over the whole demo drive: <= 3.9 cm and 0.16 deg over ~1.5 m steps.
        assert np.linalg.norm(error[3:]) < 0.06
        assert np.linalg.norm(error[:3]) < np.radians(0.3)
        assert error @ np.linalg.solve(step.covariance, error) < CHI2_6DOF_999
        previous, count = step.frame_index, count + 1
    assert count >= len(sequence) // 4
    assert odometry.lost_count == 0


@pytest.fixture(scope="module")
def rendered_demo_sequence():
    from tests.test_frontend_run import rendered_demo

    return rendered_demo()


# --- the real KITTI clip ---------------------------------------------------------------------

needs_real_clip = real_data.needs(REAL_CLIP / "poses.txt")


@needs_real_clip
def test_real_kitti_clip_is_accurate():
    # 51 frames, 60 m straight at 12 m/s (every frame a keyframe). Measured: drift 1.24 %,
    # worst step 2.5 cm, translation NEES at most 2.1.
    figures = odometry_figures(KittiSequence(REAL_CLIP), config())
    assert figures.lost == 0
    assert figures.drift_percent < 2.0
    assert figures.worst_step_m < 0.05
    assert figures.translation_nees_max < 25.0


@needs_real_clip
@pytest.mark.parametrize("every", [1, 2, 3])
def test_real_kitti_clip_covariance_is_honest(every):
    # The median NEES of the whole step (5.35 when honest) between 5.35 / 3 and 10: a
    # covariance ten times too large or too small leaves it. The clip was not used to
    # calibrate the covariance. Measured: 4.9, 6.0, 7.1 (before the disparity offset and the
    # turn's terms: 7.8, 7.9, 8.9, with floors fitted to this clip).
    figures = odometry_figures(KittiSequence(REAL_CLIP), config(), every)
    assert 5.35 / 3 <= figures.pose_nees_median <= 10.0
    assert 0.3 <= figures.translation_nees_median <= 10.0
    assert 0.3 <= figures.rotation_nees_median <= 10.0


def test_bench_refuses_a_real_clip_without_truth(tmp_path, capsys):
    from data_tools.bench_frontend import main

    with pytest.raises(SystemExit) as exit_info:
        main(["--odometry", "--real", str(tmp_path)])
    assert exit_info.value.code == 2
    assert f"--real {tmp_path}: no poses.txt" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_info:
        main(["--real", str(tmp_path)])
    assert exit_info.value.code == 2
    assert "--real goes with --odometry" in capsys.readouterr().err


@needs_real_clip
@pytest.mark.parametrize("every", [3, 6])
def test_real_kitti_clip_with_frames_left_out_never_lies(every):
    # 3.6 and 7.2 m a frame. Before the backward check, the robust scale of the inliers and the
    # descriptor search, steps were 1.7-7 m wrong with sigmas of centimetres. Measured: drift
    # 1.18 and 2.07 %, worst step 8.4 and 24 cm, translation NEES at most 2.6 and 3.7.
    figures = odometry_figures(KittiSequence(REAL_CLIP), config(), every)
    assert figures.lost == 0
    assert figures.drift_percent < 4.0
    assert figures.worst_step_m < 0.1 * every
    assert figures.translation_nees_max < 25.0


def test_rendered_drive_covariance_is_honest(rendered_demo_sequence):
    # The demo drive's first 40 frames at pixel noise 1 (the covariance was calibrated at 0.5,
    # 2, 4, 8 on 80 frames). Measured: median 6-DoF NEES 1.98, rotation 1.29; with the
    # covariance floored at the prior pixel noise and the earlier floors: 0.53 and 0.37.
    figures = odometry_figures(KittiSequence(rendered_demo_sequence), config())
    assert figures.lost == 0
    assert 5.35 / 3 <= figures.pose_nees_median <= 5.35 * 3
    assert 2.37 / 4 <= figures.rotation_nees_median <= 2.37 * 4


@pytest.mark.parametrize("every", [3, 5])
def test_rendered_corner_with_frames_left_out_never_lies(rendered_demo_sequence, every):
    # The demo drive's first corner, turning up to 13 and 22 degrees a frame: tracking from the
    # last frame fails and the descriptors find the corners again. Measured: drift 0.26 and
    # 0.35 %, worst step 9 and 44 cm, translation NEES at most 22.4 and 9.7 (the first: a
    # step 4.5 % off in the sharpest turn).
    figures = odometry_figures(KittiSequence(rendered_demo_sequence), config(), every)
    assert figures.lost == 0
    assert figures.recovered >= 2
    assert figures.drift_percent < 2.0
    assert figures.translation_nees_max < 25.0
