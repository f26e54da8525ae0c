"""The built-in scenarios: noise statistics, classes, fields of view, the real KITTI path.

Expected values are computed here from the config files and the contract, by other means than
the generators use (GTSAM for poses, finite differences for Jacobians, the raw KITTI files).
Statistical bounds are five standard errors of the estimate, so a correct generator fails
about once in a million runs, and a wrong sigma, frame or rate fails at once.
"""

from __future__ import annotations

import math
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import gtsam
import numpy as np
import pytest

from data_tools.data import KITTI05_DIR
from data_tools.scenarios import (
    SCENARIOS,
    city_grid,
    common,
    indoor_tags,
    kitti05_cars,
    load_config,
    simulate,
)
from data_tools.scenarios.geometry import quaternion_from_rotation, se3_exp
from data_tools.scenarios.noise import confusion_matrix, sample_reported_classes
from pipeline.cli import main
from pipeline.errors import InputError
from pipeline.log import read_log

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "configs" / "scenarios"
SIGMAS_OF_ERROR = 5.0


def toml(scenario: str) -> dict:
    return tomllib.loads((CONFIGS / f"{scenario}.toml").read_text())


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """`run(scenario, **options)` -> (summary, log, path); each distinct run is made once."""
    cache: dict = {}

    defaults = {"seed": 0, "odom_noise_scale": 1.0, "misclassification": 0.0}

    def get(scenario: str, **options):
        key = (scenario, tuple(sorted({**defaults, **options}.items())))
        if key not in cache:
            path = tmp_path_factory.mktemp("logs") / f"{scenario}.mcap"
            summary = simulate(scenario, path, **options)
            cache[key] = (summary, read_log(path), path)
        return cache[key]

    return get


# --- helpers, independent of the generators -------------------------------------------------


def pose3(translation, rotation) -> gtsam.Pose3:
    x, y, z, w = rotation
    return gtsam.Pose3(gtsam.Rot3.Quaternion(w, x, y, z), np.asarray(translation, dtype=float))


def ground_truth(log) -> list[gtsam.Pose3]:
    return [pose3(m.translation, m.rotation) for m in log.ground_truth_poses]


def landmark_positions(log) -> dict[int, np.ndarray]:
    return {lm.id: np.array(lm.position) for lm in log.ground_truth_landmarks.landmarks}


_TRUE_DETECTIONS: dict[int, list] = {}


def true_detections(log) -> list:
    """(pose index, detection, true body-frame point) of every detection of a real landmark."""
    if id(log) not in _TRUE_DETECTIONS:
        poses = np.array([p.matrix() for p in ground_truth(log)])
        landmarks = landmark_positions(log)
        rows = [
            (m.pose_index, det)
            for m in log.detections
            for det in m.detections
            if det.truth_landmark_id >= 0
        ]
        index = np.array([k for k, _ in rows])
        world = np.array([landmarks[det.truth_landmark_id] for _, det in rows])
        points = np.einsum(
            "nji,nj->ni", poses[index, :3, :3], world - poses[index, :3, 3]
        )  # R^T (l - t)
        _TRUE_DETECTIONS[id(log)] = [(k, det, p) for (k, det), p in zip(rows, points, strict=True)]
    return _TRUE_DETECTIONS[id(log)]


def contract_measurement(p: np.ndarray) -> np.ndarray:
    """The contract's point measurement, written out again from its definition."""
    return np.array(
        [math.atan2(p[1], p[0]), math.atan2(p[2], math.hypot(p[0], p[1])), np.linalg.norm(p)]
    )


def whiten(residuals: np.ndarray, covariances: np.ndarray) -> np.ndarray:
    """Residuals times the inverse Cholesky factor of their covariance: N(0, I) if consistent."""
    chol = np.linalg.cholesky(covariances)
    return np.linalg.solve(chol, residuals[..., None])[..., 0]


def assert_standard_normal(z: np.ndarray, what: str) -> None:
    n = len(z)
    assert n >= 200, f"{what}: too few samples ({n})"
    mean, var = z.mean(axis=0), z.var(axis=0, ddof=1)
    mean_bound = SIGMAS_OF_ERROR / math.sqrt(n)
    var_bound = SIGMAS_OF_ERROR * math.sqrt(2.0 / (n - 1))
    assert np.all(np.abs(mean) < mean_bound), f"{what}: means {mean} (bound {mean_bound:.3g})"
    assert np.all(np.abs(var - 1.0) < var_bound), f"{what}: variances {var} (bound {var_bound:.3g})"


def odometry_residuals(log) -> tuple[np.ndarray, np.ndarray]:
    """Logmap(true^-1 measured) per odometry message (the right perturbation), and covariances."""
    poses = ground_truth(log)
    xi, cov = [], []
    for k, m in enumerate(log.odometry):
        true = poses[k].between(poses[k + 1])
        xi.append(gtsam.Pose3.Logmap(true.between(pose3(m.translation, m.rotation))))
        cov.append(np.reshape(m.covariance, (6, 6)))
    return np.array(xi), np.array(cov)


