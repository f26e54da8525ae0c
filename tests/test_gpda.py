"""GPDA's expectation-maximisation loop (`methods/gpda.py`) on a two-landmark case: a detection
of landmark A from a pose whose prior puts it between A and B."""

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import L, X

from pipeline.backend.candidates import Candidates
from pipeline.backend.methods.gpda import GaussianPDA
from pipeline.config import load_config
from pipeline.geometry import bearing_elevation_range
from tests.backend_cases import (
    add_landmark,
    add_pose,
    detection_of,
    hand_context,
    keyframe_at,
    measurement,
    with_settings,
)

A, B = np.array([10.0, 1.0, 0.0]), np.array([10.0, -1.0, 0.0])
TRUE_POSE = gtsam.Pose3(gtsam.Rot3(), np.array([0.0, 0.3, 0.0]))
SIGMAS = np.array([0.05, 0.05, 0.1])  # the detection's: bearing, elevation, range
SEMANTIC = np.array([0.6, 0.9])  # P(reported class | B), P(reported class | A)


def em_case(max_iterations: int, tolerance: float):
    """Pose 1 held at the origin by a prior loose across (0.5 m in y), A and B pinned 2 m
    apart, the detection of A from 0.3 m to the left. Every move counts as one (iSAM2's
    thresholds at 1e-9), so the loop runs until the weights settle or the limit.

    Returns (context, method, record, the update count before the loop, the detection)."""
    config = with_settings(
        load_config(),
        gpda={"max_iterations": max_iterations, "weight_tolerance": tolerance},
        isam2={
            "pose_translation_threshold_m": 1e-9,
            "pose_rotation_threshold_rad": 1e-9,
            "landmark_threshold_m": 1e-9,
        },
    )
    context = hand_context(config)
    method = GaussianPDA(context)
    add_pose(context, 1, gtsam.Pose3(), [1e-4, 1e-4, 1e-4, 1e-4, 0.5, 1e-4])
    a = add_landmark(context, A, 1e-4, classes=[1.0, 0.0])
    b = add_landmark(context, B, 1e-4, classes=[1.0, 0.0])
    context.solver.update()
    m = measurement(1, detection_of(TRUE_POSE, A, sigmas=SIGMAS))
    # weighed alike at first, B listed first (the first of a tie is the association)
    candidates = Candidates(np.array([b, a]), np.array([0.5, 0.5]), SEMANTIC, np.zeros(2), 2)
    record = method.associate(m, candidates, keyframe_at(1))
    moved = context.after_update(context.solver.update())
    assert X(1) in moved
    start = context.solver.num_updates
    changed = method.refine(moved)
    return context, record, context.solver.num_updates - start, changed, m


def e_step(context, m) -> np.ndarray:
    """The weights of B and A at the current estimate, worked out here: semantic likelihood
    times N(h(x, l) - z; 0, Gamma) (the normaliser alike for both), normalised."""
    pose = context.solver.pose(X(1))
    z = np.array([m.detection.bearing, m.detection.elevation, m.detection.range])
    likelihood = []
    for landmark in (B, A):
        residual = bearing_elevation_range(pose.transformTo(landmark)) - z
        likelihood.append(np.exp(-0.5 * np.sum((residual / SIGMAS) ** 2)))
    weights = SEMANTIC * np.array(likelihood)
    return weights / weights.sum()


def test_the_weights_settle_where_the_estimate_explains_them():
    tolerance = 1e-9
    context, record, updates, changed, m = em_case(max_iterations=50, tolerance=tolerance)
    # a fixed point: the E-step at the final estimate gives the weights the graph holds
    assert np.max(np.abs(e_step(context, m) - record.graph_weights)) <= tolerance
    # the answer: the detection is A's, and the pose moved from its prior towards the truth
    assert record.graph_weights[1] > 0.99
    assert 0.1 < context.solver.pose(X(1)).translation()[1] < 0.3
    assert record.landmark_id == record.landmark_ids[1]
    assert record.switches == 1 and changed == [record]  # from B (the tie's first) to A
    # it took several rounds, and stopped well before the limit
    assert 2 <= updates < 50


def test_a_looser_tolerance_stops_sooner_within_it():
    context, record, loose_updates, _, m = em_case(max_iterations=50, tolerance=1e-3)
    _, _, tight_updates, _, _ = em_case(max_iterations=50, tolerance=1e-9)
    assert 1 <= loose_updates < tight_updates
    assert np.max(np.abs(e_step(context, m) - record.graph_weights)) <= 1e-3


def test_the_loop_stops_at_max_iterations_before_the_weights_settle():
    context, record, updates, _, m = em_case(max_iterations=1, tolerance=1e-9)
    assert updates == 1
    # one M-step moved the pose; the weights it would give now differ by more than tolerance
    assert np.max(np.abs(e_step(context, m) - record.graph_weights)) > 1e-3
    # and the graph holds the first E-step's weights, from the prior's estimate (y = 0)
    assert 0.5 < record.graph_weights[1] < 0.99


def test_a_change_within_the_tolerance_is_not_applied():
    # the first E-step moves the weights by about 0.4 (0.5 -> 0.9): a tolerance of 0.6 keeps
    # the candidates' weights and updates nothing
    context, record, updates, changed, m = em_case(max_iterations=50, tolerance=0.6)
    first_change = np.max(np.abs(e_step(context, m) - 0.5))
    assert 0.2 < first_change < 0.6
    assert updates == 0 and changed == [] and record.switches == 0
    np.testing.assert_allclose(record.graph_weights, [0.5, 0.5], rtol=1e-15)


def test_each_component_s_factor_carries_its_weight():
    # both factors in the graph, each whitened by sqrt(w): its information scaled by w
    context, record, _, _, _ = em_case(max_iterations=50, tolerance=1e-9)
    graph = context.solver.isam.getFactorsUnsafe()
    information = {}
    for k in range(graph.size()):
        factor = graph.at(k)
        if factor is not None and graph.exists(k) and len(factor.keys()) == 2:
            landmark = factor.keys()[1]
            information[landmark] = np.trace(factor.noiseModel().information())
    b, a = record.landmark_ids
    w_b, w_a = record.graph_weights
    assert w_b > 10 * context.config.association.min_weight  # B's factor is kept, weak
    assert set(information) == {L(a), L(b)}
    # the two detections' factors differ only in their weight
    assert information[L(b)] / information[L(a)] == pytest.approx(w_b / w_a, rel=1e-9)
