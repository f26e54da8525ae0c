"""Landmark merges on small states built by hand: which pairs `MergeFinder` proposes, and what
`MaxMixture.merge` does to the records, the graph and the map."""

import itertools
import math

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import L, X

from pipeline.backend import association as assoc
from pipeline.backend.hypotheses import NULL, AssociationRecord
from pipeline.backend.landmarks import LandmarkKind
from pipeline.backend.merges import MergeFinder
from pipeline.backend.methods.maxmixture import MaxMixture
from pipeline.config import load_config
from tests.backend_cases import (
    add_landmark,
    add_pose,
    detection_of,
    factor_keys,
    hand_context,
    measurement,
    past_record,
    with_settings,
)

# --- MaxMixture.merge ---------------------------------------------------------------------------

POSES = [gtsam.Pose3(gtsam.Rot3(), np.array([float(i), 0.0, 0.0])) for i in range(3)]


@pytest.fixture
def two_estimates_of_one_landmark():
    """Landmark `a` and its duplicate `b` 10 cm apart, and `c` elsewhere; six records, each a
    way a record can hold the duplicate. Committed to iSAM2."""
    context = hand_context()
    method = MaxMixture(context, null_hypothesis=True)
    for i, pose in enumerate(POSES):
        add_pose(context, i, pose, 1e-3)
    a = add_landmark(context, [10.0, 2.0, 0.0], 5.0, classes=[0.8, 0.2])
    b = add_landmark(context, [10.1, 2.0, 0.0], 5.0, classes=[0.6, 0.4])
    c = add_landmark(context, [10.0, -3.0, 0.0], 5.0)
    positions = {a: [10.0, 2.0, 0.0], b: [10.1, 2.0, 0.0], c: [10.0, -3.0, 0.0]}
    detection_index = itertools.count()  # each record of a detection of its own

    def record(pose, seen, ids, weights, active):
        detection = detection_of(POSES[pose], positions[seen])
        m = measurement(pose, detection, next(detection_index))
        mixture = len(ids) > 1
        r = past_record(context, m, ids, weights, active, 0.1 if mixture else 0.0)
        return method.track(r) if mixture else r

    records = {
        "a alone": record(0, a, [a], [1.0], 0),
        "b alone": record(1, b, [b], [1.0], 0),
        "b of b, c": record(2, b, [b, c], [0.6, 0.3], 0),
        "c of c, b": record(2, c, [c, b], [0.7, 0.2], 0),
        "b of a, b": record(1, a, [a, b], [0.3, 0.6], 1),
        "null of b, c": record(2, b, [b, c], [0.5, 0.4], NULL),
    }
    context.solver.update()
    return context, method, (a, b, c), records


def test_a_merge_re_points_every_record_of_the_duplicate(two_estimates_of_one_landmark):
    context, method, (a, b, c), records = two_estimates_of_one_landmark
    method.merge(a, b)
    expected = {  # components, their weights (a duplicate's added to the survivor's), active
        "a alone": ([a], [1.0], 0),
        "b alone": ([a], [1.0], 0),
        "b of b, c": ([a, c], [0.6, 0.3], 0),
        "c of c, b": ([c, a], [0.7, 0.2], 0),
        "b of a, b": ([a], [0.9], 0),
        "null of b, c": ([a, c], [0.5, 0.4], NULL),
    }
    for name, (ids, weights, active) in expected.items():
        r = records[name]
        assert r.landmark_ids == ids, name
        np.testing.assert_allclose(r.weights, weights, rtol=1e-12, err_msg=name)
        assert r.active == active, name
        assert len(r.handles) == (0 if active == NULL else 1), name
    # every record that may be the survivor is indexed under it, once
    assert sorted(map(id, context.records_of[a])) == sorted(map(id, records.values()))
    assert b not in context.records_of
    # the tracked mixtures are revisited when the survivor moves
    tracked = [r for r in records.values() if r.is_mixture]
    assert set(map(id, method.affected({L(a)}))) == set(map(id, tracked))