def odometry_sigmas(scenario: str, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """(calibrated, true) sigmas in Pose3 tangent order, from the config file."""
    o = toml(scenario)["odometry"]
    base = np.array([*o["base_rotation_sigma_rad"], *o["base_translation_sigma_m"]])
    added = scale * np.array(
        [0, 0, o["added_sigma_yaw_rad"], o["added_sigma_x_m"], o["added_sigma_y_m"], 0]
    )
    return base, np.sqrt(base**2 + added**2)


ALL = list(SCENARIOS)
# planar-park's odometry errs by a slow bias instead (tests/test_scenario_worlds.py).
PAPER_ODOMETRY = [s for s in SCENARIOS if s != "planar-park"]
# Scenarios whose simulation alone takes 8 s or more here (KITTI 05's 2,761 poses, the park's
# laser): a test that makes one is slow.
SLOW_SCENARIOS = ("kitti05-cars", "planar-park")


def with_slow(scenarios: list[str]) -> list:
    """`scenarios` as parameters, the slow ones marked so."""
    return [
        pytest.param(s, marks=pytest.mark.slow) if s in SLOW_SCENARIOS else s for s in scenarios
    ]


# --- odometry -------------------------------------------------------------------------------


def test_odometry_noise_matches_requested_sigmas(run):
    # Both scenarios draw odometry with the same code; kitti05-cars is checked just below.
    scenario, scale = "indoor-tags", 10.0
    _, log, _ = run(scenario, odom_noise_scale=scale, true_covariance=True)
    _, sigmas = odometry_sigmas(scenario, scale)
    xi, cov = odometry_residuals(log)
    np.testing.assert_allclose(cov, np.broadcast_to(np.diag(sigmas**2), cov.shape), rtol=1e-12)
    assert_standard_normal(xi / sigmas, f"{scenario} odometry residuals / true sigmas")


@pytest.mark.parametrize("scenario", with_slow(PAPER_ODOMETRY))
def test_log_covariance_is_the_calibrated_model_by_default(run, scenario):
    scale = 10.0
    _, log, _ = run(scenario, odom_noise_scale=scale)
    base, true = odometry_sigmas(scenario, scale)
    xi, cov = odometry_residuals(log)
    np.testing.assert_allclose(cov, np.broadcast_to(np.diag(base**2), cov.shape), rtol=1e-12)
    # The noise drawn is still base + added: beyond what the log declares on x, y and yaw.
    assert_standard_normal(xi / true, f"{scenario} odometry residuals / true sigmas")


def test_noise_scale_zero_leaves_only_the_calibrated_noise(run):
    _, log, _ = run("indoor-tags", odom_noise_scale=0.0, true_covariance=True)
    base, _ = odometry_sigmas("indoor-tags", 0.0)
    xi, cov = odometry_residuals(log)
    np.testing.assert_allclose(cov[0], np.diag(base**2), rtol=1e-12)
    assert_standard_normal(xi / base, "indoor-tags odometry residuals at scale 0")


# --- detections: noise ----------------------------------------------------------------------


@pytest.mark.slow
def test_indoor_point_and_pose_noise_match_the_written_covariances(run):
    world_config = load_config("indoor-tags")
    world = indoor_tags.build_world(world_config)
    tag_poses = np.linalg.inv(world.poses[0]) @ world.tag_poses  # in the first body frame
    points, pose_residuals, point_cov, pose_cov = [], [], [], []
    for seed in (0, 1, 2):
        # The runs of the confusion test: classes are drawn apart from the geometry's noise.
        _, log, _ = run("indoor-tags", seed=seed, misclassification=0.3)
        landmarks = landmark_positions(log)
        np.testing.assert_allclose(
            np.array([landmarks[k] for k in range(len(tag_poses))]), tag_poses[:, :3, 3], atol=1e-9
        )
        poses = ground_truth(log)
        for index, det, p in true_detections(log):
            points.append(
                np.array([det.bearing, det.elevation, det.range]) - contract_measurement(p)
            )
            point_cov.append(np.reshape(det.covariance, (3, 3)))
            tag = gtsam.Pose3(tag_poses[det.truth_landmark_id])
            true = poses[index].between(tag)
            rp = det.relative_pose
            measured = pose3(rp.translation, rp.rotation)
            pose_residuals.append(gtsam.Pose3.Logmap(true.between(measured)))
            pose_cov.append(np.reshape(rp.covariance, (6, 6)))
    m = toml("indoor-tags")["measurement"]
    expected = np.diag([m["sigma_bearing_rad"], m["sigma_elevation_rad"], m["sigma_range_m"]])
    np.testing.assert_allclose(point_cov, np.broadcast_to(expected**2, (len(point_cov), 3, 3)))
    rot, trans = m["relative_pose_sigma_rotation_rad"], m["relative_pose_sigma_translation_m"]
    np.testing.assert_allclose(pose_cov[0], np.diag([rot] * 3 + [trans] * 3) ** 2)
    assert rot >= 0.3, "the paper's tags carry a large rotation error"
    assert_standard_normal(whiten(np.array(points), np.array(point_cov)), "tag bearing/elev/range")
    assert_standard_normal(
        whiten(np.array(pose_residuals), np.array(pose_cov)), "tag relative pose (right, tangent)"
    )


def _camera_measurement(u: np.ndarray, v: np.ndarray, fx: float, fy: float, cx, cy) -> np.ndarray:
    """Bearing and elevation of the ray through pixel (u, v): camera z forward = body x."""
    ray_camera = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones_like(u)], -1)
    ray_body = np.stack([ray_camera[..., 2], -ray_camera[..., 0], -ray_camera[..., 1]], -1)
    return np.stack(
        [
            np.arctan2(ray_body[..., 1], ray_body[..., 0]),
            np.arctan2(ray_body[..., 2], np.hypot(ray_body[..., 0], ray_body[..., 1])),
        ],
        -1,
    )


