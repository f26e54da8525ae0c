"""Measurement models against numerical differentiation and against GTSAM."""

import gtsam
import numpy as np
import pytest

from pipeline import geometry as lie
from pipeline.backend import geometry as g
from pipeline.backend.factors import (
    body_point_covariance,
    direction_frame,
    point_measurement_factor,
)
from pipeline.log.messages import Detection
from tests.numerics import numerical_jacobian

# Every test draws from a generator of its own, so that what it draws does not hang on which
# tests ran before it (a -k or -m selection, another order).


def random_pose(rng: np.random.Generator, scale: float = 3.0) -> gtsam.Pose3:
    return gtsam.Pose3.Expmap(
        np.concatenate([rng.normal(size=3) * 0.5, rng.normal(size=3) * scale])
    )


def test_bearing_elevation_range_of_hand_computed_points():
    z = lie.bearing_elevation_range(np.array([[1.0, 1.0, 0.0], [0.0, 0.0, 2.0], [3.0, 0.0, 4.0]]))
    np.testing.assert_allclose(z[0], [np.pi / 4, 0.0, np.sqrt(2)])
    np.testing.assert_allclose(z[1, 1:], [np.pi / 2, 2.0])
    np.testing.assert_allclose(z[2], [0.0, np.arctan2(4, 3), 5.0])


def test_point_and_measurement_round_trip():
    rng = np.random.default_rng(10)
    p = rng.normal(size=(50, 3)) * 10
    np.testing.assert_allclose(
        lie.point_from_bearing_elevation_range(lie.bearing_elevation_range(p)), p, atol=1e-9
    )


def test_world_point_covariance_hand_computed():
    # Straight ahead at range 10, heading turned 90 degrees: range noise along world y,
    # bearing noise (10 m lever) along world -x, elevation noise along z.
    yaw = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    covariance = np.diag([0.01**2, 0.02**2, 0.5**2])
    C = g.world_point_covariance(yaw, np.array([0.0, 0.0, 10.0]), covariance)
    np.testing.assert_allclose(C, np.diag([0.1**2, 0.5**2, 0.2**2]), atol=1e-12)


def test_world_point_covariance_matches_sampled_detections():
    rng = np.random.default_rng(3)
    R = gtsam.Rot3.RzRyRx(0.3, -0.2, 1.1).matrix()
    z = np.array([0.4, -0.1, 12.0])
    covariance = np.diag([2e-3, 1e-3, 0.3]) ** 2
    samples = rng.multivariate_normal(z, covariance, size=200_000, method="cholesky")
    points = lie.point_from_bearing_elevation_range(samples) @ R.T
    np.testing.assert_allclose(
        np.cov(points.T), g.world_point_covariance(R, z, covariance), rtol=0.03, atol=1e-5
    )


def test_bearing_elevation_range_jacobian_matches_numerical():
    rng = np.random.default_rng(11)
    for p in rng.normal(size=(10, 3)) * 5:
        J = lie.bearing_elevation_range_jacobian(p)
        J_num = numerical_jacobian(g.bearing_elevation_range, p, lambda x, d: x + d, 3)
        np.testing.assert_allclose(J, J_num, atol=1e-6)


def test_predict_point_jacobians_match_numerical_on_right_perturbation():
    rng = np.random.default_rng(12)
    for _ in range(10):
        pose = random_pose(rng)
        landmark = pose.transformFrom(rng.normal(size=3) * 4 + np.array([6.0, 0, 0]))
        _, H_pose, H_landmark = g.predict_point(
            pose.rotation().matrix(), pose.translation(), landmark
        )

        def h_of_pose(p: gtsam.Pose3, lm: np.ndarray = landmark) -> np.ndarray:
            return g.predict_point(p.rotation().matrix(), p.translation(), lm)[0]

        def h_of_landmark(lm: np.ndarray, p: gtsam.Pose3 = pose) -> np.ndarray:
            return g.predict_point(p.rotation().matrix(), p.translation(), lm)[0]

        H_pose_num = numerical_jacobian(h_of_pose, pose, lambda p, d: p.retract(d), 6)
        H_lm_num = numerical_jacobian(h_of_landmark, landmark, lambda x, d: x + d, 3)
        np.testing.assert_allclose(H_pose, H_pose_num, atol=1e-6)
        np.testing.assert_allclose(H_landmark, H_lm_num, atol=1e-6)


