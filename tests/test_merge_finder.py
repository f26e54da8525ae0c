"""`MergeFinder.find` on small maps built by hand: two point landmarks pinned by priors of known
width, seen lately or long ago, and the sensor at the origin looking along x. The score of a
lone pair is worked out here (scipy's density, the measurement box's world volume, the
landmarks in view), and which pairs merge follows from it: a local pair at the local gate's
confidence and `local_log_odds`, a loop pair at the loop's confidence, under the drift the
loops allow, and `loop_log_odds`."""

import math

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import X
from scipy.stats import multivariate_normal

from pipeline.backend.candidates import PosePrediction
from pipeline.backend.hypotheses import AssociationRecord
from pipeline.backend.landmarks import LandmarkKind
from pipeline.backend.merges import MergeFinder
from pipeline.config import load_config
from tests.backend_cases import (
    add_landmark,
    add_pose,
    detection_of,
    hand_context,
    measurement,
    with_settings,
)

NOW = 100  # the check's keyframe; recent_keyframes (30) back from it is "lately"
LATELY, LONG_AGO = NOW - 5, NOW - 60
# The measurement box the detections spanned: bearing +-1 rad, elevation +-0.3 rad, 1 to 20 m.
CORNERS = ([-1.0, -0.3, 1.0], [1.0, 0.3, 20.0])
WORLD_VOLUME = (20.0**3 - 1.0**3) / 3.0 * 2.0 * (math.sin(0.3) - math.sin(-0.3))


def finder(**merges):
    config = with_settings(load_config(), merges={"local_detection_noise": False, **merges})
    context = hand_context(config)
    space = context.space[LandmarkKind.POINT]
    for corner in CORNERS:
        space.observe(np.array(corner), np.eye(3) * 1e-4)
    for pose in (LONG_AGO, *range(LATELY - 10, LATELY + 1)):  # where detections are seen from
        add_pose(context, pose, gtsam.Pose3(), 1e-3)
    return context, MergeFinder(context, config.merges, margin_m=0.0, space=space)


def landmark(context, position, sigma, poses, classes=(1.0, 0.0)) -> int:
    """A landmark pinned by a prior of `sigma` (its marginal), seen from these poses (records
    without factors, from poses pinned at the origin)."""
    j = add_landmark(context, position, sigma, classes=classes)
    for pose in poses:
        m = measurement(pose, detection_of(gtsam.Pose3(), position))
        context.register(AssociationRecord(m, [j], np.ones(1)))
    return j


def find(context, merge_finder) -> list[tuple[int, int]]:
    context.solver.update()
    prediction = PosePrediction(NOW, X(NOW - 1), gtsam.Pose3(), np.eye(6), np.zeros((6, 6)))
    return merge_finder.find(NOW, prediction)


def local_score(offset: float, sigma: float, in_view: int, agreement: float = 1.0) -> float:
    """A lone local pair's score: the density of its difference (covariance 2 sigma^2 I) plus
    the log world volume over the landmarks in view, the prior odds (0) and the classes."""
    density = multivariate_normal(np.zeros(3), 2 * sigma**2 * np.eye(3)).logpdf([offset, 0, 0])
    return density + math.log(WORLD_VOLUME / in_view) + math.log(agreement)


@pytest.mark.parametrize("offset", [0.005, 0.03])
def test_a_local_duplicate_merges_into_the_older(offset):
    context, merge_finder = finder()
    old = landmark(context, [5.0, 0.0, 0.0], 0.01, [LATELY - 3])
    new = landmark(context, [5.0 + offset, 0.0, 0.0], 0.01, [LATELY])
    assert local_score(offset, 0.01, 2) > 2.0
    assert find(context, merge_finder) == [(new, old)]


def test_a_local_pair_passes_the_local_gate_not_the_loop_s():
    """d^2 = 10 (0.045 m at 1 cm each): inside the local gate (16.3 at 0.999), outside the
    loop's (7.8 at 0.95), and sure (score 12.5)."""
    context, merge_finder = finder()
    offset = math.sqrt(10.0 * 2 * 0.01**2)
    old = landmark(context, [5.0, 0.0, 0.0], 0.01, [LATELY - 3])
    new = landmark(context, [5.0 + offset, 0.0, 0.0], 0.01, [LATELY])
    assert local_score(offset, 0.01, 2) > 8.0
    assert find(context, merge_finder) == [(new, old)]


def test_a_loop_the_drift_explains_closes_and_teaches_the_drift():
    """The same pair, its older landmark seen long ago: outside the loop's gate at the map's
    covariance, inside it under the widest drift (100 times), and likely under the drift
    mixture: it closes, and the drift belief takes it."""
    context, merge_finder = finder()
    offset = math.sqrt(10.0 * 2 * 0.01**2)
    old = landmark(context, [5.0, 0.0, 0.0], 0.01, [LONG_AGO])
    new = landmark(context, [5.0 + offset, 0.0, 0.0], 0.01, [LATELY])
    before = merge_finder.drift_belief.log_weights.copy()
    assert find(context, merge_finder) == [(new, old)]
    assert merge_finder.drift_belief.loops == 1
    assert np.max(np.abs(merge_finder.drift_belief.log_weights - before)) > 1e-3