def test_a_merge_leaves_no_factor_on_the_duplicate(two_estimates_of_one_landmark):
    context, method, (a, b, c), _ = two_estimates_of_one_landmark
    before = [k for k in factor_keys(context.solver) if len(k) == 2]
    assert (X(1), L(b)) in before
    method.merge(a, b)
    context.solver.update()
    keys = factor_keys(context.solver)
    assert not [k for k in keys if L(b) in k]  # its detections' factors and its anchor gone
    # one factor for each record's active component: detections of poses 0, 1, 2, 1 on a
    detections = sorted(k for k in keys if len(k) == 2)
    assert detections == sorted(
        [(X(0), L(a)), (X(1), L(a)), (X(2), L(a)), (X(1), L(a)), (X(2), L(c))]
    )
    # a now holds the detections b held: its position is pulled to the pair's 10 cm apart
    position = context.solver.point(L(a))
    assert 10.0 < position[0] < 10.1


def test_a_merge_combines_the_classes_and_forgets_the_duplicate(two_estimates_of_one_landmark):
    context, method, (a, b, _), _ = two_estimates_of_one_landmark
    assert context.last_seen[a] == 0 and context.last_seen[b] == 2
    method.merge(a, b)
    # both posteriors hold the uniform prior once: their product, normalised, counts it once
    # [0.8, 0.2] * [0.6, 0.4] = [0.48, 0.08] -> [6/7, 1/7]
    np.testing.assert_allclose(
        context.landmarks.landmarks[a].class_probabilities, [6 / 7, 1 / 7], rtol=1e-12
    )
    assert b not in context.landmarks.landmarks
    assert context.landmarks.resolve(b) == a
    assert b not in context.landmarks.near(LandmarkKind.POINT, np.array([10.1, 2.0, 0.0]), 1.0)
    # the survivor was seen when either was last seen
    assert context.last_seen[a] == 2 and b not in context.last_seen


# --- MergeFinder.candidate_pairs ----------------------------------------------------------------

SIGMA = 1.0  # every landmark's marginal: an isotropic prior of 1 m
NOW = 100  # the pose of the check; recent_keyframes (30) back from it is "lately"
LATELY, LONG_AGO = NOW - 5, NOW - 60


def finder_context(**merges):
    """A context whose landmarks are pinned by 1 m priors, and a finder over it (no search
    margin: the reach is search_sigmas standard deviations exactly)."""
    config = with_settings(load_config(), merges=merges) if merges else load_config()
    context = hand_context(config)
    return context, MergeFinder(context, config.merges, margin_m=0.0, space=None)


def seen(context, landmark: int, *poses: int) -> None:
    """Detections of the landmark from these poses, as records the context indexes (without
    factors: the finder reads only which keyframes saw what)."""
    position = context.landmarks.position(landmark)
    for pose in poses:
        m = measurement(pose, detection_of(gtsam.Pose3(), position))
        context.register(AssociationRecord(m, [landmark], np.ones(1)))


def landmark_at(context, position, classes=(1.0, 0.0), poses=None) -> int:
    """A landmark seen from `poses`; by default lately, from a keyframe of its own."""
    j = add_landmark(context, position, SIGMA, classes=classes)
    seen(context, j, *(poses or (LATELY - j,)))
    return j


def pairs(context, finder) -> list[tuple[int, int]]:
    context.solver.update()
    return finder.candidate_pairs(NOW)


def reach(config) -> float:
    """How far a source looks: search_sigmas times the spread of the difference of two
    landmarks each known to SIGMA (sqrt 2 SIGMA), at drift scale 1."""
    return config.search_sigmas * math.sqrt(2.0) * SIGMA


