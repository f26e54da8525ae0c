"""The two worlds made to test association on: city-grid (aliased streets of parked vehicles)
and planar-park (a planar scanner among trees, biased odometry, misstated noise)."""

import math

import numpy as np
import pytest

from data_tools.scenarios import city_grid, load_config, simulate
from data_tools.scenarios.geometry import inside_any
from pipeline.backend.planar import is_planar
from pipeline.log import read_log
from tests.test_scenarios import (
    assert_standard_normal,
    contract_measurement,
    odometry_residuals,
    true_detections,
)


@pytest.fixture(scope="module")
def city(tmp_path_factory):
    path = tmp_path_factory.mktemp("city") / "city.mcap"
    simulate("city-grid", path, seed=1, misclassification=0.1, foxglove=False)
    return read_log(path)


@pytest.fixture(scope="module")
def park(tmp_path_factory):
    path = tmp_path_factory.mktemp("park") / "park.mcap"
    simulate("planar-park", path, seed=1, foxglove=False)
    return read_log(path)


def test_city_vehicles_stand_in_regular_slots_along_the_kerbs():
    config = load_config("city-grid")
    world = city_grid.build_world(config)
    p = config.parking
    xs, ys = city_grid.street_lines(config.grid)
    for v in world.vehicles[:, :2]:
        # on a kerb line: kerb_offset_m from a street's centre line, one way or the other
        off_x = np.min(np.abs(np.abs(v[0] - np.array(xs)) - p.kerb_offset_m))
        off_y = np.min(np.abs(np.abs(v[1] - np.array(ys)) - p.kerb_offset_m))
        assert min(off_x, off_y) < 1e-9
    # along a kerb, neighbours are whole slots apart, give or take the jitter
    kerb = world.vehicles[np.isclose(world.vehicles[:, 1], ys[0] + p.kerb_offset_m)]
    kerb = kerb[(kerb[:, 0] > xs[0]) & (kerb[:, 0] < xs[1])]
    gaps = np.diff(np.sort(kerb[:, 0]))
    slots = np.round(gaps / p.slot_spacing_m)
    assert len(gaps) >= 3 and np.all(slots >= 1)
    assert np.all(np.abs(gaps - slots * p.slot_spacing_m) <= 2 * p.slot_jitter_m + 1e-9)


def test_city_measurement_noise_matches_the_written_covariance(city):
    rows = true_detections(city)
    residuals = np.array([[d.bearing, d.elevation, d.range] for _, d, _ in rows]) - np.array(
        [contract_measurement(p) for _, _, p in rows]
    )
    sigmas = np.array([np.sqrt(np.diag(np.reshape(d.covariance, (3, 3)))) for _, d, _ in rows])
    residuals[:, 0] = (residuals[:, 0] + np.pi) % (2 * np.pi) - np.pi
    assert_standard_normal(residuals / sigmas, "city-grid measurement residuals / sigmas")


def test_city_sees_no_vehicle_through_a_building(city):
    config = load_config("city-grid")
    world = city_grid.build_world(config)
    poses = np.array([np.array(m.translation) for m in city.ground_truth_poses])
    landmarks = {lm.id: np.array(lm.position) for lm in city.ground_truth_landmarks.landmarks}
    # buildings in the log's frame: the world shifted so that pose 0 is the origin
    shift = world.poses[0, :2, 3]
    buildings = world.buildings - np.tile(shift, 2)
    for k, det, _ in true_detections(city)[::7]:
        start, end = poses[k, :2], landmarks[det.truth_landmark_id][:2]
        samples = start + np.linspace(0.05, 0.95, 50)[:, None] * (end - start)
        assert not inside_any(samples, buildings).any()


def test_city_streets_are_driven_again(city):
    stamps = city.pose_stamps_ns()
    first: dict[int, int] = {}
    revisits = set()
    for message in city.detections:
        for det in message.detections:
            if det.truth_landmark_id < 0:
                continue
            seen = first.setdefault(det.truth_landmark_id, stamps[message.pose_index])
            if stamps[message.pose_index] - seen > 60e9:
                revisits.add(det.truth_landmark_id)
    assert len(revisits) > 0.3 * len(first)


@pytest.mark.slow
def test_park_is_planar(park):
    # the back-end's own test: height, roll, pitch and elevation zero to round-off
    assert is_planar(park)
    _, cov = odometry_residuals(park)
    flat = load_config("planar-park").odometry.stated_flat_variance
    np.testing.assert_allclose(cov[:, [0, 1, 5], [0, 1, 5]], flat)


@pytest.mark.slow
def test_park_bearing_noise_is_smaller_than_the_log_says(park):
    rows = true_detections(park)
    scanner = load_config("planar-park").scanner
    bearing = np.array([d.bearing for _, d, _ in rows]) - np.array(
        [math.atan2(p[1], p[0]) for _, _, p in rows]
    )
    bearing = (bearing + np.pi) % (2 * np.pi) - np.pi
    stated = np.sqrt([np.reshape(d.covariance, (3, 3))[0, 0] for _, d, _ in rows])
    np.testing.assert_allclose(stated, scanner.stated_sigma_bearing_rad)
    assert np.std(bearing) == pytest.approx(scanner.sigma_bearing_rad, rel=0.1)


@pytest.mark.slow
def test_park_odometry_errs_by_a_slow_bias(park):
    xi, _ = odometry_residuals(park)
    yaw = xi[:, 2]
    lag1 = np.corrcoef(yaw[:-1], yaw[1:])[0, 1]
    assert lag1 > 0.8  # white noise would give about 0
    # and the drift over the run is far beyond what the stated sigmas allow
    stated = load_config("planar-park").odometry.stated_sigma_yaw_rad
    assert abs(np.sum(yaw)) > 5 * stated * math.sqrt(len(yaw))


@pytest.mark.slow
def test_park_has_clutter(park):
    false = [d for m in park.detections for d in m.detections if d.truth_landmark_id == -1]
    assert len(false) > 100