@pytest.mark.slow
def test_kitti_stereo_noise_matches_the_camera_model(run):
    _, log, _ = run("kitti05-cars")
    cam, det_cfg = toml("kitti05-cars")["camera"], toml("kitti05-cars")["detector"]
    fx, fy, cx, cy, b = cam["fx"], cam["fy"], cam["cx"], cam["cy"], cam["baseline"]
    residuals, covariances, points = [], [], []
    for _, det, p in true_detections(log):
        residuals.append(
            np.array([det.bearing, det.elevation, det.range]) - contract_measurement(p)
        )
        covariances.append(np.reshape(det.covariance, (3, 3)))
        points.append(p)
    residuals, covariances, points = map(np.array, (residuals, covariances, points))
    # Range: sigma_z = z^2 sigma_d / (f b) for the depth z (body x), along the ray for range.
    depth, distance = points[:, 0], np.linalg.norm(points, axis=1)
    sigma_z = depth**2 * det_cfg["disparity_sigma_px"] / (fx * b)
    np.testing.assert_allclose(np.sqrt(covariances[:, 2, 2]), sigma_z * distance / depth)
    # Bearing and elevation: pixel noise through the camera, by finite differences here.
    u = fx * (-points[:, 1]) / depth + cx
    v = fy * (-points[:, 2]) / depth + cy
    h = 1e-3
    jac = np.stack(
        [
            (
                _camera_measurement(u + h, v, fx, fy, cx, cy)
                - _camera_measurement(u - h, v, fx, fy, cx, cy)
            )
            / (2 * h),
            (
                _camera_measurement(u, v + h, fx, fy, cx, cy)
                - _camera_measurement(u, v - h, fx, fy, cx, cy)
            )
            / (2 * h),
        ],
        -1,
    )
    expected = det_cfg["pixel_sigma_px"] ** 2 * jac @ np.swapaxes(jac, 1, 2)
    np.testing.assert_allclose(covariances[:, :2, :2], expected, rtol=1e-5, atol=1e-14)
    assert_standard_normal(whiten(residuals, covariances), "car bearing/elevation/range")


# --- detections: classes --------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize(
    ("scenario", "alpha"),
    [
        ("indoor-tags", 0.3),
        ("kitti05-cars", 0.3),
        ("kitti05-cars", 0.0),
    ],
)
def test_observed_confusion_matches_alpha(run, scenario, alpha):
    seeds = (0, 1, 2) if scenario == "indoor-tags" else (0,)
    counts = None
    for seed in seeds:
        _, log, _ = run(scenario, seed=seed, misclassification=alpha)
        c = log.metadata.num_classes
        expected = np.full((c, c), alpha / (c - 1))
        np.fill_diagonal(expected, 1 - alpha)
        np.testing.assert_allclose(log.metadata.confusion_matrix, expected, atol=1e-15)
        true_class = {lm.id: lm.class_id for lm in log.ground_truth_landmarks.landmarks}
        counts = np.zeros((c, c)) if counts is None else counts
        for _, det, _ in true_detections(log):
            counts[true_class[det.truth_landmark_id], det.class_id] += 1
    rows = counts.sum(axis=1, keepdims=True)
    assert np.all(rows > 100), f"too few detections per class: {rows.ravel()}"
    observed = counts / rows
    bound = SIGMAS_OF_ERROR * np.sqrt(expected * (1 - expected) / rows) + 1e-12
    assert np.all(np.abs(observed - expected) <= bound), f"observed {observed}, alpha {alpha}"
    misclassified = 1 - np.trace(counts) / counts.sum()
    n = counts.sum()
    assert abs(misclassified - alpha) <= SIGMAS_OF_ERROR * math.sqrt(alpha * (1 - alpha) / n)


