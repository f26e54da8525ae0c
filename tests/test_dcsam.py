"""`--method dcsam`: the model's costs by hand, the discrete step against brute force, one
alternation against GTSAM's own `gtsam.DCSAM`, small graphs end to end, the contract outputs."""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
from pathlib import Path

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import L, X

from pipeline.backend.decisions import MeasurementSpace
from pipeline.backend.hypotheses import NULL
from pipeline.backend.landmarks import LandmarkKind
from pipeline.backend.measurements import make_measurement
from pipeline.backend.methods.dcsam import discrete_step
from pipeline.backend.methods.dcsam.method import HybridRecord
from pipeline.backend.methods.dcsam.model import (
    class_log_evidence,
    class_posterior,
    geometric_weights,
    mode_constants,
    mode_probabilities,
    new_landmark_log_volume,
)
from pipeline.backend.solver import Isam2Solver
from pipeline.cli import main
from pipeline.config import load_config
from pipeline.geometry import bearing_elevation_range
from pipeline.log import Detection
from tests.synthetic import (
    KIDNAP_POSE,
    MEAS_SIGMAS,
    ODOM_SIGMAS,
    Scene,
    kidnap_scene,
    square_loop,
    write_scene,
)
from tests.test_backend import (
    assert_class_posteriors_follow_the_reports,
    class_reports_scene,
    landmark_of_truth,
    record_at,
    run_backend,
)

ROOT = Path(__file__).resolve().parents[1]

# ---------------------------------------------------------------- the model, by hand


def test_geometric_weights_divide_the_class_out():
    # 0.6 / 0.9 = 2/3 and 0.4 / 0.1 = 4, over 14/3
    np.testing.assert_allclose(
        geometric_weights(np.array([0.6, 0.4]), np.array([0.9, 0.1])), [1 / 7, 6 / 7]
    )


def test_mode_constants_by_hand():
    costs = mode_constants(np.array([0.25, 0.75]), 0.1, 0.5, -2.0, 3.0, 20.0)
    share = 0.9
    expected = [
        -math.log(share * 0.5 * 0.25) - 2.0,
        -math.log(share * 0.5 * 0.75) - 2.0,
        -math.log(share * 0.5) + 3.0,
        20.0,
    ]
    np.testing.assert_allclose(costs, expected)


def test_class_evidence_and_posterior_by_hand():
    confusion = np.array([[0.8, 0.2], [0.3, 0.7]])
    evidence = class_log_evidence(np.array([2.0, 1.0]), confusion)
    np.testing.assert_allclose(evidence, [math.log(0.8 * 0.8 * 0.2), math.log(0.3 * 0.3 * 0.7)])
    # 0.128 and 0.063 over 0.191
    np.testing.assert_allclose(class_posterior(evidence), [0.128 / 0.191, 0.063 / 0.191])


def test_a_class_the_detector_never_confuses_is_ruled_out_without_nan():
    evidence = class_log_evidence(np.array([3.0, 0.0]), np.eye(2))
    assert evidence[0] == pytest.approx(0.0) and evidence[1] == -math.inf
    np.testing.assert_allclose(class_posterior(evidence), [1.0, 0.0])
    # nothing held: every class as likely
    np.testing.assert_allclose(class_posterior(class_log_evidence(np.zeros(3), np.eye(3))), 1 / 3)


def test_a_new_landmark_is_uniform_over_the_box_the_detections_span():
    space = MeasurementSpace()
    space.observe(np.array([-0.5, 0.0, 2.0]), np.diag([1e-4, 1e-4, 1e-2]))
    space.observe(np.array([0.5, 0.2, 12.0]), np.diag([1e-4, 1e-4, 1e-2]))
    # sides 1.0 rad, 0.2 rad, 10 m
    assert new_landmark_log_volume(LandmarkKind.POINT, space) == pytest.approx(math.log(2.0))
    pose = new_landmark_log_volume(LandmarkKind.POSE, space)
    assert pose == pytest.approx(math.log(8 * math.pi**2) + space.log_world_volume())


