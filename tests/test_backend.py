"""The back-end end to end on small logs the tests write."""

import dataclasses
import os
import subprocess
import sys

import gtsam
import numpy as np
import pytest

from pipeline import settings
from pipeline.backend.hypotheses import NULL
from pipeline.backend.landmarks import LandmarkKind
from pipeline.backend.noise import MEASUREMENT_COMPONENTS, ODOMETRY_AXES
from pipeline.backend.slam import Backend
from pipeline.config import MIXTURE_SELECTIONS, load_config
from pipeline.log import read_log
from pipeline.replay import compute_metrics, keyframes, replay
from tests.backend_cases import with_settings
from tests.synthetic import (
    KIDNAP_POSE,
    ODOM_SIGMAS,
    Scene,
    kidnap_scene,
    square_loop,
    write_scene,
)

METHODS = ("known", "ml", "gpda", "mm", "mm-nh", "dcsam")


def run_backend(log_path, method: str, config=None) -> Backend:
    log = read_log(log_path)
    config = config or load_config()
    backend = Backend(config, np.asarray(log.metadata.confusion_matrix), method)
    for odometry, detections in keyframes(log):
        backend.add_keyframe(odometry, detections)
    return backend


def landmark_of_truth(backend: Backend) -> dict[int, int]:
    """Estimated landmark id of each true landmark, from the detections that created them."""
    out: dict[int, int] = {}
    for r in backend.records:
        out.setdefault(r.measurement.detection.truth_landmark_id, r.landmark_id)
    return out


def record_at(backend: Backend, pose: int, detection: int):
    (record,) = [
        r
        for r in backend.records
        if r.measurement.pose_index == pose and r.measurement.detection_index == detection
    ]
    return record


@pytest.fixture(scope="module")
def square_scene() -> Scene:
    corners = []
    for x in np.arange(2.0, 20.0, 4.0):
        corners += [[x, -3, 0.5], [23, x, 0.5], [20 - x, 23, 0.5], [-3, 20 - x, 0.5]]
    landmarks = np.array(corners)
    return Scene(square_loop(20.0, 1.0, laps=1.25), landmarks, np.arange(len(landmarks)) % 2)


@pytest.mark.e2e
def test_known_association_is_exact_on_noise_free_data(tmp_path, square_scene):
    log = write_scene(tmp_path / "exact.mcap", square_scene, odom_noise=0.0, meas_noise=0.0)
    result = replay(log, "known", tmp_path / "out", load_config(), progress=False)
    assert result.metrics["translation_error_m"]["max"] < 1e-6
    assert result.metrics["rotation_error_rad"]["max"] < 1e-6
    assert result.metrics["association"]["wrong"] == 0
    assert result.num_landmarks == len(square_scene.landmarks)


# Seeds 0 and 4 were the worst of eight: every method's RMSE within 0.26 m, every association
# right, no landmark lost to another; the bound leaves twice that.
@pytest.mark.e2e
@pytest.mark.parametrize("seed", [0, 4])
@pytest.mark.parametrize("method", METHODS)
def test_every_method_maps_a_noisy_loop(tmp_path, square_scene, method, seed):
    log = write_scene(tmp_path / "noisy.mcap", square_scene, seed=seed)
    result = replay(log, method, tmp_path / method, load_config(), progress=False)
    metrics = result.metrics
    assert metrics["translation_error_m"]["rmse"] < 0.5
    assert metrics["association"]["wrong"] == 0
    assert metrics["solver_fallbacks"] == {"batch": 0, "qr": 0}
    # a 0.9 chi-square gate turns down about a tenth of the true re-observations, and each of
    # those starts a duplicate landmark; far more than that means the innovation is wrong
    assert result.num_landmarks <= len(square_scene.landmarks) + 0.25 * result.num_detections


PAPER = settings.config_path("paper.toml")


def mixture_config(selection: str, path=None):
    """A CustomFactor revisits its choice only when iSAM2 relinearises it: every update here."""
    config = load_config(path)
    isam2 = config.isam2
    if selection == "custom-factor":
        isam2 = dataclasses.replace(isam2, relinearize_skip=1, relinearize_threshold=0.01)
    return dataclasses.replace(
        config, mixture=dataclasses.replace(config.mixture, selection=selection), isam2=isam2
    )


