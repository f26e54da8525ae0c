"""Stereo range inside a box: the math by hand and by numerical derivatives, the matcher on a
synthetic shift, and on a real pair with ground truth (Middlebury's motorcycle, scikit-image)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from data_tools.bench_objects import TEDDY, teddy_grid
from pipeline.datasets.camera import StereoIntrinsics
from pipeline.errors import InputError
from pipeline.frontend import geometry as g
from pipeline.frontend import stereo_range as sr
from pipeline.frontend.config import load_frontend_config
from tests import real_data
from tests.numerics import numerical_jacobian

INTRINSICS = StereoIntrinsics(
    width=640, height=480, fx=700.0, fy=690.0, cx=320.0, cy=240.0, baseline=0.5
)
# The bare stereo point: no surface-to-centre offset (tested on its own below).
CONFIG = dataclasses.replace(
    load_frontend_config().objects.stereo, surface_to_centre=0.0, surface_to_centre_sigma=0.0
)


# --- pure math -------------------------------------------------------------------------------


def test_depth_and_its_noise_by_hand():
    assert sr.depth_from_disparity(35.0, 700.0, 0.5) == pytest.approx(10.0)
    # sigma_z = z^2 sigma_d / (f b) = 100 * 0.5 / 350
    assert sr.depth_sigma(10.0, 0.5, 700.0, 0.5) == pytest.approx(1.0 / 7.0)


def test_pixel_bearing_elevation_by_hand():
    k = INTRINSICS
    assert sr.pixel_bearing_elevation(k.cx, k.cy, k) == pytest.approx((0.0, 0.0))
    # One focal length right of the centre: 45 degrees to the right (negative bearing).
    assert sr.pixel_bearing_elevation(k.cx + k.fx, k.cy, k) == pytest.approx((-math.pi / 4, 0.0))
    # One focal length below: 45 degrees down.
    assert sr.pixel_bearing_elevation(k.cx, k.cy + k.fy, k) == pytest.approx((0.0, -math.pi / 4))
    # Up and left: ray (1, 1, 1) in the body frame.
    bearing, elevation = sr.pixel_bearing_elevation(k.cx - k.fx, k.cy - k.fy, k)
    assert bearing == pytest.approx(math.pi / 4)
    assert elevation == pytest.approx(math.atan2(1.0, math.sqrt(2.0)))


def test_bearing_and_elevation_do_not_depend_on_the_disparity():
    u, v = 500.0, 100.0
    expected = sr.pixel_bearing_elevation(u, v, INTRINSICS)
    for d in (2.0, 20.0, 90.0):
        point, covariance = sr.stereo_point(np.array([u, v, d]), np.eye(3), INTRINSICS)
        measurement, _ = sr.body_measurement(point, covariance)
        assert tuple(measurement[:2]) == pytest.approx(expected, abs=1e-12)


def test_camera_to_body_by_hand():
    point, covariance = sr.camera_to_body(np.array([1.0, 2.0, 3.0]), np.diag([1.0, 2.0, 3.0]))
    np.testing.assert_allclose(point, [3.0, -1.0, -2.0])
    np.testing.assert_allclose(covariance, np.diag([3.0, 1.0, 2.0]))


def test_box_pixel_covariance_by_hand():
    config = dataclasses.replace(
        CONFIG, center_sigma=3.0, center_sigma_fraction=0.1, disparity_sigma=0.5
    )
    covariance = sr.box_pixel_covariance((100.0, 50.0, 140.0, 90.0), config)  # 40 x 40 box
    np.testing.assert_allclose(covariance, np.diag([25.0, 25.0, 0.25]))  # hypot(3, 4) = 5
    # A spread of 1.2 px in the box's disparities: 0.5^2 + 1.2^2 = 1.69.
    covariance = sr.box_pixel_covariance((100.0, 50.0, 140.0, 90.0), config, spread=1.2)
    np.testing.assert_allclose(covariance, np.diag([25.0, 25.0, 1.69]))


def test_depth_variance_is_z2_sigma_d_over_fb():
    uvd = np.array([400.0, 300.0, 14.0])
    config = dataclasses.replace(CONFIG, disparity_sigma=0.7)
    point, covariance = sr.stereo_point(
        uvd, sr.box_pixel_covariance((380, 280, 420, 320), config), INTRINSICS
    )
    z = sr.depth_from_disparity(14.0, INTRINSICS.fx, INTRINSICS.baseline)
    assert point[2] == pytest.approx(z)
    expected = sr.depth_sigma(z, 0.7, INTRINSICS.fx, INTRINSICS.baseline)
    assert math.sqrt(covariance[2, 2]) == pytest.approx(expected, rel=1e-12)


def test_measurement_covariance_matches_numerical_jacobian():
    uvd = np.array([150.0, 330.0, 9.0])
    pixel_covariance = np.diag([4.0, 2.25, 0.36])

    def measurement(x: np.ndarray) -> np.ndarray:
        point_body = g.BODY_FROM_CAMERA_ROTATION @ g.triangulate(x, INTRINSICS)
        return g.bearing_elevation_range(point_body)

    jacobian = numerical_jacobian(measurement, uvd, step=1e-5)
    point, covariance = sr.stereo_point(uvd, pixel_covariance, INTRINSICS)
    values, measured = sr.body_measurement(point, covariance)
    np.testing.assert_allclose(values, measurement(uvd), rtol=1e-12)
    np.testing.assert_allclose(measured, jacobian @ pixel_covariance @ jacobian.T, rtol=1e-6)


# --- the robust statistic --------------------------------------------------------------------


def test_central_box_by_hand():
    # 100 x 40 px from (10.4, 20.0): rounded outwards to columns 10..111 (101 px) and rows
    # 20..60; half of each, centred: 50 columns from 10 + 25 = 35, 20 rows from 20 + 10 = 30.
    assert sr.central_box((10.4, 20.0, 110.2, 60.0), 0.5, 640, 480) == (35, 30, 85, 50)
    # Clipped to the image first: columns 600..640.
    assert sr.central_box((600.0, 0.0, 700.0, 10.0), 0.5, 640, 480) == (610, 2, 630, 7)
    assert sr.central_box((5.0, 5.0, 6.0, 6.0), 0.5, 640, 480) == (5, 5, 6, 6)


def test_robust_disparity_ignores_invalid_pixels_and_measures_the_spread():
    box = np.full((10, 20), 12.0)
    box[:, 15:] = 16.0  # a second surface in a quarter of the pixels
    box[3, 2:7] = np.nan  # unmatched pixels
    box[5, 0:3] = 0.5  # below min_disparity
    found = sr.robust_disparity(box, CONFIG)
    assert found is not None
    assert (found.total, found.valid) == (200, 200 - 5 - 3)
    assert found.disparity == pytest.approx(12.0, rel=1e-12)  # a median of 12s: round-off
    # 50 of the 192 valid values are 16: the upper quartile (at 143.25 of 191) lies among them.
    assert found.spread == pytest.approx((16.0 - 12.0) / 1.349)
    box[:, 15:] = 12.0
    assert sr.robust_disparity(box, CONFIG).spread == pytest.approx(0.0, abs=1e-12)


def test_robust_disparity_needs_enough_matches():
    box = np.full((10, 10), np.nan)
    box[5, 5] = 7.0  # 1 valid of 100 pixels
    assert sr.robust_disparity(box, CONFIG) is None
    assert (
        sr.robust_disparity(box, dataclasses.replace(CONFIG, min_valid_fraction=0.01)) is not None
    )
    assert sr.robust_disparity(np.empty((0, 0)), CONFIG) is None


def test_stereo_config_keys_are_checked(tmp_path):
    override = tmp_path / "frontend.toml"
    override.write_text("[objects.stereo]\nmax_disparity = 64\n")
    stereo = load_frontend_config(override).objects.stereo
    assert stereo.max_disparity == 64 and stereo.block_size == CONFIG.block_size  # merged
    for text, message in [
        ("[objects.stereo]\nmax_disp = 64\n", "unknown key 'objects.stereo.max_disp'"),
        ("[objects.stereo]\nmax_disparity = 100\n", "max_disparity"),
        ("[objects.stereo]\nblock_size = 4.5\n", "block_size"),
    ]:
        override.write_text(text)
        with pytest.raises(InputError, match=message):
            load_frontend_config(override)


def test_surface_to_centre_moves_the_point_along_its_ray():
    point = np.array([3.0, 0.0, 4.0])
    moved, covariance = sr.surface_to_centre(point, np.eye(3) * 0.01, 1.0, 0.5)
    np.testing.assert_allclose(moved, [3.6, 0.0, 4.8])  # 5 m -> 6 m, same direction
    ray = point / 5.0
    assert ray @ covariance @ ray == pytest.approx(0.01 + 0.25)
    side = np.array([0.0, 1.0, 0.0])
    assert side @ covariance @ side == pytest.approx(0.01)


# --- matching inside a box -------------------------------------------------------------------


def shifted_pair(disparity: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Random texture seen at one disparity everywhere: right(u) = left(u + d)."""
    rng = np.random.default_rng(seed)
    texture = rng.integers(0, 256, (240, 400 + disparity), dtype=np.uint8)
    texture = np.repeat(np.repeat(texture, 2, axis=0), 2, axis=1)[:240, : 400 + disparity]
    left = np.ascontiguousarray(texture[:, :400])
    right = np.ascontiguousarray(texture[:, disparity : disparity + 400])
    return left, right