@pytest.mark.parametrize(("d2", "merged"), [(0.5, True), (10.0, False)])
def test_the_final_check_pairs_landmarks_seen_long_ago_as_the_map_stands(d2, merged):
    """Both landmarks seen long ago: a check at a keyframe leaves them; the log's last one
    tests them at the map's covariance. d^2 = 0.5 merges; d^2 = 10, which a loop's drift lets
    through, does not. The drift belief is left as it was: no test follows."""
    context, merge_finder = finder()
    offset = math.sqrt(d2 * 2 * 0.01**2)
    old = landmark(context, [5.0, 0.0, 0.0], 0.01, [LONG_AGO])
    new = landmark(context, [5.0 + offset, 0.0, 0.0], 0.01, [LONG_AGO + 1])
    assert find(context, merge_finder) == []
    before = merge_finder.drift_belief.log_weights.copy()
    context.changed = {old, new}
    prediction = PosePrediction(NOW, X(NOW - 1), gtsam.Pose3(), np.eye(6), np.zeros((6, 6)))
    assert merge_finder.find(NOW, prediction, final=True) == ([(new, old)] if merged else [])
    assert merge_finder.drift_belief.loops == 0
    np.testing.assert_array_equal(merge_finder.drift_belief.log_weights, before)


@pytest.mark.parametrize(("last_seen", "merged"), [(LATELY - 3, True), (LONG_AGO, False)])
def test_a_loop_pair_must_reach_loop_log_odds_where_a_local_one_needs_local(last_seen, merged):
    """Landmarks known to 0.3 m, 2 cm apart: the pair scores about 6.8, above local_log_odds
    (2) and below loop_log_odds (8), which the drift mixture only lowers."""
    context, merge_finder = finder()
    score = local_score(0.02, 0.3, 2)
    assert 2.0 < score < 8.0
    old = landmark(context, [5.0, 0.0, 0.0], 0.3, [last_seen])
    new = landmark(context, [5.02, 0.0, 0.0], 0.3, [LATELY])
    assert find(context, merge_finder) == ([(new, old)] if merged else [])


@pytest.mark.parametrize(
    ("classes", "merged"), [((1.0, 0.0), True), ((0.9, 0.1), True), ((0.2, 0.8), False)]
)
def test_classes_that_disagree_weigh_against_a_merge(classes, merged):
    """A pair scoring about 2.8 with classes agreeing: the new landmark's classes against the
    old one's [0.9, 0.1] multiply its odds by their agreement (0.9, 0.83, 0.26)."""
    context, merge_finder = finder(prior_log_odds=-4.3)
    old = landmark(context, [5.0, 0.0, 0.0], 0.3, [LATELY - 3], classes=(0.9, 0.1))
    new = landmark(context, [5.02, 0.0, 0.0], 0.3, [LATELY], classes=classes)
    agreement = float(np.dot(classes, (0.9, 0.1)))
    score = local_score(0.02, 0.3, 2, agreement) - 4.3
    assert (score >= 2.0) == merged and abs(score - 2.0) > 0.3
    assert find(context, merge_finder) == ([(new, old)] if merged else [])


@pytest.mark.parametrize(("new_sightings", "merged"), [(2, True), (1, False)])
def test_a_detection_s_noise_is_allowed_once_both_hold_two(new_sightings, merged):
    """Landmarks known to 1 cm, 8 cm apart along the range: d^2 = 32 without a detection's
    noise (0.1 m in range), 0.6 with it; allowed only where each holds two detections."""
    context, merge_finder = finder(local_detection_noise=True)
    old = landmark(context, [5.0, 0.0, 0.0], 0.01, [LATELY - 10, LATELY - 9])
    poses = [LATELY - 1, LATELY][-new_sightings:]
    new = landmark(context, [5.08, 0.0, 0.0], 0.01, poses)
    assert find(context, merge_finder) == ([(new, old)] if merged else [])


def test_the_landmarks_in_view_are_averaged_over_the_checks():
    context, merge_finder = finder()
    for k in range(3):  # three in view, one behind the sensor
        landmark(context, [5.0, 2.0 * k, 0.0], 0.1, [LATELY])
    landmark(context, [-5.0, 0.0, 0.0], 0.1, [LATELY])
    context.solver.update()
    prediction = PosePrediction(NOW, X(NOW - 1), gtsam.Pose3(), np.eye(6), np.zeros((6, 6)))
    assert merge_finder._landmarks_in_view(prediction) == pytest.approx(3.0)
    turned = gtsam.Pose3(gtsam.Rot3.Yaw(math.pi), np.zeros(3))  # now only the one behind
    behind = PosePrediction(NOW, X(NOW - 1), turned, np.eye(6), np.zeros((6, 6)))
    assert merge_finder._landmarks_in_view(behind) == pytest.approx((3 + 1) / 2)