def test_pairs_are_proposed_within_reach_and_the_newer_is_the_source():
    context, finder = finder_context()
    r = reach(finder.config)  # 4.24 m, inside the gate: 4.24^2 / (2 + 2) = 4.5 < 16.3
    assert r**2 / (4 * SIGMA**2) < assoc.chi2_gate(3, finder.config.local_confidence)
    old = landmark_at(context, [0.0, 0.0, 0.0])
    inside = landmark_at(context, [0.0, 0.98 * r, 0.0])
    outside = landmark_at(context, [0.0, -1.02 * r, 0.0])
    # inside and outside are 2 r apart: no pair between them either
    assert pairs(context, finder) == [(inside, old)]
    assert outside not in {j for pair in pairs(context, finder) for j in pair}


def test_pairs_need_classes_that_agree():
    # min_class_agreement 0.02: p.q of [0.99, 0.01] and [0.01, 0.99] is 0.0198, of [0.98, 0.02]
    # and [0.02, 0.98] 0.0392
    context, finder = finder_context()
    assert finder.config.min_class_agreement == pytest.approx(0.02)
    landmark_at(context, [0.0, 0.0, 0.0], classes=(0.99, 0.01))
    landmark_at(context, [1.0, 0.0, 0.0], classes=(0.01, 0.99))
    context2, finder2 = finder_context()
    a2 = landmark_at(context2, [0.0, 0.0, 0.0], classes=(0.98, 0.02))
    b2 = landmark_at(context2, [1.0, 0.0, 0.0], classes=(0.02, 0.98))
    assert pairs(context, finder) == []
    assert pairs(context2, finder2) == [(b2, a2)]


def test_landmarks_seen_in_one_keyframe_are_never_paired():
    context, finder = finder_context()
    a = landmark_at(context, [0.0, 0.0, 0.0], poses=(LATELY, LATELY + 1))
    b = landmark_at(context, [1.0, 0.0, 0.0], poses=(LATELY + 1,))  # beside a, at once
    c = landmark_at(context, [0.0, 1.0, 0.0], poses=(LATELY + 2,))
    assert pairs(context, finder) == [(c, a), (c, b)]


def test_only_landmarks_seen_lately_are_sources():
    context, finder = finder_context()
    a = landmark_at(context, [0.0, 0.0, 0.0], poses=(LONG_AGO,))
    landmark_at(context, [1.0, 0.0, 0.0], poses=(LONG_AGO - 1,))
    assert pairs(context, finder) == []  # neither was seen within recent_keyframes
    c = landmark_at(context, [0.0, 1.0, 0.0])  # seen lately, near both
    assert sorted(pairs(context, finder)) == [(c, a), (c, a + 1)]


def test_the_final_check_takes_the_changed_landmarks_as_sources_seen_lately_or_not():
    context, finder = finder_context()
    a = landmark_at(context, [0.0, 0.0, 0.0], poses=(LONG_AGO,))
    b = landmark_at(context, [1.0, 0.0, 0.0], poses=(LONG_AGO - 1,))
    c = landmark_at(context, [50.0, 0.0, 0.0], poses=(LONG_AGO - 2,))
    d = landmark_at(context, [50.0, 1.0, 0.0], poses=(LONG_AGO - 3,))
    context.changed = {a, b, c, d}
    assert pairs(context, finder) == []  # a check at a keyframe: none was seen lately
    context.changed = {a, b, c}  # d is near c only: c is its pair's source
    context.solver.update()
    assert finder.candidate_pairs(NOW, final=True) == [(b, a), (d, c)]
    assert context.changed == set()


def test_the_final_check_leaves_the_sources_past_max_landmarks_waiting():
    context, finder = finder_context(max_landmarks=2)
    a = landmark_at(context, [0.0, 0.0, 0.0], poses=(LONG_AGO,))
    b = landmark_at(context, [1.0, 0.0, 0.0], poses=(LONG_AGO - 1,))
    c = landmark_at(context, [50.0, 0.0, 0.0], poses=(LONG_AGO - 2,))
    d = landmark_at(context, [50.0, 1.0, 0.0], poses=(LONG_AGO - 3,))
    context.changed = {a, b, c, d}
    context.solver.update()
    # the latest seen first: a and b fill max_landmarks; c and d wait for the next check
    assert finder.candidate_pairs(NOW, final=True) == [(b, a)]
    assert context.changed == {c, d}
    assert finder.candidate_pairs(NOW, final=True) == [(d, c)]
    assert context.changed == set()