def test_mode_probabilities_by_hand():
    p = mode_probabilities(np.array([1.0, 1.0 + math.log(3.0)]))
    np.testing.assert_allclose(p, [0.75, 0.25])


# ---------------------------------------------------------------- the discrete step


def brute_force(detections, evidence):
    """The MPE by enumerating every assignment of modes and classes."""
    landmarks = sorted({j for d in detections for j in d.landmarks if j is not None})
    num_classes = len(detections[0].report)
    best, best_value = None, -math.inf
    for modes in itertools.product(*(range(len(d.costs)) for d in detections)):
        for classes in itertools.product(range(num_classes), repeat=len(landmarks)):
            of = dict(zip(landmarks, classes, strict=True))
            value = sum(evidence[j][c] for j, c in of.items())
            for d, mode in zip(detections, modes, strict=True):
                value -= d.costs[mode]
                if mode == d.null:
                    value += math.log(np.mean(d.report))
                elif d.landmarks[mode] is None:
                    value += math.log(np.max(d.report))
                else:
                    value += math.log(d.report[of[d.landmarks[mode]]])
            if value > best_value + 1e-9:
                best, best_value = (list(modes), of), value
    return best


@pytest.mark.parametrize("seed", range(6))
def test_the_discrete_step_finds_the_brute_force_mpe(seed):
    rng = np.random.default_rng(seed)
    confusion = rng.dirichlet(np.ones(3), size=3)
    detections = []
    for i in range(3):
        candidates = [int(j) for j in rng.choice(4, size=rng.integers(1, 3), replace=False)]
        own = 10 + i if rng.random() < 0.5 else None
        costs = rng.normal(scale=2.0, size=len(candidates) + 2)
        report = confusion[:, rng.integers(3)]
        detections.append(discrete_step.DetectionModes(costs, (*candidates, own), report))
    landmarks = {j for d in detections for j in d.landmarks if j is not None}
    evidence = {j: class_log_evidence(rng.integers(0, 3, size=3), confusion) for j in landmarks}
    solution = discrete_step.solve(detections, evidence)
    modes, classes = brute_force(detections, evidence)
    assert solution.modes == modes
    assert solution.classes == classes
    for p in solution.probabilities:
        assert p.sum() == pytest.approx(1.0)


def test_with_one_class_each_detection_takes_its_cheapest_mode():
    detections = [
        discrete_step.DetectionModes(np.array([3.0, 1.0, 2.0, 9.0]), (4, 5, None), np.ones(1)),
        discrete_step.DetectionModes(np.array([5.0, 4.0, 0.5]), (4, None), np.ones(1)),
    ]
    solution = discrete_step.solve(detections, None)
    assert solution.modes == [1, 2]
    assert solution.classes == {}
    np.testing.assert_allclose(solution.probabilities[1], mode_probabilities([5.0, 4.0, 0.5]))


def test_the_class_decides_between_two_landmarks_that_fit_alike():
    confusion = np.array([[0.9, 0.1], [0.1, 0.9]])
    fit_alike = np.array([1.0, 1.0, 30.0, 40.0])
    evidence = {  # landmark 1 reported class 0 four times, landmark 2 class 1
        1: class_log_evidence(np.array([4.0, 0.0]), confusion),
        2: class_log_evidence(np.array([0.0, 4.0]), confusion),
    }
    for reported, expected in ((0, 0), (1, 1)):
        d = discrete_step.DetectionModes(fit_alike, (1, 2, None), confusion[:, reported])
        solution = discrete_step.solve([d], evidence)
        assert solution.modes == [expected]
        assert solution.classes == {1: 0, 2: 1}
        # the chosen landmark's report likelihood against the other's: 0.9 / 0.1
        p = solution.probabilities[0]
        assert p[expected] / p[1 - expected] == pytest.approx(9.0)