@pytest.mark.parametrize("bbox", [(200.0, 80.0, 300.0, 160.0), (5.0, 100.0, 80.0, 150.0)])
def test_box_disparity_on_a_shifted_texture(bbox):
    # The second box touches the left border, where part of the search range is missing.
    left, right = shifted_pair(23)
    found = sr.robust_disparity(sr.box_disparities(left, right, bbox, CONFIG), CONFIG)
    assert found is not None
    assert found.disparity == pytest.approx(23.0, abs=0.25)


def test_measure_box_gives_the_point_at_the_box_centre():
    left, right = shifted_pair(35)
    k = StereoIntrinsics(400, 240, 700.0, 700.0, 200.0, 120.0, 0.5)
    bbox = (250.0, 60.0, 330.0, 140.0)
    found = sr.measure_box(left, right, bbox, k, CONFIG)
    assert found is not None
    z = 700.0 * 0.5 / 35.0
    np.testing.assert_allclose(
        found.point, [(290 - 200) * z / 700, (100 - 120) * z / 700, z], rtol=0.01
    )
    assert np.all(np.linalg.eigvalsh(found.covariance) > 0)


def test_a_box_without_texture_has_no_range():
    flat = np.full((240, 400), 128, np.uint8)
    assert sr.measure_box(flat, flat, (100.0, 50.0, 200.0, 150.0), INTRINSICS, CONFIG) is None


