"""`mmslam convert`: 2-D landmark files (GTSAM's text format) to contract logs, hand-checked,
refused in one line where a line cannot be taken, and the real Victoria Park file converted."""

import json
import math
from pathlib import Path

import gtsam
import numpy as np
import pytest

from data_tools.landmarks2d import (
    bearing_range_covariance,
    convert_landmarks2d,
    load_landmarks2d_config,
    parse_landmarks2d,
    step_covariance,
)
from data_tools.plot_runs import read_tum
from pipeline.backend.planar import is_planar
from pipeline.cli import main as cli_main
from pipeline.errors import InputError
from pipeline.log import read_log

VICTORIA_PARK = Path(gtsam.__file__).parent / "Data" / "victoria_park.txt"
EXAMPLE_GRAPH = Path(gtsam.__file__).parent / "Data" / "example.graph"

SMALL = """\
# two steps, three sightings; ids shared between poses and landmarks, as in Victoria Park
VERTEX2 0 0 0 0
ODOMETRY 0 1 1.0 0.0 0.1 0.0001 0 0 4e-06 0 4e-06
LANDMARK 1 5 3.0 4.0 0.25 0 0.25
ODOMETRY 1 2 0.5 0.1 -0.2 0.0001 2e-06 0 4e-06 0 9e-06
BR 2 6 4.0 10.0 0.05 0.2
LANDMARK 2 5 2.0 -1.0 0.4 0.1 0.3
"""


def write(tmp_path: Path, text: str, name: str = "data.txt") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_step_covariance_reads_a_covariance_or_toros_information_by_its_zeros():
    cov = step_covariance(np.array([1e-4, 2e-6, 3e-6, 4e-6, 5e-7, 9e-6]))
    np.testing.assert_allclose(
        cov, [[1e-4, 2e-6, 3e-6], [2e-6, 4e-6, 5e-7], [3e-6, 5e-7, 9e-6]], rtol=0, atol=0
    )
    # ff fs ss rr fr sr with fs = fr = sr = 0: TORO's information, theta last
    information = step_covariance(np.array([100.0, 0.0, 400.0, 2500.0, 0.0, 0.0]))
    np.testing.assert_allclose(information, np.diag([0.01, 0.0025, 0.0004]), rtol=1e-12)


def test_a_point_covariance_is_carried_to_bearing_and_range():
    # a point 5 m along x with 0.1 m sigma across and 0.2 m along: bearing 0.02 rad, range 0.2
    cov = bearing_range_covariance(5.0, 0.0, np.diag([0.04, 0.01]))
    np.testing.assert_allclose(cov, np.diag([0.0004, 0.04]), atol=1e-15)
    # at 45 degrees an isotropic covariance stays isotropic, the bearing's divided by r^2
    cov = bearing_range_covariance(3.0, 3.0, 0.5 * np.eye(2))
    np.testing.assert_allclose(cov, np.diag([0.5 / 18.0, 0.5]), atol=1e-15)


def test_a_small_file_becomes_a_planar_log_with_its_ids_as_truth(tmp_path):
    out = tmp_path / "small.mcap"
    summary = convert_landmarks2d(write(tmp_path, SMALL), out)
    assert (summary.num_poses, summary.num_detections, summary.num_landmarks) == (3, 3, 2)
    log = read_log(out)
    assert log.num_poses == 3 and is_planar(log)
    step = log.odometry[1]
    assert step.translation == (0.5, 0.1, 0.0)
    assert 2 * math.atan2(step.rotation[2], step.rotation[3]) == pytest.approx(-0.2, abs=1e-15)
    cov = np.reshape(step.covariance, (6, 6))
    flat = load_landmarks2d_config().flat_sigma ** 2
    # (x, y, theta) at (tx, ty, rz); height, roll, pitch at the flat sigma
    np.testing.assert_allclose(cov[np.ix_([3, 4, 2], [3, 4, 2])], step_covariance(
        np.array([1e-4, 2e-6, 0.0, 4e-6, 0.0, 9e-6])), atol=0)  # fmt: skip
    np.testing.assert_allclose(np.diag(cov)[[0, 1, 5]], [flat] * 3, rtol=1e-12)
    by_pose = {m.pose_index: m.detections for m in log.detections}
    (first,) = by_pose[1]
    assert (first.truth_landmark_id, first.elevation) == (5, 0.0)
    assert first.bearing == pytest.approx(math.atan2(4.0, 3.0)) and first.range == 5.0
    br, second = by_pose[2]
    assert (br.truth_landmark_id, br.range) == (6, 10.0)
    assert br.bearing == pytest.approx(4.0 - 2 * math.pi, abs=1e-15)  # wrapped: round-off
    np.testing.assert_allclose(np.reshape(br.covariance, (3, 3))[[0, 2], [0, 2]], [0.0025, 0.04])
    assert second.truth_landmark_id == 5
    assert log.pose_stamps_ns() == [0, 100_000_000, 200_000_000]