# Only between updates: a CustomFactor chooses at its first linearisation, the odometry's
# prediction, where every truthful detection looks like an outlier and the lookalike fits; it
# stays in that fixed point. The paper's settings choose first by the association weights, then
# the null wins once the truthful detections have moved the pose; mmslam's defaults choose the
# keyframe's detections together, and the alias starts a landmark of its own.
@pytest.mark.e2e
@pytest.mark.parametrize("settings", ["paper", "default"])
def test_wrong_loop_closure_accepted_by_ml_is_rejected_by_the_null_hypothesis(tmp_path, settings):
    scene, lookalike, alias = kidnap_scene(alias_seen_before=False)
    log = write_scene(tmp_path / "alias.mcap", scene, odom_noise=0.0, meas_noise=0.0)
    config = mixture_config("between-updates", PAPER if settings == "paper" else None)
    errors = {}
    for method in ("ml", "mm", "mm-nh"):
        backend = run_backend(log, method, config)
        backend.result()
        alias_detection = record_at(backend, KIDNAP_POSE, 0)
        assert alias_detection.measurement.detection.truth_landmark_id == alias
        errors[method] = replay(log, method, tmp_path / method, config, progress=False)
        wrong_closure = landmark_of_truth(backend)[lookalike]
        if method == "mm-nh" and settings == "paper":
            assert alias_detection.landmark_id == NULL
            assert alias_detection.switches == 1
        elif method == "mm-nh":
            assert alias_detection.landmark_id not in (NULL, wrong_closure)
            assert backend.landmarks.landmarks[alias_detection.landmark_id]
        else:
            # the alias was explained by the lookalike: the wrong loop closure
            assert alias_detection.landmark_id == wrong_closure
    ml = errors["ml"].metrics["translation_error_m"]["max"]
    mm_nh = errors["mm-nh"].metrics["translation_error_m"]["max"]
    assert ml > 0.2
    assert mm_nh < 0.02
    assert errors["mm-nh"].metrics["association"]["null"] == (1 if settings == "paper" else 0)
    assert errors["mm-nh"].metrics["association"]["wrong"] == 0


@pytest.mark.e2e
@pytest.mark.parametrize("selection", MIXTURE_SELECTIONS)
def test_max_mixture_switches_component_when_the_estimate_moves(tmp_path, selection):
    scene, lookalike, alias = kidnap_scene(alias_seen_before=True, shift=3.0)
    log = write_scene(tmp_path / "switch.mcap", scene, odom_noise=0.0, meas_noise=0.0)
    backend = run_backend(log, "mm", mixture_config(selection))
    backend.result()
    record = record_at(backend, KIDNAP_POSE, 0)
    lookalike, alias = landmark_of_truth(backend)[lookalike], landmark_of_truth(backend)[alias]
    # both mapped landmarks are components; the drifted prediction favours the lookalike ...
    ids = record.landmark_ids
    assert len(ids) == 2
    assert record.weights[ids.index(lookalike)] > record.weights[ids.index(alias)]
    # ... and once the other detections have moved the pose, the alias wins
    assert record.switches == 1
    assert record.landmark_id == alias
    ml = run_backend(log, "ml")
    assert record_at(ml, KIDNAP_POSE, 0).landmark_id == landmark_of_truth(ml)[0]


def class_reports_scene() -> Scene:
    """Two landmarks of classes 0 and 1 seen from every pose of a quarter lap, each report
    drawn through a confusion matrix that confuses them 3 times in 10: a minority of the
    reports (`misreports`) name the other class."""
    confusion = np.array([[0.7, 0.3], [0.3, 0.7]])
    poses = square_loop(8.0, 1.0, laps=0.25)
    landmarks = np.array([[4.0, 3.0, 0.0], [6.0, -3.0, 0.0]])
    misreports = {(0, 0), (1, 0), (2, 1)}
    scene = Scene(poses, landmarks, np.array([0, 1]), confusion=confusion, misreports=misreports)
    scene.sightings = [(i, j) for i in range(len(poses)) for j in range(2)]
    return scene