# --- a real pair with ground truth -----------------------------------------------------------

# Middlebury 2014 "Motorcycle", downsampled 4x as scikit-image ships it; calibration from
# skimage.data.stereo_motorcycle's documentation. `doffs`: the principal points' difference,
# so depth = f b / (d + doffs).
MOTORCYCLE_F = 994.978
MOTORCYCLE_BASELINE = 0.193001
MOTORCYCLE_DOFFS = 31.086
# Boxes drawn by hand around objects of the scene (u_min, v_min, u_max, v_max).
MOTORCYCLE_BOXES = {
    "fuel tank": (320, 150, 480, 240),
    "engine": (340, 240, 470, 370),
    "rear wheel": (120, 230, 290, 400),
    "front wheel": (510, 280, 680, 450),
    "bench": (50, 110, 280, 190),
    "cardboard box": (525, 30, 600, 95),
    "red crate": (530, 180, 610, 250),
}
# The bound: the box's median disparity within 1 px of the ground truth's median over the same
# central part, and so depth within 2 % (measured: at most 0.71 px, 0.99 %).
MAX_DISPARITY_ERROR_PX = 1.0
MAX_DEPTH_ERROR = 0.02


def test_box_range_agrees_with_middlebury_ground_truth():
    skimage_data = pytest.importorskip("skimage.data")
    import cv2

    left_rgb, right_rgb, truth = skimage_data.stereo_motorcycle()
    left = cv2.cvtColor(left_rgb, cv2.COLOR_RGB2GRAY)
    right = cv2.cvtColor(right_rgb, cv2.COLOR_RGB2GRAY)
    config = dataclasses.replace(CONFIG, max_disparity=64)  # the scene's disparities reach 60 px
    for name, bbox in MOTORCYCLE_BOXES.items():
        u0, v0, u1, v1 = sr.central_box(bbox, config.central_fraction, *left.shape[::-1])
        found = sr.robust_disparity(
            sr.box_disparities(left, right, (u0, v0, u1, v1), config), config
        )
        assert found is not None, name
        truth_box = truth[v0:v1, u0:u1].astype(float)
        truth_box[~np.isfinite(truth_box)] = np.nan
        expected = sr.robust_disparity(truth_box, config)
        assert expected is not None, name
        error = found.disparity - expected.disparity
        assert abs(error) <= MAX_DISPARITY_ERROR_PX, f"{name}: disparity off by {error:.2f} px"
        depth = sr.depth_from_disparity(
            found.disparity + MOTORCYCLE_DOFFS, MOTORCYCLE_F, MOTORCYCLE_BASELINE
        )
        true_depth = sr.depth_from_disparity(
            expected.disparity + MOTORCYCLE_DOFFS, MOTORCYCLE_F, MOTORCYCLE_BASELINE
        )
        assert abs(depth / true_depth - 1) <= MAX_DEPTH_ERROR, f"{name}: depth {depth:.3f} m"