def test_groups_are_the_detections_linked_through_landmarks():
    def d(*landmarks):
        return discrete_step.DetectionModes(np.zeros(len(landmarks) + 1), landmarks, np.ones(2))

    # 0 and 2 share landmark 7, 2 and 3 share 9; 1 and 4 stand alone (own landmarks unmade)
    detections = [d(7, None), d(5, None), d(7, 9, None), d(9, None), d(None)]
    assert discrete_step.groups(detections) == [[0, 2, 3], [1], [4]]


@pytest.mark.parametrize("seed", range(6))
def test_by_turns_ends_where_neither_associations_nor_classes_would_change(seed):
    """A group larger than `exact_class_variables` (0 here): each detection's mode the best
    given the classes, each class the best given the modes, and no better than the MPE."""
    rng = np.random.default_rng(seed)
    confusion = rng.dirichlet(np.ones(3), size=3)
    detections = []
    for _ in range(4):
        candidates = [int(j) for j in rng.choice(4, size=rng.integers(1, 3), replace=False)]
        costs = rng.normal(scale=2.0, size=len(candidates) + 2)
        detections.append(
            discrete_step.DetectionModes(costs, (*candidates, None), confusion[:, rng.integers(3)])
        )
    landmarks = discrete_step.landmarks_of(detections)
    evidence = {j: class_log_evidence(rng.integers(0, 3, size=3), confusion) for j in landmarks}
    solution = discrete_step.solve(detections, evidence, exact_class_variables=0)
    modes, classes = solution.modes, solution.classes
    for d, mode in zip(detections, modes, strict=True):
        semantic = discrete_step.unary_semantics(d, classes)
        assert mode == int(np.argmin(d.costs - np.log(semantic)))
    for j in landmarks:
        held = [
            np.log(d.report)
            for d, mode in zip(detections, modes, strict=True)
            if mode < d.null and d.landmarks[mode] == j
        ]
        assert classes[j] == int(np.argmax(evidence[j] + sum(held, np.zeros(3))))

    def log_probability(modes, classes):
        value = sum(evidence[j][c] for j, c in classes.items())
        for d, mode in zip(detections, modes, strict=True):
            value += math.log(discrete_step.unary_semantics(d, classes)[mode]) - d.costs[mode]
        return value

    best_modes, best_classes = brute_force(detections, evidence)
    assert log_probability(modes, classes) <= log_probability(best_modes, best_classes) + 1e-9


# ---------------------------------------------------------------- against gtsam.DCSAM

# Modes without their own factor weigh this little in a hybrid factor (GTSAM 4.3 wants every
# component of a HybridNonlinearFactor on the same variables).
NO_PULL = 1e-12


def detection(pose: gtsam.Pose3, point: np.ndarray, class_id: int = 0) -> Detection:
    b, e, r = bearing_elevation_range(pose.transformTo(point))
    return Detection(
        class_id, 0.9, float(b), float(e), float(r), tuple(np.diag(MEAS_SIGMAS**2).ravel()), "bbox"
    )


def odometry_factor(a: int, b: int, step: gtsam.Pose3) -> gtsam.BetweenFactorPose3:
    noise = gtsam.noiseModel.Diagonal.Sigmas(ODOM_SIGMAS)
    return gtsam.BetweenFactorPose3(X(a), X(b), step, noise)