@pytest.mark.parametrize(
    "line,why",
    [
        ("ODOMETRY 2 3 1.0 0 0 1e-4 0 0 4e-6 0", "line 6: 11 numbers expected"),
        ("EDGE2 5 6 1.0 0 0 1e-4 0 0 4e-6 0 4e-6", "line 6: the step 5 -> 6 does not continue"),
        ("ODOMETRY 2 3 1 0 0 -1e-4 0 0 4e-6 0 4e-6", "line 6: the covariance is not positive"),
        ("LANDMARK 2 7 0 0 0.1 0 0.1", "line 6: a landmark seen at range 0"),
        ("LANDMARK 2 7 1 x 0.1 0 0.1", "line 6: not a number"),
        ("LANDMARK 2.5 7 1 1 0.1 0 0.1", "line 6: ids are integers"),
        ("BR 9 7 0.1 5.0 0.1 0.2", "landmark 7 seen from 9, no pose"),
        ("POINT3 1 2 3", "line 6: unknown tag 'POINT3'"),
    ],
)
def test_a_line_it_cannot_take_is_refused_in_one_line_and_nothing_is_written(
    tmp_path, capsys, line, why
):
    source = write(tmp_path, "\n".join([*SMALL.splitlines()[:5], line]) + "\n")
    with pytest.raises(InputError, match=why):
        parse_landmarks2d(source)
    out = tmp_path / "kept.mcap"
    out.write_bytes(b"an earlier log")
    assert cli_main(["convert", str(source), "--out", str(out)]) == 2
    error = capsys.readouterr().err.strip()
    assert "\n" not in error and str(source) in error
    assert out.read_bytes() == b"an earlier log"


def test_victoria_park_converts_whole():
    data = parse_landmarks2d(VICTORIA_PARK)
    assert len(data.pose_ids()) == 6969 and len(data.sightings) == 3640
    assert len({s.landmark_id for s in data.sightings}) == 151
    ranges = np.array([s.range for s in data.sightings])
    assert ranges.min() > 1.0 and ranges.max() < 100.0


@pytest.mark.slow
@pytest.mark.e2e
def test_a_small_real_dataset_replays_with_its_associations(tmp_path):
    """GTSAM's example.graph (95 poses, 422 bearing-range sightings of 24 landmarks): Known DA
    and MM + NH both end with every association right and no solver fallback."""
    log = tmp_path / "example.mcap"
    convert_landmarks2d(EXAMPLE_GRAPH, log)
    for method in ("known", "mm-nh"):
        assert cli_main(["replay", str(log), "--method", method, "--out", str(tmp_path / method),
                         "-q"]) == 0  # fmt: skip
        metrics = json.loads((tmp_path / method / "metrics.json").read_text())
        assert metrics["association_one_to_one"]["correct"] == 422
        assert metrics["solver_fallbacks"] == {"batch": 0, "qr": 0}
        assert "translation_error_m" not in metrics  # the file has no ground-truth poses


@pytest.mark.slow
@pytest.mark.e2e
def test_victoria_park_closes_its_loops_once_the_drift_windows_tell_the_yaw(tmp_path):
    """The real Victoria Park, the given associations hidden from MM + NH (README, "Victoria
    Park"): its odometry's yaw bias keeps every loop open at the stated noise, until the drift
    windows raise the yaw's scale (its forward noise stated about right); from there its loops
    close as Known DA's do."""
    log = tmp_path / "vp.mcap"
    convert_landmarks2d(VICTORIA_PARK, log)
    for method in ("known", "mm-nh"):
        out = tmp_path / method
        assert cli_main(["replay", str(log), "--method", method, "--out", str(out), "-q"]) == 0
    metrics = json.loads((tmp_path / "mm-nh" / "metrics.json").read_text())
    assert metrics["solver_fallbacks"] == {"batch": 0, "qr": 0}
    odometry = metrics["noise_scales"]["odometry"]
    assert odometry["yaw"] >= 4.0 and 0.5 <= odometry["forward"] <= 2.0
    assert {m["source"] for m in metrics["noise_scales"]["moves"]} >= {"drift windows"}
    given = metrics["association"]
    assert given["correct"] >= 0.95 * sum(given.values())
    assert metrics["num_landmarks"] <= 1.2 * 151
    gap = read_tum(tmp_path / "mm-nh" / "trajectory.tum") - read_tum(
        tmp_path / "known" / "trajectory.tum"
    )
    assert np.sqrt(np.mean(np.sum(gap**2, axis=1))) <= 6.5  # 5.0 m measured