# --- Middlebury's teddy (../shared/data/real): a grid of boxes -------------------------------


@real_data.needs(TEDDY / "disp2.png")
def test_logged_sigma_covers_the_range_error_over_a_grid_of_teddy_boxes():
    # Boxes of 30x40 to 150x120 px every 30 px. Before the check from the right image and the
    # spread in the covariance (measured on the grid at 15 px): 93 % within 3 sigmas, 42 boxes
    # over 20 % off, and 13 of 23 narrow boxes at the left border ranged (4 of them over 20 %
    # off, up to 20 times too far). Now 98.6 %, 11, none.
    grid = teddy_grid(CONFIG, step=30)
    assert grid.boxes >= 250 and grid.ranged >= 0.9 * grid.boxes
    assert grid.within_3_sigma >= 0.97 * grid.ranged
    assert grid.confident_and_wrong <= 0.02 * grid.ranged
    assert grid.border_boxes >= 3 and grid.border_ranged == 0


def test_a_box_whose_object_is_left_of_the_right_image_gets_no_range():
    # Texture at 60 px disparity; a box over columns 0-40: none of it is in the right image.
    left, right = shifted_pair(60)
    k = StereoIntrinsics(400, 240, 700.0, 700.0, 200.0, 120.0, 0.5)
    assert sr.measure_box(left, right, (0.0, 60.0, 40.0, 140.0), k, CONFIG) is None
    found = sr.measure_box(left, right, (100.0, 60.0, 140.0, 140.0), k, CONFIG)
    assert found is not None and found.uvd[2] == pytest.approx(60.0, abs=0.25)