def test_one_alternation_matches_gtsam_dcsam_first_update():
    """Landmarks 0 and 1, 1.5 m apart, and 3 and 4 seen from poses 0 and 1; from pose 1,
    whose initial guess is 1.5 m off to the side, a detection of landmark 0 that the guess
    puts on landmark 1. Its modes: landmark 0, landmark 1, its own landmark 2, the null; two
    classes. gtsam.DCSAM's first update (the discrete step at the guess, then iSAM2) and its
    estimate (the discrete step again at the result), against the same with mmslam's
    pieces: `discrete_step.solve` and `Isam2Solver`."""
    confusion = np.array([[0.8, 0.2], [0.2, 0.8]])
    truth = [np.array(p) for p in ([6.0, 0.75, 0.0], [6.0, -0.75, 0.0], [7.0, 4.0, 0.5])]
    truth.append(np.array([7.0, -4.0, -0.5]))
    poses = [gtsam.Pose3(), gtsam.Pose3(gtsam.Rot3(), np.array([1.0, 0.0, 0.0]))]
    guess = gtsam.Pose3(gtsam.Rot3(), np.array([1.0, -1.5, 0.0]))
    m = make_measurement(1, 0, detection(poses[1], truth[0], 0), False)
    report = confusion[:, 0]
    constants = mode_constants(np.array([0.5, 0.5]), 0.1, 0.5, m.log_normaliser, 2.0, 25.0)
    mapped = {0: truth[0], 1: truth[1], 3: truth[2], 4: truth[3]}
    points = {**mapped, 2: guess.transformFrom(m.body_point)}  # 2: the detection's own

    fixed = [
        gtsam.PriorFactorPose3(X(0), poses[0], gtsam.noiseModel.Isotropic.Sigma(6, 1e-4)),
        odometry_factor(0, 1, poses[0].between(poses[1])),
    ]
    for j, p in mapped.items():
        fixed.append(
            make_measurement(0, j, detection(poses[0], p, j % 2), False).factor(X(0), L(j))
        )
    for j in (3, 4):
        fixed.append(
            make_measurement(1, j, detection(poses[1], mapped[j]), False).factor(X(1), L(j))
        )
    for j, p in points.items():
        fixed.append(gtsam.PriorFactorPoint3(L(j), p, gtsam.noiseModel.Isotropic.Sigma(3, 1e3)))
    initial = gtsam.Values()
    initial.insert(X(0), poses[0])
    initial.insert(X(1), guess)
    for j, p in points.items():
        initial.insert(L(j), p)
    evidence = {0: class_log_evidence(np.array([1.0, 0.0]), confusion)}
    evidence[1] = class_log_evidence(np.array([0.0, 1.0]), confusion)
    evidence[2] = np.zeros(2)

    # GTSAM's: a hybrid factor on association `a` for each landmark the detection may be
    # (its mode's factor, a copy that weighs nothing in the other modes), class factors
    a = gtsam.symbol("z", 0)
    graph = gtsam.HybridNonlinearFactorGraph()
    for f in fixed:
        graph.push_back(f)
    for j in range(3):
        components = [
            (
                m.factor(X(1), L(j), 1.0 if mode == j else NO_PULL),
                constants[mode] if mode == j else 0.0,
            )
            for mode in range(4)
        ]
        if j == 0:  # the null's cost, once
            components[3] = (components[3][0], constants[3])
        graph.push_back(gtsam.HybridNonlinearFactor((a, 4), components))
        table = np.ones((4, 2))
        table[j] = report
        k = (gtsam.symbol("k", j), 2)
        graph.push_back(gtsam.DecisionTreeFactor([(a, 4), k], list(table.ravel())))
        graph.push_back(gtsam.DecisionTreeFactor(k, list(np.exp(evidence[j] - max(evidence[j])))))
    graph.push_back(gtsam.DecisionTreeFactor((a, 4), [1.0, 1.0, 1.0, float(np.mean(report))]))
    dcsam = gtsam.DCSAM(gtsam.ISAM2Params())
    dcsam.update(graph, gtsam.HybridValues(gtsam.DiscreteValues(), initial))
    theirs = dcsam.calculateEstimate()

    # mmslam's: the discrete step at the guess, iSAM2 with the chosen factor, the step again
    def step(values: gtsam.Values) -> int:
        errors = [m.factor(X(1), L(j)).error(values) for j in range(3)]
        d = discrete_step.DetectionModes(constants + np.array([*errors, 0.0]), (0, 1, 2), report)
        return discrete_step.solve([d], evidence).modes[0]

    first = step(initial)
    solver = Isam2Solver(load_config().isam2)
    for f in fixed:
        solver.add(f)
    solver.insert(X(0), poses[0])
    solver.insert(X(1), guess)
    for j, p in points.items():
        solver.insert(L(j), p)
    solver.add(m.factor(X(1), L(first)))
    solver.update()
    ours = solver.estimate()

    assert first == 1  # the guess puts the detection on landmark 1 ...
    assert step(ours) == theirs.discrete()[a] == 0  # ... the odometry and landmarks 3, 4 on 0
    np.testing.assert_allclose(
        ours.atPose3(X(1)).translation(), theirs.nonlinear().atPose3(X(1)).translation(), atol=1e-6
    )