@pytest.mark.slow
def test_indoor_classes_are_tag_id_mod_c(run):
    for options in ({}, {"num_classes": 3}):
        _, log, _ = run("indoor-tags", **options)
        c = options.get("num_classes", toml("indoor-tags")["num_classes"])
        assert log.metadata.num_classes == c
        assert all(lm.class_id == lm.id % c for lm in log.ground_truth_landmarks.landmarks)
        # No misclassification asked: every detection reports its tag's class.
        for _, det, _ in true_detections(log):
            assert det.class_id == det.truth_landmark_id % c


# --- detections: where they can be ---------------------------------------------------------


def test_indoor_detections_are_inside_the_field_of_view_and_range(run):
    _, log, _ = run("indoor-tags")
    camera = toml("indoor-tags")["camera"]
    count = 0
    for _, det, p in true_detections(log):
        bearing, elevation, distance = contract_measurement(p)
        assert p[0] > 0
        assert abs(bearing) <= math.radians(camera["horizontal_fov_deg"]) / 2 + 1e-12
        assert abs(elevation) <= math.radians(camera["vertical_fov_deg"]) / 2 + 1e-12
        assert distance <= camera["max_range_m"] + 1e-12
        assert det.source == "apriltag" and det.relative_pose is not None
        count += 1
    assert count == log.num_detections  # tags have no false positives


@pytest.mark.slow
def test_kitti_detections_are_inside_the_image_and_range(run):
    _, log, _ = run("kitti05-cars")
    config = toml("kitti05-cars")
    cam, det_cfg = config["camera"], config["detector"]
    false_positives = 0
    for message in log.detections:
        for det in message.detections:
            assert det.score >= det_cfg["score_threshold"]
            u0, v0, u1, v1 = det.bbox
            assert 0 <= u0 <= u1 <= cam["width"] and 0 <= v0 <= v1 <= cam["height"]
            if det.truth_landmark_id == -1:
                false_positives += 1
    for _, _, p in true_detections(log):
        u = cam["fx"] * (-p[1]) / p[0] + cam["cx"]
        v = cam["fy"] * (-p[2]) / p[0] + cam["cy"]
        assert p[0] >= det_cfg["min_depth_m"]
        assert 0 <= u <= cam["width"] and 0 <= v <= cam["height"]
        assert np.linalg.norm(p) <= det_cfg["max_range_m"]
    assert 0 < false_positives < 0.05 * log.num_detections


@pytest.mark.slow
def test_kitti_detector_misses_cars_in_view(run):
    """Detections are a proper subset of the cars in view: the threshold drops some."""
    _, log, _ = run("kitti05-cars")
    cam, det_cfg = toml("kitti05-cars")["camera"], toml("kitti05-cars")["detector"]
    poses = np.array([p.matrix() for p in ground_truth(log)])
    ids = sorted(landmark_positions(log))
    cars = np.array([landmark_positions(log)[k] for k in ids])
    local = np.einsum("nji,nmj->nmi", poses[:, :3, :3], cars[None] - poses[:, None, :3, 3])
    u = cam["fx"] * (-local[..., 1]) / local[..., 0] + cam["cx"]
    v = cam["fy"] * (-local[..., 2]) / local[..., 0] + cam["cy"]
    in_view = (
        (local[..., 0] >= det_cfg["min_depth_m"])
        & (np.linalg.norm(local, axis=-1) <= det_cfg["max_range_m"])
        & (u >= 0)
        & (u <= cam["width"])
        & (v >= 0)
        & (v <= cam["height"])
    )
    seen = {(index, det.truth_landmark_id) for index, det, _ in true_detections(log)}
    visible = {(int(k), ids[m]) for k, m in zip(*np.nonzero(in_view), strict=True)}
    assert seen <= visible
    assert 0.3 < len(seen) / len(visible) < 0.98


# --- the worlds -----------------------------------------------------------------------------


def test_indoor_run_is_the_papers_size(run):
    summary, log, _ = run("indoor-tags")
    route = toml("indoor-tags")["route"]
    stamps = np.array([m.stamp_ns for m in log.ground_truth_poses])
    np.testing.assert_array_equal(np.diff(stamps), round(route["keyframe_period_s"] * 1e9))
    positions = np.array([m.translation for m in log.ground_truth_poses])
    length = np.linalg.norm(np.diff(positions, axis=0), axis=1).sum()
    assert abs(length - 1080.0) < 0.01 * 1080.0
    assert summary.path_length_m == pytest.approx(length)
    assert len(log.ground_truth_landmarks.landmarks) == 262
    assert 600 <= log.num_detections <= 800  # the paper: 702 detections of 262 tags
    assert log.num_poses == summary.num_poses == len(log.ground_truth_poses)
    # Loops: many keyframes come back within a metre of a place visited minutes before.
    far_in_time = np.abs(np.subtract.outer(stamps, stamps)) > 120e9
    close = np.linalg.norm(positions[:, None] - positions[None], axis=-1) < 1.0
    assert (far_in_time & close).any(axis=1).mean() > 0.5