def assert_class_posteriors_follow_the_reports(backend: Backend, scene: Scene) -> None:
    """Every landmark of `scene`'s log (`class_reports_scene`), surely associated, holds the
    class posterior its reports give, P(c) ~ prod P(report | c), and its true class wins."""
    assert scene.confusion is not None
    reports = {j: [int(c)] * len(scene.poses) for j, c in enumerate(scene.classes)}
    for i, j in scene.misreports:
        reports[j][i] = 1 - reports[j][i]
    assert len(backend.landmarks.landmarks) == len(scene.landmarks)
    for j, landmark in backend.landmarks.landmarks.items():
        expected = np.array([np.prod(scene.confusion[c, reports[j]]) for c in range(2)])
        np.testing.assert_allclose(landmark.class_probabilities, expected / expected.sum())
        assert landmark.map_class == j


@pytest.mark.e2e
def test_class_posterior_follows_the_reports(tmp_path):
    scene = class_reports_scene()
    log = write_scene(tmp_path / "classes.mcap", scene, odom_noise=0.0, meas_noise=0.0)
    assert_class_posteriors_follow_the_reports(run_backend(log, "known"), scene)


def test_known_takes_a_report_its_confusion_matrix_calls_impossible(tmp_path):
    # A front-end log: the truth labels join a car boxed as a truck to the car, and the
    # detector's confusion matrix (the identity) says that never happens.
    poses = square_loop(8.0, 1.0, laps=0.25)
    landmarks = np.array([[4.0, 3.0, 0.0], [6.0, -3.0, 0.0]])
    scene = Scene(poses, landmarks, np.array([0, 1]), misreports={(2, 0), (3, 1)})
    scene.sightings = [(i, j) for i in range(len(poses)) for j in range(2)]
    log = write_scene(tmp_path / "impossible.mcap", scene, odom_noise=0.0, meas_noise=0.0)
    backend = run_backend(log, "known")
    for j, landmark in backend.landmarks.landmarks.items():
        np.testing.assert_allclose(landmark.class_probabilities, np.eye(2)[j])


@pytest.mark.e2e
@pytest.mark.parametrize("method", ["gpda", "mm-nh", "dcsam"])
def test_same_input_gives_byte_identical_outputs(tmp_path, square_scene, method):
    log = write_scene(tmp_path / "det.mcap", square_scene, seed=5, odom_noise=2.0)
    config = load_config()
    replay(log, method, tmp_path / "a", config, progress=False)
    replay(log, method, tmp_path / "b", config, progress=False)
    for name in ("trajectory.tum", "landmarks.csv", "associations.csv"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()
    import json

    a = json.loads((tmp_path / "a" / "metrics.json").read_text())
    b = json.loads((tmp_path / "b" / "metrics.json").read_text())
    a.pop("runtime_s")
    b.pop("runtime_s")
    assert a == b


@pytest.mark.e2e
def test_blas_threads_do_not_change_the_answer(tmp_path, square_scene):
    """numpy's BLAS may split a product over threads, and sum in another order: a replay with
    one thread and with several gives the same associations and estimates to round-off.
    (The gtsam wheel is built without TBB: its elimination is single-threaded.)"""
    log = write_scene(tmp_path / "det.mcap", square_scene, seed=5, odom_noise=2.0)
    for threads in ("1", "4"):
        env = {**os.environ, "OPENBLAS_NUM_THREADS": threads, "OMP_NUM_THREADS": threads}
        command = [sys.executable, "-m", "pipeline.cli", "replay", str(log), "--method",
                   "mm-nh", "--out", str(tmp_path / threads), "--quiet"]  # fmt: skip
        subprocess.run(command, check=True, env=env, capture_output=True)
    one, several = (tmp_path / "1", tmp_path / "4")
    assert (one / "associations.csv").read_text() == (several / "associations.csv").read_text()
    a = np.loadtxt(one / "trajectory.tum")
    b = np.loadtxt(several / "trajectory.tum")
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-9)