def test_gtsam_dcsam_adds_every_hybrid_factor_again_at_each_update():
    """Why mmslam runs the alternation itself (docs/dcsam.md): GTSAM 4.3's DCSAM puts the
    selected component of every hybrid factor it holds into its iSAM2 at every update, beside
    the copies already there. When this fails, gtsam.DCSAM can be used incrementally."""
    graph = gtsam.HybridNonlinearFactorGraph()
    graph.push_back(
        gtsam.PriorFactorPoint3(X(0), np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(3, 1))
    )
    tight, loose = (gtsam.noiseModel.Isotropic.Sigma(3, s) for s in (0.1, 10.0))
    components = [
        (gtsam.BetweenFactorPoint3(X(0), L(0), np.ones(3), noise), noise.negLogConstant())
        for noise in (tight, loose)
    ]
    graph.push_back(gtsam.HybridNonlinearFactor((gtsam.symbol("a", 0), 2), components))
    values = gtsam.Values()
    values.insert(X(0), np.zeros(3))
    values.insert(L(0), np.ones(3))
    dcsam = gtsam.DCSAM(gtsam.ISAM2Params())
    dcsam.update(graph, gtsam.HybridValues(gtsam.DiscreteValues(), values))
    sizes = [dcsam.getNonlinearFactorGraph().size()]
    for _ in range(3):
        dcsam.update()
        sizes.append(dcsam.getNonlinearFactorGraph().size())
    assert sizes == [2, 3, 4, 5]


# ---------------------------------------------------------------- small graphs end to end


def two_landmarks_scene(phantom_offset: float | None = None) -> Scene:
    """Landmarks 0 and 1, 2 m apart, seen from poses 0-3; pose 5's odometry admits a metre
    sideways, so both are candidates for its detection of landmark 0. `phantom_offset`: pose 5
    also reports something that far beside landmark 0, which nothing else ever shows (an
    outlier)."""
    poses = [gtsam.Pose3(gtsam.Rot3(), np.array([float(i), 0.0, 0.0])) for i in range(7)]
    landmarks = [[10.0, 1.0, 0.0], [10.0, -1.0, 0.0]]
    sightings = [(i, j) for i in range(4) for j in (0, 1)] + [(5, 0)]
    if phantom_offset is not None:
        landmarks.append([10.0, 1.0 + phantom_offset, 0.0])
        sightings.append((5, 2))
    step = gtsam.Pose3(gtsam.Rot3(), np.array([1.0, 0.0, 0.0]))
    sigmas = np.array([1e-3, 1e-3, 1e-3, 0.05, 1.0, 0.05])
    return Scene(
        poses,
        np.array(landmarks),
        np.zeros(len(landmarks), dtype=int),
        num_classes=1,
        sightings=sightings,
        odometry_overrides={5: (step, sigmas)},
    )


def dcsam_config(**dcsam):
    config = load_config()
    return dataclasses.replace(config, dcsam=dataclasses.replace(config.dcsam, **dcsam))