@pytest.mark.slow
def test_kitti_path_is_the_real_sequence(run):
    summary, log, _ = run("kitti05-cars")
    raw = np.loadtxt(KITTI05_DIR / "poses.txt")
    times = np.loadtxt(KITTI05_DIR / "times.txt")
    assert log.num_poses == summary.num_poses == len(raw) == len(log.ground_truth_poses) == 2761
    camera_xyz = raw[:, [3, 7, 11]]
    real_length = np.linalg.norm(np.diff(camera_xyz, axis=0), axis=1).sum()
    positions = np.array([m.translation for m in log.ground_truth_poses])
    assert np.linalg.norm(np.diff(positions, axis=0), axis=1).sum() == pytest.approx(
        real_length, rel=1e-9
    )
    assert summary.path_length_m == pytest.approx(real_length, rel=1e-9)
    assert 2100 < real_length < 2300
    # Body = camera axes renamed (x = z_c, y = -x_c, z = -y_c); KITTI's pose 0 is the identity.
    np.testing.assert_allclose(
        positions, np.stack([camera_xyz[:, 2], -camera_xyz[:, 0], -camera_xyz[:, 1]], -1), atol=1e-6
    )
    stamps = np.array([m.stamp_ns for m in log.ground_truth_poses])
    np.testing.assert_array_equal(stamps, np.round(times * 1e9).astype(np.int64))
    assert log.calibration is not None and log.calibration.width == 1226


@pytest.mark.slow
def test_kitti_cars_line_both_sides_and_are_seen_again_on_revisits(run):
    _, log, _ = run("kitti05-cars")
    names = log.metadata.class_names
    assert names == tuple(v["name"] for v in toml("kitti05-cars")["vehicles"])
    classes = [lm.class_id for lm in log.ground_truth_landmarks.landmarks]
    assert set(classes) == set(range(len(names)))
    left = right = 0
    first_seen, revisits = {}, 0
    stamps = {m.pose_index: m.stamp_ns for m in log.detections}
    for index, det, p in true_detections(log):
        left, right = left + (p[1] > 0), right + (p[1] < 0)
        first = first_seen.setdefault(det.truth_landmark_id, stamps[index])
        revisits += stamps[index] - first > 60e9  # the same car, a minute or more later
    assert left > 0.2 * (left + right) and right > 0.2 * (left + right)
    assert revisits > 100


# --- the log as a whole ---------------------------------------------------------------------


@pytest.mark.parametrize("scenario", with_slow(ALL))
def test_logs_pass_contract_validation(run, scenario):
    summary, log, path = run(scenario)
    assert log.num_poses == summary.num_poses
    assert log.num_detections == summary.num_detections
    assert len(log.ground_truth_landmarks.landmarks) == summary.num_landmarks
    # the origin, computed from the route: round-off (6.9e-18 under OpenBLAS's Haswell kernels)
    np.testing.assert_allclose(log.ground_truth_poses[0].translation, 0.0, rtol=0, atol=1e-12)
    assert len(log.detections) == summary.num_poses  # one detection message a keyframe
    assert all(d.truth_landmark_id is not None for m in log.detections for d in m.detections)
    try:
        from pipeline.inspect import inspect_log
    except ImportError:
        return  # `mmslam inspect` is not there yet; read_log above is the contract's reader
    assert inspect_log(path)["valid"]


@pytest.mark.slow
@pytest.mark.parametrize("scenario", ALL)
def test_same_seed_same_bytes(tmp_path, scenario):
    path = tmp_path / "first.mcap"
    simulate(scenario, path, seed=3)
    again = tmp_path / "again.mcap"
    simulate(scenario, again, seed=3)
    assert again.read_bytes() == path.read_bytes()
    other = tmp_path / "other.mcap"
    simulate(scenario, other, seed=4)
    assert other.read_bytes() != path.read_bytes()


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"scenario": "office"}, "unknown scenario"),
        ({"misclassification": -0.1}, "misclassification"),
        ({"misclassification": 1.5}, "misclassification"),
        ({"misclassification": float("nan")}, "misclassification"),
        ({"odom_noise_scale": -1.0}, "odom-noise-scale"),
        ({"num_classes": 0}, "num-classes"),
        ({"num_classes": 1, "misclassification": 0.2}, "num-classes"),
        ({"seed": -1}, "seed"),
    ],
)
def test_bad_arguments_are_input_errors(tmp_path, options, message):
    options = dict(options)
    scenario = options.pop("scenario", "indoor-tags")
    out = tmp_path / "x.mcap"
    with pytest.raises(InputError, match=message):
        simulate(scenario, out, **options)
    assert not out.exists()


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[route]\nspeed = 1.0\n", "unknown key 'route.speed'"),
        ("[route]\nspeed_mps = 'fast'\n", "route.speed_mps"),
        ("[camera]\ndetection_probability = 1.5\n", "detection_probability"),
        ("[odometry]\nbase_rotation_sigma_rad = [0.1, 0.1]\n", "base_rotation_sigma_rad"),
        (
            "[odometry]\nbase_translation_sigma_m = [0.0, 0.1, 0.1]\n",
            r"'odometry\.base_translation_sigma_m\[0\]' must be in \(0, 100\], got 0\.0",
        ),
        ("num_classes = [\n", "not valid TOML"),
        ("[tags]\ncount = 100000\n", "walls too short"),
        ("[route]\ncorner_smoothing_m = 12.0\n", "leaves the corridors"),
    ],
)
def test_bad_config_files_are_input_errors(tmp_path, text, message):
    config = tmp_path / "bad.toml"
    config.write_text(text)
    with pytest.raises(InputError, match=message):
        simulate("indoor-tags", tmp_path / "x.mcap", config_path=config)