def test_predict_point_batch_agrees_with_gtsam_transform():
    rng = np.random.default_rng(13)
    poses = [random_pose(rng) for _ in range(5)]
    points = rng.normal(size=(5, 3)) * 8
    R = np.stack([p.rotation().matrix() for p in poses])
    t = np.stack([p.translation() for p in poses])
    expected = [
        lie.bearing_elevation_range(p.transformTo(x)) for p, x in zip(poses, points, strict=True)
    ]
    np.testing.assert_allclose(g.predict_point_batch(R, t, points), expected, atol=1e-12)


def test_world_point_jacobian_matches_numerical():
    rng = np.random.default_rng(14)
    pose = random_pose(rng)
    p_body = np.array([5.0, -1.0, 0.5])
    J = g.world_point_jacobian_pose(pose.rotation().matrix(), p_body)
    J_num = numerical_jacobian(
        lambda p: p.transformFrom(p_body), pose, lambda p, d: p.retract(d), 6
    )
    np.testing.assert_allclose(J, J_num, atol=1e-6)


def test_point_residual_wraps_bearing():
    r = g.point_residual(np.array([np.pi - 0.01, 0.0, 1.0]), np.array([-np.pi + 0.01, 0.0, 1.5]))
    np.testing.assert_allclose(r, [-0.02, 0.0, -0.5], atol=1e-12)


def test_se3_log_matches_gtsam_logmap_including_small_angles():
    rng = np.random.default_rng(15)
    for scale in (1.0, 1e-3, 1e-9):
        xi = np.concatenate([rng.normal(size=3) * scale, rng.normal(size=3)])
        pose = gtsam.Pose3.Expmap(xi)
        ours = lie.se3_log(pose.rotation().matrix(), pose.translation())
        np.testing.assert_allclose(ours, gtsam.Pose3.Logmap(pose), atol=1e-9)


def test_so3_exp_inverts_log():
    rng = np.random.default_rng(16)
    w = rng.normal(size=(6, 3))
    np.testing.assert_allclose(lie.so3_log(lie.so3_exp(w)), w, atol=1e-9)