def test_a_detection_that_fits_one_of_two_landmarks_takes_it(tmp_path):
    log = write_scene(tmp_path / "two.mcap", two_landmarks_scene(), odom_noise=0.0, meas_noise=0.0)
    backend = run_backend(log, "dcsam")
    result = backend.result()
    record = record_at(backend, 5, 0)
    first_sighting = record_at(backend, 0, 0).landmark_id
    assert isinstance(record, HybridRecord)
    assert record.num_candidates == 2 and first_sighting in record.landmark_ids
    assert record.landmark_id == first_sighting
    assert record.weights[record.landmark_ids.index(first_sighting)] > 0.9
    assert len(result.landmark_ids) == 2


@pytest.mark.parametrize("new_landmark_weight", [0.5, 1e-12])
def test_an_outlier_beside_a_landmark_is_no_pull_on_it(tmp_path, new_landmark_weight):
    """An outlier a metre beside landmark 0, in its gate but 11 of its sigmas off: its own
    landmark wins (defaults), or, where new landmarks are costlier than the null, the null;
    never landmark 0, and the map stays exact."""
    scene = two_landmarks_scene(phantom_offset=1.0)
    log = write_scene(tmp_path / "outlier.mcap", scene, odom_noise=0.0, meas_noise=0.0)
    config = dcsam_config(new_landmark_weight=new_landmark_weight)
    backend = run_backend(log, "dcsam", config)
    result = backend.result()
    outlier = next(
        r
        for r in backend.records
        if r.measurement.pose_index == 5 and r.measurement.detection.truth_landmark_id == 2
    )
    landmark_0 = record_at(backend, 0, 0).landmark_id
    assert isinstance(outlier, HybridRecord) and landmark_0 in outlier.landmark_ids
    if new_landmark_weight < 1e-6:
        assert outlier.landmark_id == NULL
        assert outlier.null_weight > 0.9
        assert len(result.landmark_ids) == 2
    else:
        assert outlier.landmark_id not in (NULL, landmark_0)
        assert len(result.landmark_ids) == 3
    assert record_at(backend, 5, 0).landmark_id == landmark_0
    np.testing.assert_allclose(result.poses[5].translation(), [5.0, 0.0, 0.0], atol=1e-6)


def test_class_posterior_follows_the_reports_through_the_confusion(tmp_path):
    scene = class_reports_scene()
    log = write_scene(tmp_path / "classes.mcap", scene, odom_noise=0.0, meas_noise=0.0)
    backend = run_backend(log, "dcsam")
    backend.result()
    for r in backend.records[2:]:
        assert isinstance(r, HybridRecord) and r.landmark_id == r.landmark_ids[0]
    assert_class_posteriors_follow_the_reports(backend, scene)


def test_decided_at_the_drifted_prediction_a_wrong_loop_closure_is_taken(tmp_path):
    """What DC-SAM lacks that mm-nh has: the kidnapped robot's alias fits the lookalike at the
    drifted prediction while its seven truthful detections fit nothing there. DC-SAM's discrete
    step, at the prediction, gives those their own landmarks (no pull) and the alias the
    lookalike: the wrong loop closure, as ML takes it. mm-nh's joint choice, the pose
    integrated out, starts the alias a landmark of its own."""
    scene, lookalike, _ = kidnap_scene(alias_seen_before=False)
    log = write_scene(tmp_path / "alias.mcap", scene, odom_noise=0.0, meas_noise=0.0)
    chosen = {}
    for method in ("dcsam", "mm-nh"):
        backend = run_backend(log, method)
        backend.result()
        chosen[method] = (
            record_at(backend, KIDNAP_POSE, 0).landmark_id
            == (landmark_of_truth(backend)[lookalike])
        )
    assert chosen == {"dcsam": True, "mm-nh": False}


# ---------------------------------------------------------------- the command line