def test_config_file_overrides_defaults(tmp_path):
    config = tmp_path / "small.toml"
    config.write_text("[route]\nlength_m = 100.0\n")
    summary = simulate("indoor-tags", tmp_path / "x.mcap", config_path=config)
    assert summary.num_poses == math.floor(100.0 / 0.72) + 1
    missing = tmp_path / "kitti.toml"
    missing.write_text(f'[sequence]\ndata_dir = "{tmp_path / "no-such-folder"}"\n')
    with pytest.raises(InputError, match=re.escape(str(tmp_path / "no-such-folder"))):
        simulate("kitti05-cars", tmp_path / "y.mcap", config_path=missing)


# --- the math underneath ---------------------------------------------------------------------


def test_se3_exp_and_quaternions_agree_with_gtsam():
    rng = np.random.default_rng(0)
    xi = np.concatenate([rng.normal(0, 1.0, (50, 6)), rng.normal(0, 1e-7, (50, 6))])
    ours = se3_exp(xi)
    quats = quaternion_from_rotation(ours[:, :3, :3])
    for k in range(len(xi)):
        theirs = gtsam.Pose3.Expmap(xi[k])
        np.testing.assert_allclose(ours[k], theirs.matrix(), atol=1e-12)
        q = theirs.rotation().toQuaternion()
        expected = np.array([q.x(), q.y(), q.z(), q.w()]) * (1 if q.w() >= 0 else -1)
        np.testing.assert_allclose(quats[k], expected, atol=1e-12)


def test_confusion_matrix_and_class_sampling():
    for c, alpha in ((2, 0.1), (3, 0.5), (5, 1.0)):
        matrix = confusion_matrix(c, alpha)
        np.testing.assert_allclose(matrix.sum(axis=1), 1.0)
        np.testing.assert_allclose(np.diag(matrix), 1 - alpha)
    matrix = confusion_matrix(3, 0.3)
    rng = np.random.default_rng(1)
    true = np.repeat(np.arange(3), 20000)
    reported = sample_reported_classes(rng, true, matrix)
    for t in range(3):
        observed = np.bincount(reported[true == t], minlength=3) / 20000
        bound = SIGMAS_OF_ERROR * np.sqrt(matrix[t] * (1 - matrix[t]) / 20000)
        assert np.all(np.abs(observed - matrix[t]) <= bound)


# --- bounded memory: runs made in blocks and pieces, sizes refused before any work ------------


def test_pieces_keep_every_candidate_once_and_do_not_depend_on_the_blocks(monkeypatch):
    monkeypatch.setattr(common, "DETECTIONS_PER_PIECE", 10)
    rng = np.random.default_rng(0)
    counts = rng.integers(0, 6, 200)
    counts[50] = 25  # one keyframe over the limit: a piece of its own
    pose_index = np.repeat(np.arange(200), counts)
    landmark = rng.integers(0, 1000, len(pose_index))

    def chunked(size: int):
        for first in range(0, 200, size):
            inside = (pose_index >= first) & (pose_index < first + size)
            yield slice(first, min(first + size, 200)), (pose_index[inside], landmark[inside])

    made = [list(common.pieces(chunked(size), extra_per_pose=0.5)) for size in (1, 7, 200)]
    bounds = [[(p.start, p.stop) for p, _ in pieces] for pieces in made]
    assert bounds[0] == bounds[1] == bounds[2] and len(bounds[0]) > 20
    for piece, (poses, _) in made[1]:
        assert np.all((poses >= piece.start) & (poses < piece.stop))
        held = len(poses) + 0.5 * (piece.stop - piece.start)
        assert held <= 10 or piece.stop - piece.start == 1
    assert [s for s, _ in bounds[0]] == [0] + [e for _, e in bounds[0][:-1]]  # consecutive
    assert bounds[0][-1][1] == 200 and (50, 51) in bounds[0]
    np.testing.assert_array_equal(np.concatenate([p for _, (p, _) in made[1]]), pose_index)
    np.testing.assert_array_equal(np.concatenate([m for _, (_, m) in made[1]]), landmark)