def test_a_source_keeps_its_max_partners_nearest():
    context, finder = finder_context(max_partners=2)
    # partners seen long ago are no sources themselves: only the recent source's list counts
    far = landmark_at(context, [2.5, 0.0, 0.0], poses=(LONG_AGO,))
    near = landmark_at(context, [0.5, 0.0, 0.0], poses=(LONG_AGO,))
    middle = landmark_at(context, [0.0, -1.5, 0.0], poses=(LONG_AGO,))
    source = landmark_at(context, [0.0, 0.0, 0.0])
    assert pairs(context, finder) == [(source, near), (source, middle)]
    assert far not in {j for pair in pairs(context, finder) for j in pair}


@pytest.mark.parametrize(("max_landmarks", "sources_taken"), [(2, 1), (3, 1), (4, 2)])
def test_sources_are_taken_the_latest_first_up_to_max_landmarks(max_landmarks, sources_taken):
    context, finder = finder_context(max_landmarks=max_landmarks)
    # two sources 50 m apart, each with one old partner: the later seen comes first
    earlier_partner = landmark_at(context, [50.0, 1.0, 0.0], poses=(LONG_AGO,))
    earlier = landmark_at(context, [50.0, 0.0, 0.0], poses=(LATELY,))
    later_partner = landmark_at(context, [0.0, 1.0, 0.0], poses=(LONG_AGO,))
    later = landmark_at(context, [0.0, 0.0, 0.0], poses=(LATELY + 1,))
    expected = [(later, later_partner), (earlier, earlier_partner)][:sources_taken]
    assert pairs(context, finder) == sorted(expected)


def test_nothing_seen_or_moved_since_the_last_check_proposes_nothing():
    context, finder = finder_context()
    a = landmark_at(context, [0.0, 0.0, 0.0])
    b = landmark_at(context, [1.0, 0.0, 0.0])
    assert pairs(context, finder) == [(b, a)]
    assert pairs(context, finder) == []  # the check emptied `changed`
    context.changed.add(a)
    assert pairs(context, finder) == [(b, a)]


def bounds_computed(context) -> set[int]:
    return {j for j, lm in context.landmarks.landmarks.items() if lm.covariance_bound is not None}


def test_a_check_computes_max_marginals_at_most_and_the_sources_left_wait_for_the_next():
    # four landmarks of one keyframe beside an old one: each a source paired with it
    context, finder = finder_context(max_marginals=2)
    old = landmark_at(context, [0.0, 0.0, 0.0], poses=(LONG_AGO,))
    crowd = [landmark_at(context, [0.3 * k, 1.0, 0.0], poses=(LATELY,)) for k in range(4)]
    # the first source's bound and its partner's: the budget; the other three wait, apart
    assert pairs(context, finder) == [(crowd[0], old)]
    assert bounds_computed(context) == {old, crowd[0]}
    assert context.changed == set(crowd[1:])
    # the next check: the bounds kept cost nothing, two more sources fit
    assert pairs(context, finder) == [(crowd[0], old), (crowd[1], old), (crowd[2], old)]
    assert pairs(context, finder) == [(j, old) for j in crowd]
    assert context.changed == set()


def test_within_max_marginals_a_check_pairs_as_without_a_budget():
    # two old landmarks, and six new from two keyframes: 6 x 2 + 3 x 3 pairs, 8 marginals
    sources = []
    for budget in (10**6, 8):
        context, finder = finder_context(max_marginals=budget)
        landmark_at(context, [0.0, 0.0, 0.0], poses=(LONG_AGO,))
        landmark_at(context, [2.0, 0.0, 0.0], poses=(LONG_AGO,))
        for k in range(6):
            landmark_at(context, [0.4 * k, 1.0, 0.0], poses=(LATELY - k % 2,))
        sources.append(pairs(context, finder))
    assert sources[0] == sources[1] and len(sources[0]) == 21