def test_replay_dcsam_writes_valid_contract_outputs(tmp_path, capsys):
    small = ROOT / "configs" / "scenarios" / "small-indoor-tags.toml"
    log = tmp_path / "tags.mcap"
    args = ["simulate", "indoor-tags", "--out", str(log), "--seed", "1", "--config", str(small)]
    assert main([*args, "--odom-noise-scale", "2", "--misclassification", "0.1"]) == 0
    out = tmp_path / "dcsam"
    assert main(["replay", str(log), "--method", "dcsam", "--out", str(out), "--quiet"]) == 0
    assert capsys.readouterr().err == ""  # no solver fallback, no warning
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["method"] == "dcsam"
    assert metrics["solver_fallbacks"] == {"batch": 0, "qr": 0}
    trajectory = np.loadtxt(out / "trajectory.tum")
    assert trajectory.shape == (metrics["num_poses"], 8)
    np.testing.assert_allclose(np.linalg.norm(trajectory[:, 4:], axis=1), 1.0, atol=1e-9)
    landmarks = np.loadtxt(out / "landmarks.csv", delimiter=",", skiprows=1, ndmin=2)
    associations = np.loadtxt(out / "associations.csv", delimiter=",", skiprows=1, ndmin=2)
    assert len(landmarks) == metrics["num_landmarks"] > 0
    assert len(associations) == metrics["num_detections"] > 0
    # every landmark holds a detection, and every detection is on a landmark of the file or null
    ids = set(landmarks[:, 0].astype(int))
    held = associations[:, 2].astype(int)
    assert set(held) - {NULL} <= ids
    assert {int(j): int(n) for j, n in zip(landmarks[:, 0], landmarks[:, 6], strict=True)} == {
        j: int(np.sum(held == j)) for j in ids
    }
    assert np.all((landmarks[:, 5] > 0) & (landmarks[:, 5] <= 1))  # the class's probability
    assert np.all((associations[:, 3] >= 0) & (associations[:, 3] <= 1))
    counts = metrics["association"]
    assert counts["correct"] + counts["wrong"] + counts["null"] == metrics["num_detections"]
    assert metrics["translation_error_m"]["rmse"] < 5.0


def test_a_bad_dcsam_setting_is_one_line_and_exit_2(tmp_path, capsys):
    scene = Scene(square_loop(4.0, 1.0, 0.25), np.array([[3.0, 1.0, 0.0]]), np.array([0]))
    log = write_scene(tmp_path / "log.mcap", scene)
    config = tmp_path / "bad.toml"
    config.write_text("[dcsam]\nmax_alternations = 0\n")
    status = main(
        [
            "replay",
            str(log),
            "--method",
            "dcsam",
            "--out",
            str(tmp_path / "o"),
            "--config",
            str(config),
        ]
    )
    err = capsys.readouterr().err
    assert status == 2 and err.count("\n") == 1 and "Traceback" not in err
    assert "'dcsam.max_alternations' must be in [1, 1000], got 0" in err
    assert not (tmp_path / "o").exists()


# ---------------------------------------------------------------- the method's bookkeeping


def two_classes_scene() -> Scene:
    """Three landmarks, two of class 1 beside each other, seen around a square with some
    reports wrong, under a confusion matrix that is not symmetric (P(r | c) = confusion[c, r]:
    reading it by row instead of by column gives other numbers)."""
    confusion = np.array([[0.9, 0.1], [0.35, 0.65]])
    poses = square_loop(8.0, 1.0, laps=1.25)
    landmarks = np.array([[4.0, 3.0, 0.0], [6.0, -3.0, 0.0], [4.5, 3.6, 0.0]])
    misreports = {(0, 0), (1, 0), (2, 1), (5, 2), (9, 0), (11, 2)}
    return Scene(poses, landmarks, np.array([0, 1, 1]), confusion=confusion, misreports=misreports)


@pytest.fixture(scope="module")
def two_classes_run(tmp_path_factory):
    path = tmp_path_factory.mktemp("dcsam") / "classes.mcap"
    scene = two_classes_scene()
    log = write_scene(path, scene, odom_noise=1.0, meas_noise=1.0)
    backend = run_backend(log, "dcsam")
    backend.result()
    return backend, scene.confusion