def test_a_run_made_in_many_pieces_sees_what_a_run_made_whole_sees(tmp_path, monkeypatch):
    """Every tag in view detected, so the pieces' draws (which differ from a whole run's) leave
    the detections themselves as they were: the same landmarks from the same poses."""
    config = tmp_path / "all-seen.toml"
    config.write_text("[route]\nlength_m = 300.0\n[camera]\ndetection_probability = 1.0\n")
    whole = simulate("indoor-tags", tmp_path / "whole.mcap", seed=1, config_path=config)
    monkeypatch.setattr(common, "DETECTIONS_PER_PIECE", 7)
    monkeypatch.setattr(common, "ELEMENTS_PER_BLOCK", 5000)
    pieced = simulate("indoor-tags", tmp_path / "pieced.mcap", seed=1, config_path=config)
    assert (pieced.num_poses, pieced.num_detections) == (whole.num_poses, whole.num_detections)
    a, b = read_log(tmp_path / "whole.mcap"), read_log(tmp_path / "pieced.mcap")

    def seen(log) -> list[list[int]]:
        return [sorted(d.truth_landmark_id for d in m.detections) for m in log.detections]

    assert seen(a) == seen(b) and whole.num_detections > 50
    assert a.ground_truth_poses == b.ground_truth_poses
    assert (tmp_path / "whole.mcap").read_bytes() != (tmp_path / "pieced.mcap").read_bytes()


SHORT_RUNS = {  # a config, and the detections of a piece: several pieces
    "city-grid": ("[route]\nlength_m = 400.0\n", 20),
    "planar-park": ("[route]\nlength_m = 300.0\n", 20),
    "kitti05-cars": ("", 1000),  # the real path, 2761 keyframes
}


@pytest.mark.parametrize("scenario", with_slow(sorted(SHORT_RUNS)))
def test_every_scenario_makes_a_valid_log_in_pieces(tmp_path, monkeypatch, scenario):
    config = tmp_path / "short.toml"
    text, piece = SHORT_RUNS[scenario]
    config.write_text(text)
    whole = simulate(scenario, tmp_path / "whole.mcap", seed=2, config_path=config)
    monkeypatch.setattr(common, "DETECTIONS_PER_PIECE", piece)
    monkeypatch.setattr(common, "ELEMENTS_PER_BLOCK", 3000)
    pieced = simulate(scenario, tmp_path / "pieced.mcap", seed=2, config_path=config)
    log = read_log(tmp_path / "pieced.mcap")  # the contract's checks
    assert log.num_poses == pieced.num_poses == whole.num_poses
    assert log.num_detections == pieced.num_detections
    assert log.ground_truth_poses == read_log(tmp_path / "whole.mcap").ground_truth_poses
    # other draws, the same expectation: 10 standard errors of a Poisson count apart at most
    assert abs(pieced.num_detections - whole.num_detections) < 10 * math.sqrt(whole.num_detections)
    assert pieced.num_false_positives > 0 and whole.num_detections > 100