@pytest.mark.parametrize("angle", [0.0, 1e-12, 1e-6, 1e-3, 1.0, 3.0, np.pi - 1e-6, np.pi])
def test_so3_log_and_quaternion_match_gtsam_from_zero_to_pi(angle):
    rng = np.random.default_rng(17)
    axes = rng.normal(size=(20, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    rotations = [gtsam.Rot3.Expmap(axis * angle) for axis in axes]
    matrices = np.array([r.matrix() for r in rotations])
    logs = lie.so3_log(matrices)
    quaternions = lie.quaternion_from_rotation(matrices)
    for rotation, log, q in zip(rotations, logs, quaternions, strict=True):
        expected = gtsam.Rot3.Logmap(rotation)
        if angle > 3.0:  # at pi the axis' sign is either
            expected = expected if expected @ log >= 0 else -expected
        np.testing.assert_allclose(log, expected, atol=1e-9)
        theirs = rotation.toQuaternion()
        theirs = np.array([theirs.x(), theirs.y(), theirs.z(), theirs.w()])
        theirs = theirs if theirs[3] > 0 or (theirs[3] == 0 and theirs @ q > 0) else -theirs
        np.testing.assert_allclose(q, theirs, atol=1e-9)
        assert q[3] >= 0.0


def test_quaternion_of_hand_computed_rotations():
    half = np.sqrt(0.5)
    about_z = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # 90 deg about z
    np.testing.assert_allclose(lie.quaternion_from_rotation(about_z), [0, 0, half, half])
    flip_x = np.diag([1.0, -1.0, -1.0])  # 180 deg about x: w = 0
    np.testing.assert_allclose(lie.quaternion_from_rotation(flip_x), [1, 0, 0, 0], atol=1e-15)
    np.testing.assert_allclose(lie.so3_log(flip_x), [np.pi, 0, 0], atol=1e-15)
    np.testing.assert_allclose(lie.so3_log(np.eye(3)), [0, 0, 0])
    stacked = lie.so3_log(np.broadcast_to(about_z, (2, 4, 3, 3)))
    np.testing.assert_allclose(stacked, np.broadcast_to([0, 0, np.pi / 2], (2, 4, 3)))


def test_pose_residual_matches_gtsam_between_factor_error():
    rng = np.random.default_rng(18)
    x, lm = random_pose(rng), random_pose(rng)
    z = x.between(lm).compose(gtsam.Pose3.Expmap(rng.normal(size=6) * 0.05))
    ours = g.pose_residual_batch(
        x.rotation().matrix(),
        x.translation(),
        lm.rotation().matrix(),
        lm.translation(),
        z.rotation().matrix(),
        z.translation(),
    )
    np.testing.assert_allclose(ours, z.localCoordinates(x.between(lm)), atol=1e-9)


def test_pose_residual_jacobians_match_numerical_at_zero_residual():
    rng = np.random.default_rng(19)
    x, lm = random_pose(rng), random_pose(rng)
    z = x.between(lm)
    H_x, H_l = g.pose_residual_jacobians(
        x.rotation().matrix(), x.translation(), lm.rotation().matrix(), lm.translation()
    )

    def residual(a: gtsam.Pose3, b: gtsam.Pose3) -> np.ndarray:
        return z.localCoordinates(a.between(b))

    H_x_num = numerical_jacobian(lambda a: residual(a, lm), x, lambda p, d: p.retract(d), 6)
    H_l_num = numerical_jacobian(lambda b: residual(x, b), lm, lambda p, d: p.retract(d), 6)
    np.testing.assert_allclose(H_x, H_x_num, atol=1e-6)
    np.testing.assert_allclose(H_l, H_l_num, atol=1e-6)


def _factor_and_ours(bearing, elevation, cov, dz):
    det = Detection(0, 1.0, bearing, elevation, 8.0, tuple(cov.ravel()), "bbox")
    values = gtsam.Values()
    values.insert(0, gtsam.Pose3())
    values.insert(
        1, lie.point_from_bearing_elevation_range(np.array([bearing, elevation, 8.0]) + dz)
    )
    factor = point_measurement_factor(0, 1, det)
    return 2.0 * factor.error(values), dz @ np.linalg.solve(cov, dz)


# (-2.0, -0.4) looks along a direction whose x and z components nearly tie, where GTSAM's Unit3
# basis flips; (0.0, 0.0) is a planar sensor straight ahead, elevation far tighter than bearing.
@pytest.mark.parametrize("bearing,elevation", [(0.3, 0.1), (-2.0, -0.4), (3.0, 0.8), (0.0, 0.0)])
def test_point_factor_weighs_residuals_with_the_whole_detection_covariance(bearing, elevation):
    """Near the measurement, the factor's error is the detection's own Mahalanobis distance in
    (bearing, elevation, range), correlations included (they agree to first order: the
    Cartesian residual's angles scale with the range, so a range error of 1 % changes the
    angles' weight by 1 %)."""
    rng = np.random.default_rng(20)
    # anisotropic and correlated: bearing 0.03, elevation 0.005, range 0.3
    cov = np.array([[9e-4, 3e-5, 0.0], [3e-5, 2.5e-5, 1e-4], [0.0, 1e-4, 0.09]])
    for _ in range(5):
        dz = rng.multivariate_normal(np.zeros(3), cov, method="cholesky") * 0.01
        theirs, ours = _factor_and_ours(bearing, elevation, cov, dz)
        assert theirs == pytest.approx(ours, rel=5e-3)


def test_body_point_covariance_hand_computed():
    # elevation 60 degrees halves the bearing's span across; range 2 m doubles the angles'
    sb, se, sr = 0.02, 0.03, 0.5
    offset = body_point_covariance(np.pi / 3, 2.0, np.diag([sb**2, se**2, sr**2]))
    np.testing.assert_allclose(offset, np.diag([0.02**2, 0.06**2, 0.25]), atol=1e-15)


def cartesian_residual(det: Detection, pose: gtsam.Pose3, landmark: np.ndarray) -> np.ndarray:
    """The point factor's model written out: R^T (l - t) minus the detected point, whitened by
    the detection's covariance carried to the point (first order), in the body frame."""
    z = np.array([det.bearing, det.elevation, det.range])
    point = lie.point_from_bearing_elevation_range(z)
    to_point = np.linalg.inv(lie.bearing_elevation_range_jacobian(point))
    covariance = to_point @ np.reshape(det.covariance, (3, 3)) @ to_point.T
    whitening = np.linalg.cholesky(np.linalg.inv(covariance)).T
    return whitening @ (pose.transformTo(landmark) - point)


CORRELATED = np.array([[9e-4, 3e-5, 1e-4], [3e-5, 2.5e-5, 1e-4], [1e-4, 1e-4, 0.09]])


@pytest.mark.parametrize(
    "bearing,elevation,range_m",
    [(0.3, 0.1, 8.0), (-2.0, -0.4, 1.8), (3.0, 0.8, 40.0), (0.0, 0.0, 12.0)],
)
def test_point_factor_is_the_cartesian_residual_with_its_jacobians(bearing, elevation, range_m):
    """Error and Jacobians are those of R^T (l - t) - p whitened by the detection's covariance,
    near the measurement and metres away from it, behind the sensor included."""
    rng = np.random.default_rng(21)
    det = Detection(0, 1.0, bearing, elevation, range_m, tuple(CORRELATED.ravel()), "bbox")
    factor = point_measurement_factor(0, 1, det)
    point = lie.point_from_bearing_elevation_range(np.array([bearing, elevation, range_m]))
    for offset in (0.1, 3.0, 2.0 * range_m):  # the last puts the landmark behind the pose
        pose = random_pose(rng)
        landmark = pose.transformFrom(point + rng.normal(size=3) * offset / np.sqrt(3))
        values = gtsam.Values()
        values.insert(0, pose)
        values.insert(1, landmark)
        ours = cartesian_residual(det, pose, landmark)
        # the orthographic limit is reached to (offset / ORTHOGRAPHIC_DISTANCE_M)
        assert factor.error(values) == pytest.approx(0.5 * ours @ ours, rel=2e-3)
        A, _ = factor.linearize(values).jacobian()
        H_pose = numerical_jacobian(
            lambda x, lm=landmark: cartesian_residual(det, x, lm),
            pose,
            lambda x, d: x.retract(d),
            6,
        )
        H_lm = numerical_jacobian(lambda lm, x=pose: cartesian_residual(det, x, lm), landmark)
        expected = np.hstack([H_pose, H_lm])
        # Both whitenings are square roots of the same information: compare A^T A.
        information = expected.T @ expected
        assert np.linalg.norm(A.T @ A - information) < 5e-3 * np.linalg.norm(information)
        assert np.linalg.matrix_rank(A[:, 6:]) == 3


def test_direction_frame_looks_along_the_detection():
    frame = direction_frame(0.4, -0.3)
    np.testing.assert_allclose(frame.T @ frame, np.eye(3), atol=1e-12)
    assert np.linalg.det(frame) == pytest.approx(1.0)
    np.testing.assert_allclose(
        frame[:, 2], lie.point_from_bearing_elevation_range(np.array([0.4, -0.3, 1.0])), atol=1e-12
    )
    assert frame[2, 0] == pytest.approx(0.0)  # "left" is horizontal


def test_batched_point_prediction_matches_one_by_one():
    rng = np.random.default_rng(22)
    pose = random_pose(rng)
    landmarks = pose.transformFrom(np.array([8.0, 1.0, 0.5])) + rng.normal(size=(6, 3))
    R, t = pose.rotation().matrix(), pose.translation()
    z, H_pose, H_lm = g.predict_point_jacobians_batch(R, t, landmarks)
    for k, landmark in enumerate(landmarks):
        z1, H_pose1, H_lm1 = g.predict_point(R, t, landmark)
        np.testing.assert_allclose(z[k], z1, atol=1e-12)
        np.testing.assert_allclose(H_pose[k], H_pose1, atol=1e-12)
        np.testing.assert_allclose(H_lm[k], H_lm1, atol=1e-12)


def test_a_detection_at_the_zenith_keeps_a_span_across_its_line_of_sight():
    """Straight up, a bearing spans nothing across the line of sight; the span is taken as a
    bearing's at 1.5 rad, so the covariance stays positive definite and close to the one 86
    degrees up (straight up, every method's solver fell back)."""
    cov = np.diag([1e-4, 1e-4, 1e-2])
    zenith = body_point_covariance(np.pi / 2, 5.0, cov)
    assert np.linalg.eigvalsh(zenith)[0] == pytest.approx((np.cos(1.5) * 5.0) ** 2 * 1e-4)
    np.testing.assert_allclose(zenith, body_point_covariance(1.5, 5.0, cov), rtol=1e-12)
    below = body_point_covariance(1.4, 5.0, cov)  # below 1.5 rad the bearing's own span
    assert below[0, 0] == pytest.approx((np.cos(1.4) * 5.0) ** 2 * 1e-4, rel=1e-12)