def held_reports(backend, landmark_id: int, leaving_out=None) -> np.ndarray:
    """How many detections now on `landmark_id` reported each class (one left out)."""
    counts = np.zeros(2)
    for r in backend.records:
        if r is not leaving_out and r.landmark_id == landmark_id:
            counts[r.measurement.detection.class_id] += 1
    return counts


def test_each_landmark_s_class_is_what_the_detections_it_holds_report(two_classes_run):
    backend, confusion = two_classes_run
    held = {r.landmark_id for r in backend.records if r.landmark_id != NULL}
    assert set(backend.landmarks.landmarks) == held  # none that no detection holds
    assert len(held) >= 3
    for j, landmark in backend.landmarks.landmarks.items():
        counts = held_reports(backend, j)
        likelihood = np.array([np.prod(confusion[c] ** counts) for c in range(2)])
        np.testing.assert_allclose(landmark.class_probabilities, likelihood / likelihood.sum())


def test_the_discrete_step_weighs_a_detection_by_the_others_reports(two_classes_run):
    """A detection's report enters its modes through P(report | class) (the confusion's
    column), and a landmark's class evidence for it comes from the other detections it holds,
    never its own report counted twice."""
    backend, confusion = two_classes_run
    method = backend.method
    hybrid = [r for r in backend.records if isinstance(r, HybridRecord)]
    assert len(hybrid) > 20
    for r in hybrid:
        np.testing.assert_allclose(r.report, confusion[:, r.measurement.detection.class_id])
        evidence = method._evidence_outside([r])
        for j in r.landmark_ids:
            counts = held_reports(backend, j, leaving_out=r)
            np.testing.assert_allclose(evidence[j], class_log_evidence(counts, confusion))


def test_each_detection_holds_the_most_probable_of_its_modes(two_classes_run):
    backend, _ = two_classes_run
    for r in (r for r in backend.records if isinstance(r, HybridRecord)):
        probabilities = [*r.weights, r.null_weight]
        assert len(r.weights) == len(r.landmark_ids)
        unmade = 1.0 - sum(probabilities)  # a landmark of its own not made yet
        assert unmade == pytest.approx(0.0, abs=1e-9) or len(r.landmark_ids) == r.num_candidates
        held = r.null_weight if r.landmark_id == NULL else r.weights[r.active]
        assert held >= max(*probabilities, unmade) - 1e-12
        assert r.mode == (r.num_candidates + 1 if r.landmark_id == NULL else r.active)


def test_refine_returns_the_detections_it_switched(tmp_path):
    """A detection put on the wrong one of two landmarks: the next alternation moves it back,
    counts the switch and reports the record; the landmark it left, held by no detection any
    more, leaves the map at the end, and one taken again comes back."""
    log = write_scene(tmp_path / "two.mcap", two_landmarks_scene(), odom_noise=0.0, meas_noise=0.0)
    backend = run_backend(log, "dcsam")
    method, context = backend.method, backend.context
    record = record_at(backend, 5, 0)
    right = record.landmark_id
    wrong = next(j for j in record.landmark_ids[: record.num_candidates] if j != right)
    method._switch(record, record.landmark_ids.index(wrong))
    assert record.landmark_id == wrong and record.switches == 1
    moved = context.after_update(context.solver.update())
    switched = method.refine(moved | {X(5), L(right), L(wrong)})
    assert switched and all(r is record for r in switched)
    assert record.landmark_id == right and record.switches == 1 + len(switched)
    # the null: a mode of its own, K + 1
    method._switch(record, record.num_candidates + 1)
    assert record.landmark_id == NULL and record.mode == record.num_candidates + 1
    assert right in backend.landmarks.landmarks  # others hold it
    result = backend.result()
    assert record.landmark_id == right and right in result.landmark_ids