@pytest.mark.e2e
@pytest.mark.parametrize("method", METHODS)
def test_keyframes_without_detections_before_the_first_landmark(tmp_path, method):
    landmarks = np.array([[12.0, 2.0, 0.0], [14.0, -2.0, 0.0]])
    scene = Scene(square_loop(8.0, 1.0, laps=0.5), landmarks, np.array([0, 1]))
    scene.sightings = [(i, j) for i in range(4, 9) for j in range(2)]  # none at poses 0-3
    log = write_scene(tmp_path / "late.mcap", scene, odom_noise=0.0, meas_noise=0.0)
    result = replay(log, method, tmp_path / method, load_config(), progress=False)
    assert result.num_landmarks == 2
    assert result.metrics["association"]["correct"] == 10


def drift_config(**noise):
    """Short windows for a short log: the noise scales looked at every 10 keyframes."""
    config = load_config()
    n = dataclasses.replace(
        config.noise,
        update_every=10,
        drift_window=10,
        long_drift_window=40,
        min_drift_windows=3,
        min_contrasts=10,
        **noise,
    )
    return dataclasses.replace(config, noise=n)


def odometry_information(backend: Backend) -> list[np.ndarray]:
    """The information matrix of every odometry factor now in iSAM2 (pose to pose)."""
    graph = backend.solver.isam.getFactorsUnsafe()
    out = []
    for k in range(graph.size()):
        factor = graph.at(k)
        if (
            factor is not None
            and factor.size() == 2
            and all(chr(gtsam.Symbol(key).chr()) == "x" for key in factor.keys())  # noqa: SIM118
        ):
            out.append(factor.noiseModel().information())
    return out


def three_laps(tmp_path, square_scene, seed: int, odom_noise=1.0, meas_noise=1.0):
    """Three laps of the square, its odometry erring `odom_noise` times the stated sigmas and
    its detections `meas_noise` times (per direction, or all alike)."""
    scene = dataclasses.replace(square_scene, poses=square_loop(20.0, 1.0, laps=3.0))
    odom_noise, meas_noise = np.asarray(odom_noise, float), np.asarray(meas_noise, float)
    return write_scene(tmp_path / "drift.mcap", scene, seed, odom_noise, meas_noise)


def assert_every_factor_at(backend: Backend, odometry: np.ndarray, bearing: float) -> None:
    """One odometry factor per step in iSAM2, each the stated covariance at the `odometry`
    scales; every detection's measurement at the `bearing` scale."""
    information = odometry_information(backend)
    assert len(information) == backend.num_poses - 1
    stated = np.diag(ODOM_SIGMAS**2 * odometry)
    for matrix in information:
        np.testing.assert_allclose(np.linalg.inv(matrix), stated, rtol=1e-6, atol=1e-15)
    for record in backend.records:
        assert record.measurement.covariance[0, 0] == pytest.approx(bearing * 1e-4, rel=1e-9)


# Calibrated on seeds 1-3 of each (three laps of the square, updates every 10 keyframes):
# yaw sigmas x6 (variance x36) read 15-28, forward x4 (x16) 8.4-9.2, bearing x0.3 (x0.09)
# 0.09-0.17: short of an odometry's truth where landmarks decide part of a window (drift.py).
# Stated right, nothing moved on seeds 1-2; on seed 3 the roll, to 3.0 (docs/method.md).
@pytest.mark.slow
@pytest.mark.e2e
@pytest.mark.parametrize("seed", [1, 2])
@pytest.mark.parametrize(
    ("odom_noise", "meas_noise", "moved", "true"),
    [
        ([1, 1, 1, 1, 1, 1], [1, 1, 1], None, 1.0),
        ([1, 1, 6, 1, 1, 1], [1, 1, 1], "yaw", 36.0),
        ([1, 1, 1, 4, 1, 1], [1, 1, 1], "forward", 16.0),
        ([1, 1, 1, 1, 1, 1], [0.3, 1, 1], "bearing", 0.09),
    ],
)
def test_a_direction_stated_wrong_is_found_alone_and_every_factor_reweighted(
    tmp_path, square_scene, seed, odom_noise, meas_noise, moved, true
):
    """The log states every covariance; one direction errs other than stated. mm-nh finds
    that direction's scale within a factor 2, moves no other, and every factor of the graph
    then carries the scales; metrics.json reports the moves as made."""
    log = three_laps(tmp_path, square_scene, seed, odom_noise, meas_noise)
    backend = run_backend(log, "mm-nh", drift_config())
    scales = backend.noise.scales
    names = (*ODOMETRY_AXES, *MEASUREMENT_COMPONENTS)
    learnt = dict(zip(names, (*scales.odometry, *scales.measurement), strict=True))
    if moved is None:
        assert backend.noise.moves == []
    else:
        assert true / 2 <= learnt[moved] <= true * 2
    assert all(v == 1.0 for name, v in learnt.items() if name != moved)
    assert_every_factor_at(backend, np.array(scales.odometry), learnt["bearing"])
    metrics = compute_metrics(read_log(log), backend.result(), "mm-nh", 0.0)
    reported = metrics["noise_scales"]
    assert reported["odometry"] == dict(zip(ODOMETRY_AXES, scales.odometry, strict=True))
    assert [(m["pose_index"], m["source"]) for m in reported["moves"]] == [
        (m.pose_index, m.source) for m in backend.noise.moves
    ]
    for m in backend.noise.moves:  # each move's evidence, as the config asks
        assert all(
            e >= backend.config.noise.evidence
            for b, a, e in zip(m.before, m.after, m.evidence, strict=True)
            if a != b
        )


