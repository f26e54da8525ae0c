"""The front-end's camera and pose math against hand-computed values, GTSAM and numerical
derivatives."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from pipeline.datasets.camera import StereoIntrinsics
from pipeline.frontend import geometry as g
from tests.numerics import numerical_jacobian

INTRINSICS = StereoIntrinsics(
    width=640, height=480, fx=500.0, fy=480.0, cx=320.0, cy=240.0, baseline=0.5
)


def test_body_from_camera_turns_optical_axes_into_rep103():
    # Camera z (forward) is body x; camera x (right) is body -y; camera y (down) is body -z.
    r = g.BODY_FROM_CAMERA_ROTATION
    np.testing.assert_allclose(r @ [0, 0, 1], [1, 0, 0])
    np.testing.assert_allclose(r @ [1, 0, 0], [0, -1, 0])
    np.testing.assert_allclose(r @ [0, 1, 0], [0, 0, -1])


def test_bearing_elevation_range_by_hand():
    np.testing.assert_allclose(g.bearing_elevation_range([1.0, 1.0, 0.0]), [np.pi / 4, 0, 2**0.5])
    np.testing.assert_allclose(g.bearing_elevation_range([1.0, 0.0, 1.0]), [0, np.pi / 4, 2**0.5])
    np.testing.assert_allclose(g.bearing_elevation_range([0.0, -2.0, 0.0]), [-np.pi / 2, 0, 2])
    point = np.array([3.0, -1.0, 0.5])
    np.testing.assert_allclose(
        g.point_from_bearing_elevation_range(g.bearing_elevation_range(point)), point
    )


def test_bearing_elevation_range_jacobian_is_the_derivative():
    for point in ([4.0, 1.0, 0.3], [-2.0, 3.0, -1.0], [0.5, -0.2, 2.0]):
        expected = numerical_jacobian(g.bearing_elevation_range, np.array(point))
        np.testing.assert_allclose(g.bearing_elevation_range_jacobian(point), expected, atol=1e-7)


def test_triangulate_by_hand_and_back():
    # At the principal point with disparity fx*b/10 the point is 10 m straight ahead.
    point = g.triangulate([320.0, 240.0, 500.0 * 0.5 / 10.0], INTRINSICS)
    np.testing.assert_allclose(point, [0.0, 0.0, 10.0])
    # 100 px right and 48 px down at 5 m: x = 100 * 5 / 500 = 1, y = 48 * 5 / 480 = 0.5.
    point = g.triangulate([420.0, 288.0, 50.0], INTRINSICS)
    np.testing.assert_allclose(point, [1.0, 0.5, 5.0])
    np.testing.assert_allclose(g.project(point, INTRINSICS), [420.0, 288.0])
    right = g.project(g.right_camera_points(point, INTRINSICS), INTRINSICS)
    np.testing.assert_allclose(420.0 - right[0], 50.0)  # the disparity comes back


def test_camera_jacobians_are_the_derivatives():
    uvd = np.array([400.0, 100.0, 12.5])
    np.testing.assert_allclose(
        g.triangulation_jacobian(uvd, INTRINSICS),
        numerical_jacobian(lambda x: g.triangulate(x, INTRINSICS), uvd),
        rtol=1e-6,
    )
    point = np.array([0.7, -0.4, 6.0])
    np.testing.assert_allclose(
        g.projection_jacobian(point, INTRINSICS),
        numerical_jacobian(lambda x: g.project(x, INTRINSICS), point),
        rtol=1e-6,
    )


def test_stereo_pixel_covariance_shares_the_left_column_noise():
    # (u, v, d) = (uL, v, uL - uR) with independent noise s on uL, v, uR.
    covariance = g.stereo_pixel_covariance(0.5)
    a = np.array([[1, 0, 0], [0, 1, 0], [1, 0, -1]])
    np.testing.assert_allclose(covariance, a @ (0.25 * np.eye(3)) @ a.T)


def test_stereo_point_measurement_straight_ahead_by_hand():
    # 10 m ahead: bearing 0, elevation 0; sigma_range = z^2 sigma_d / (fx b) with
    # sigma_d = sqrt(2) sigma; sigma_bearing = sigma / fx, sigma_elevation = sigma / fy.
    sigma = 0.1
    uvd = np.array([320.0, 240.0, 25.0])
    measurement, covariance = g.stereo_point_measurement(
        uvd, g.stereo_pixel_covariance(sigma), INTRINSICS
    )
    np.testing.assert_allclose(measurement, [0.0, 0.0, 10.0], atol=1e-12)
    sigma_d = np.sqrt(2) * sigma
    assert np.sqrt(covariance[2, 2]) == pytest.approx(100.0 * sigma_d / 250.0)
    assert np.sqrt(covariance[0, 0]) == pytest.approx(sigma / 500.0)
    assert np.sqrt(covariance[1, 1]) == pytest.approx(sigma / 480.0)


def test_stereo_point_measurement_covariance_matches_monte_carlo():
    rng = np.random.default_rng(3)
    uvd = np.array([500.0, 150.0, 20.0])
    pixel_covariance = g.stereo_pixel_covariance(0.3)
    _, covariance = g.stereo_point_measurement(uvd, pixel_covariance, INTRINSICS)
    samples = rng.multivariate_normal(uvd, pixel_covariance, size=20000, method="cholesky")
    body = g.triangulate(samples, INTRINSICS) @ g.BODY_FROM_CAMERA_ROTATION.T
    empirical = np.cov(g.bearing_elevation_range(body).T)
    np.testing.assert_allclose(np.sqrt(np.diag(empirical)), np.sqrt(np.diag(covariance)), rtol=0.05)


def test_so3_and_se3_agree_with_gtsam():
    rng = np.random.default_rng(0)
    for _ in range(5):
        xi = rng.normal(size=6)
        expected = gtsam.Pose3.Expmap(xi).matrix()
        np.testing.assert_allclose(g.se3_exp(xi), expected, atol=1e-10)
        np.testing.assert_allclose(g.so3_log(g.so3_exp(xi[:3] * 0.5)), xi[:3] * 0.5, atol=1e-10)
        pose = gtsam.Pose3(expected)
        np.testing.assert_allclose(g.pose_adjoint(expected), pose.AdjointMap(), atol=1e-10)
        q = pose.rotation().toQuaternion()
        quaternion = np.array([q.x(), q.y(), q.z(), q.w()]) * np.sign(q.w())
        np.testing.assert_allclose(g.quaternion_from_rotation(expected[:3, :3]), quaternion)
        np.testing.assert_allclose(
            g.rotation_from_quaternion(quaternion), expected[:3, :3], atol=1e-12
        )
    # log near pi, where the antisymmetric part vanishes
    omega = np.array([0.0, 1.0, 1.0]) / np.sqrt(2) * (np.pi - 1e-6)
    np.testing.assert_allclose(g.so3_log(g.so3_exp(omega)), omega, atol=1e-5)


def test_conjugation_moves_right_perturbations_with_the_adjoint():
    rng = np.random.default_rng(1)
    frame = g.se3_exp(rng.normal(size=6))
    pose = g.se3_exp(rng.normal(size=6))
    xi = rng.normal(size=6) * 1e-3
    covariance = np.diag(rng.uniform(0.1, 1.0, 6))
    new_pose, new_covariance = g.conjugate_pose(frame, pose, covariance)
    # A (T Exp(xi)) A^-1 == (A T A^-1) Exp(Ad_A xi), exactly.
    lhs = frame @ pose @ g.se3_exp(xi) @ g.invert_pose(frame)
    rhs = new_pose @ g.se3_exp(g.pose_adjoint(frame) @ xi)
    np.testing.assert_allclose(lhs, rhs, atol=1e-12)
    adjoint = g.pose_adjoint(frame)
    np.testing.assert_allclose(new_covariance, adjoint @ covariance @ adjoint.T)


def test_camera_motion_forward_is_body_motion_forward():
    camera_motion = np.eye(4)
    camera_motion[2, 3] = 1.0  # 1 m along the optical axis
    camera_motion[:3, :3] = g.so3_exp([0.0, -0.1, 0.0])  # turning left = about camera -y
    covariance = np.diag([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    motion, body_covariance = g.camera_to_body_motion(camera_motion, covariance)
    np.testing.assert_allclose(motion[:3, 3], [1.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(g.so3_log(motion[:3, :3]), [0.0, 0.0, 0.1], atol=1e-12)
    # camera (x, y, z) variances become body (z, x, y) ones: body x <- camera z, etc.
    np.testing.assert_allclose(np.diag(body_covariance), [3.0, 1.0, 2.0, 6.0, 4.0, 5.0])


def test_camera_point_measurement_matches_stereo_one():
    uvd = np.array([250.0, 300.0, 30.0])
    pixel_covariance = g.stereo_pixel_covariance(0.2)
    point = g.triangulate(uvd, INTRINSICS)
    jacobian = g.triangulation_jacobian(uvd, INTRINSICS)
    via_point = g.camera_point_measurement(point, jacobian @ pixel_covariance @ jacobian.T)
    via_pixel = g.stereo_point_measurement(uvd, pixel_covariance, INTRINSICS)
    np.testing.assert_allclose(via_point[0], via_pixel[0])
    np.testing.assert_allclose(via_point[1], via_pixel[1], rtol=1e-9, atol=1e-15)