# What the bounds refuse, each in one line naming the keys, before anything is built.
TOO_LARGE = [
    (
        "city-grid",
        "[grid]\nstreets_x = 100\nstreets_y = 100\nblock_x_m = 100000.0\nblock_y_m = 100000.0\n",
        "grid.streets_x, streets_y, block_x_m, block_y_m and parking.slot_spacing_m (7 m) make "
        "5.66e+08 parking slots; at most 100000",
    ),
    (
        "city-grid",
        "[parking]\nslot_spacing_m = 1e-3\nslot_jitter_m = 0.0\n",
        "parking.slot_spacing_m (0.001 m) make 2.77e+06 parking slots",
    ),
    (  # the issue: "slot_spacing_m = 1e-6 blames slot_jitter_m"
        "city-grid",
        "[parking]\nslot_spacing_m = 1e-6\n",
        "parking.slot_spacing_m (1e-06 m) make 2.77e+09 parking slots",
    ),
    (
        "city-grid",
        "[parking]\nslot_spacing_m = 0.5\n",
        "'parking.slot_jitter_m' (0.3 m) must be < slot_spacing_m / 2 (0.25 m)",
    ),
    (
        "kitti05-cars",
        "[parking]\npath_step_m = 1e-6\n",
        "parking.path_step_m (1e-06 m) cuts the 2206 m path into 2.21e+09 samples; at most 1000000",
    ),
    (
        "kitti05-cars",
        "[parking]\npath_step_m = 0.01\nrevisit_radius_m = 100.0\n",
        "parking.revisit_radius_m / path_step_m (100 / 0.01) over 2.21e+05 samples makes 2.21e+09",
    ),
    (
        "kitti05-cars",
        "[parking]\ngap_min_m = 0.0\n[[vehicles]]\nname = 'ant'\nfrequency = 1.0\n"
        "length_m = 0.01\nwidth_m = 0.01\nheight_m = 0.01\n",
        "[[vehicles]] length_m and parking.gap_min_m (a car every 0.01 m at the closest) could "
        "park 4.41e+05 cars",
    ),
    (
        "kitti05-cars",
        "[parking]\nmin_separation_m = 100000.0\n",
        "parking.min_separation_m (100000 m) over cars",
    ),
    (
        "indoor-tags",
        "[floor]\ncorridor_x_m = [0.0, 2.0, 40.0]\n",
        "'floor.corridor_x_m': corridors closer than floor.corridor_width_m + 2 "
        "tags.junction_clearance_m (3 m)",
    ),
    ("indoor-tags", "[floor]\ncorridor_y_m = [0.0]\n", "'floor.corridor_y_m' needs at least two"),
    ("indoor-tags", "[floor]\ncorridor_y_m = [5.0, 0.0]\n", "'floor.corridor_y_m' must be in incr"),
    (
        "indoor-tags",
        f"[floor]\ncorridor_x_m = {[10.0 * i for i in range(60)]}\n"
        f"corridor_y_m = {[10.0 * i for i in range(60)]}\n",
        "floor.corridor_x_m x corridor_y_m make 3600 junctions; at most 2500",
    ),
    (
        "indoor-tags",
        "[floor]\ncorridor_width_m = 1e-6\ncorridor_x_m = [0.0, 0.01, 0.02]\n[tags]\n"
        "junction_clearance_m = 0.0\n[route]\nlength_m = 100000.0\nwander_amplitude_m = 0\n",
        "route.length_m (100000 m) between floor corridors 0.01 m apart makes 1.1e+07 turns",
    ),
]


@pytest.mark.parametrize(("scenario", "text", "message"), TOO_LARGE)
def test_sizes_that_would_exhaust_memory_are_refused_before_any_work(
    tmp_path, monkeypatch, capsys, scenario, text, message
):
    """Issue 53: these took 4 to 16 GB, or a traceback, before."""
    module = {"city-grid": city_grid, "indoor-tags": indoor_tags}.get(scenario)
    if module is not None:  # the checks on the config alone come before the world is built
        monkeypatch.setattr(module, "build_world", lambda *a: pytest.fail("built the world"))
    else:  # kitti05-cars: once the sequence is read, before the street is made of it
        monkeypatch.setattr(kitti05_cars, "street_of", lambda *a: pytest.fail("made the street"))
    config = tmp_path / "large.toml"
    config.write_text(text)
    assert (
        main(["simulate", scenario, "--out", str(tmp_path / "x.mcap"), "--config", str(config)])
        == 2
    )
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"config {config}: " in err and message in err, err
    assert [p.name for p in tmp_path.iterdir()] == ["large.toml"]


# Runs `mmslam` and prints its peak resident memory (KiB) after its own output.
# The process's own peak (VmHWM, KiB): getrusage's ru_maxrss keeps across exec the peak of the
# process it was forked from (the test runner, hundreds of MB late in the suite).
PEAK_MEMORY = """
import re, sys
from pathlib import Path
from pipeline.cli import main
status = main(sys.argv[1:])
print(status, re.search(r"VmHWM:\\s*(\\d+)", Path("/proc/self/status").read_text())[1])
"""


@pytest.mark.slow
def test_a_dense_world_is_made_in_bounded_memory(tmp_path):
    """20,000 tags along 1,500 keyframes: the visibility arrays of every keyframe against every
    tag took 3.6 GB at the peak (the issue: 100,000 tags, 6 GB, then out of memory); tags out
    of reach are not tested now, and the rest a block at a time."""
    config = tmp_path / "dense.toml"
    config.write_text("[tags]\ncount = 20000\nmin_spacing_m = 0.0\n[camera]\nmax_range_m = 1.3\n")
    args = [
        "simulate",
        "indoor-tags",
        "--out",
        str(tmp_path / "dense.mcap"),
        "--config",
        str(config),
    ]
    done = subprocess.run(
        [sys.executable, "-c", PEAK_MEMORY, *args], cwd=ROOT, capture_output=True, text=True
    )
    summary, result = done.stdout.splitlines()
    status, peak_kib = (int(v) for v in result.split())
    assert status == 0 and "1501 poses" in summary and "detections (0 false) of" in summary
    assert int(re.search(r"(\d+) detections", summary)[1]) > 1000
    assert peak_kib < 400 * 1024, f"peak {peak_kib / 1024:.0f} MiB"