# Seeds 3 and 6 were the edges of eight: with the drift allowed, 1.006 and 1.053 landmarks a tag
# (seed 1: 1.027); with the log's statement alone 1.19 and 1.28 (seed 1: 1.29).
@pytest.mark.slow
@pytest.mark.e2e
@pytest.mark.parametrize("seed", [3, 6])
def test_loops_close_where_the_log_understates_its_drift(tmp_path, seed):
    """400 m of the indoor tag run whose log states the calibrated odometry covariance while
    its yaw drifts 9 times more (in sigma; noise x4): no revisit passes a gate built on the
    log's statement. A loop's test that lets the drift be larger, the pairs agreeing on one
    correction, closes the loops: about one landmark a tag, where without it a revisit is
    a tag mapped again."""
    from data_tools.scenarios import simulate

    route = tmp_path / "route.toml"
    route.write_text("[route]\nlength_m = 400.0\n")
    log = tmp_path / "tags.mcap"
    simulate("indoor-tags", log, seed=seed, odom_noise_scale=4.0, misclassification=0.1,
             config_path=route, foxglove=False)  # fmt: skip
    config = load_config()
    merges = dataclasses.replace(config.merges, drift_scale_weight=0.0)
    stated = dataclasses.replace(config, merges=merges)
    metrics = {
        name: replay(log, "mm-nh", tmp_path / name, c, progress=False).metrics
        for name, c in (("drift", config), ("stated", stated))
    }
    drift_per_tag = metrics["drift"]["association_one_to_one"]["landmarks_per_true"]
    stated_per_tag = metrics["stated"]["association_one_to_one"]["landmarks_per_true"]
    assert drift_per_tag <= 1.08 and stated_per_tag >= 1.15
    assert stated_per_tag - drift_per_tag >= 0.15
    # metrics.json says what the loops said: the drift is many times the log's, in the yaw's
    # scale learnt from the windows across them (the loops' own belief restarts from its prior
    # when the scales move: it says how far the drift exceeds the scales in use)
    drift = metrics["drift"]["loop_drift"]
    assert drift["loops"] > 0 and sum(drift["probabilities"]) == pytest.approx(1.0, abs=1e-3)
    learnt = metrics["drift"]["noise_scales"]["odometry"]
    assert learnt["yaw"] > 10.0
    assert all(learnt[axis] == 1.0 for axis in ("roll", "pitch", "forward", "lateral", "vertical"))


def test_a_keyframe_tells_its_heartbeat_what_it_is_doing(tmp_path, square_scene):
    log = read_log(write_scene(tmp_path / "beat.mcap", square_scene, seed=0))
    heard: list[str] = []
    confusion = np.asarray(log.metadata.confusion_matrix)
    backend = Backend(load_config(), confusion, "mm-nh", heartbeat=heard.append)
    for odometry, detections in list(keyframes(log))[:6]:
        backend.add_keyframe(odometry, detections)
    count = len(list(keyframes(log))[5][1])
    at_5 = [line for line in heard if line.startswith("pose 5: ")]
    assert at_5[:3] == [
        f"pose 5: scoring {count} detections",
        f"pose 5: associating {count} detections",
        "pose 5: updating iSAM2",
    ]
    # pose 5 is a merge check's (every 5th): it tells which source it is at
    assert any(line.startswith("pose 5: merge check, partners of source 1 of ") for line in at_5)
    assert not any("merge check" in line for line in heard if line.startswith("pose 4: "))


def test_a_replay_runs_blas_on_one_thread(tmp_path, square_scene, monkeypatch):
    """numpy's and scipy's BLAS, two threads each before the replay, run on one during it (the
    back-end's small matrices: `replay.one_blas_thread`) and on two again after it."""
    from threadpoolctl import threadpool_info, threadpool_limits

    import pipeline.replay as replay_module

    def blas_threads() -> set[int]:
        return {pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"}

    seen: list[set[int]] = []
    real = Backend.add_keyframe

    def spy(self, *args, **kwargs):
        seen.append(blas_threads())
        return real(self, *args, **kwargs)

    monkeypatch.setattr(Backend, "add_keyframe", spy)
    log = read_log(write_scene(tmp_path / "blas.mcap", square_scene, seed=0))
    with threadpool_limits(limits=2, user_api="blas"):
        assert blas_threads() == {2}
        replay_module.run_backend(log, "known", load_config(), replay_module.NullSink(), False)
        assert blas_threads() == {2}
    assert len(seen) == log.num_poses and all(threads == {1} for threads in seen)


def replayed(tmp_path, scene, config) -> Backend:
    log = read_log(write_scene(tmp_path / "final.mcap", scene, seed=0))
    backend = Backend(config, np.asarray(log.metadata.confusion_matrix), "mm-nh")
    for odometry, detections in keyframes(log):
        backend.add_keyframe(odometry, detections)
    return backend


@pytest.mark.parametrize("taken", [1, 2, 5])
def test_the_last_merge_check_takes_every_point_landmark_until_none_waits(
    tmp_path, square_scene, taken
):
    """At the log's end every point landmark is a source, seen lately or not; a check that
    reaches only `taken` of them leaves the others waiting for the next (`merge_remaining`)."""
    backend = replayed(tmp_path, square_scene, load_config())
    context = backend.context
    asked: list[set[int]] = []

    def check(pose_index, prediction, final=False):
        assert final and pose_index == backend.num_poses - 1
        asked.append(set(context.changed))
        waiting = sorted(context.changed)
        context.changed = set(waiting[taken:])  # the sources left over wait
        return []

    backend.merger.find = check
    backend.result()
    points = {j for j, lm in backend.landmarks.landmarks.items() if lm.kind is LandmarkKind.POINT}
    assert len(points) > 5 and asked[0] == points
    assert len(asked) == -(-len(points) // taken)  # ceil: each check takes `taken` more
    backend.result()  # the log's last check is made once
    assert len(asked) == -(-len(points) // taken)


def test_the_last_merge_check_ends_when_a_check_neither_merges_nor_leaves_fewer(
    tmp_path, square_scene
):
    backend = replayed(tmp_path, square_scene, load_config())
    calls = []

    def stuck(pose_index, prediction, final=False):
        calls.append(pose_index)
        return []  # `changed` kept whole: a budget too small for the first source

    backend.merger.find = stuck
    backend.result()
    assert len(calls) == 1


def test_the_last_merge_check_merges_and_can_be_turned_off(tmp_path, square_scene):
    on = replayed(tmp_path, square_scene, load_config())
    off = replayed(
        tmp_path, square_scene, with_settings(load_config(), merges={"final_check": False})
    )
    # Two landmarks of the map, made one at the log's end (what the check decides is
    # merges.py's tests').
    survivor, duplicate = sorted(on.landmarks.landmarks)[:2]
    picked = iter([[(duplicate, survivor)]])
    on.merger.find = lambda *args, **kwargs: next(picked, [])
    off.merger.find = lambda *args, **kwargs: pytest.fail("final_check is off")
    merges_before = on.merges
    result = on.result()
    off.result()
    assert duplicate not in result.landmark_ids and survivor in result.landmark_ids
    assert on.context.held_detections(duplicate) == []
    assert on.merges == merges_before + 1
