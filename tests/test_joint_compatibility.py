"""Landmark merges as a joint likelihood test, on pair sets built by hand."""

import itertools
import math

import numpy as np
import pytest

from pipeline.backend.association import gaussian_log_density
from pipeline.backend.joint_compatibility import (
    PairSet,
    best_pairs,
    difference_covariance,
    pairs_to_merge,
)
from pipeline.backend.merges import pair_groups

PRIOR = 6.0  # log(field-of-view volume) + prior log odds, per pair


def pair_set(pairs, differences, landmark_cov, loop=None, alike=None) -> PairSet:
    ids = sorted({j for p in pairs for j in p})
    slots = {j: k for k, j in enumerate(ids)}
    return PairSet(
        pairs=pairs,
        differences=np.asarray(differences, dtype=float),
        covariance=difference_covariance(landmark_cov, pairs, slots, 3),
        log_prior=np.full(len(pairs), PRIOR),
        loop=np.zeros(len(pairs), bool) if loop is None else np.asarray(loop),
        **({} if alike is None else {"alike": alike}),
    )


def independent(n: int, sigma: float) -> np.ndarray:
    return np.eye(3 * n) * sigma**2


def test_difference_covariance_hand_computed():
    # landmarks a, b with variances 1 and 4 on every axis and covariance 0.5 between them
    C = np.block([[np.eye(3), 0.5 * np.eye(3)], [0.5 * np.eye(3), 4 * np.eye(3)]])
    D = difference_covariance(C, [(0, 1)], {0: 0, 1: 1}, 3)
    np.testing.assert_allclose(D, np.eye(3) * (1 + 4 - 2 * 0.5))


def test_score_of_one_pair_hand_computed():
    ps = pair_set([(1, 0)], [[0.1, 0.0, -0.1]], independent(2, 0.1))
    expected = gaussian_log_density(np.array([0.1, 0.0, -0.1]), np.eye(3) * 0.02) + PRIOR
    assert ps.score([0]) == pytest.approx(expected)


def test_a_sure_duplicate_is_merged():
    ps = pair_set([(5, 2)], [[0.05, -0.02, 0.0]], independent(2, 0.1))
    assert pairs_to_merge(ps, 0.95, 8.0, 2.0, 3.0, 1000) == [(5, 2)]


def test_a_far_pair_is_not():
    ps = pair_set([(5, 2)], [[1.5, 0.0, 0.0]], independent(2, 0.1))
    assert pairs_to_merge(ps, 0.95, 8.0, 2.0, 3.0, 1000) == []


def test_a_shifted_rival_as_likely_blocks_the_merge():
    # Sources 10, 11 could be targets (0, 1) or, shifted by one car, (1, 2): both explain the
    # differences equally well under a large shared uncertainty.
    pairs = [(10, 0), (11, 1), (10, 1), (11, 2)]
    diffs = [[0.0, 3.5, 0.0], [0.0, 3.5, 0.0], [0.0, -3.5, 0.0], [0.0, -3.5, 0.0]]
    n = 5
    C = independent(n, 0.05)
    ids = [0, 1, 2, 10, 11]
    for a, b in itertools.product(range(3, 5), repeat=2):  # the sources share a 5 m drift in y
        C[3 * a + 1, 3 * b + 1] += 25.0
    ps = PairSet(
        pairs=pairs,
        differences=np.array(diffs),
        covariance=difference_covariance(C, pairs, {j: k for k, j in enumerate(ids)}, 3),
        log_prior=np.full(4, PRIOR),
        loop=np.ones(4, bool),
    )
    best, score, finished = best_pairs(ps, 0.95, 1000)
    assert finished and len(best) == 2 and score > 8.0
    assert pairs_to_merge(ps, 0.95, 8.0, 2.0, 3.0, 1000) == []
    # without the shifted pairs, the same evidence merges both
    alone = PairSet(ps.pairs[:2], ps.differences[:2], ps.covariance[:6, :6],
                    ps.log_prior[:2], ps.loop[:2])  # fmt: skip
    assert sorted(pairs_to_merge(alone, 0.95, 8.0, 2.0, 3.0, 1000)) == [(10, 0), (11, 1)]


def test_a_loop_pair_cannot_borrow_a_duplicates_evidence():
    # a sure duplicate (local) and a loose loop pair: the duplicate merges, the loop does not
    C = independent(4, 0.05)
    C[9:12, 9:12] += np.eye(3)  # the loop's source is uncertain by 1 m
    pairs = [(1, 0), (3, 2)]
    ps = PairSet(
        pairs=pairs,
        differences=np.array([[0.02, 0.0, 0.0], [0.5, 0.3, 0.0]]),
        covariance=difference_covariance(C, pairs, {0: 0, 1: 1, 2: 2, 3: 3}, 3),
        log_prior=np.full(2, PRIOR),
        loop=np.array([False, True]),
    )
    best, score, _ = best_pairs(ps, 0.95, 1000)
    assert len(best) == 2 and score > 8.0  # together they pass the loop threshold ...
    assert pairs_to_merge(ps, 0.95, 8.0, 2.0, 3.0, 1000) == [(1, 0)]  # ... apart, not


def test_a_rival_alike_to_the_target_does_not_block():
    # source 7 could close a loop on 3 or on 4, but 3 and 4 are one landmark mapped twice
    pairs = [(7, 3), (7, 4)]
    loop = [True, True]
    ps = pair_set(pairs, [[0.01, 0, 0], [0.02, 0, 0]], independent(3, 0.1), loop=loop,
                  alike=lambda a, b: {a, b} == {3, 4})  # fmt: skip
    assert len(pairs_to_merge(ps, 0.95, 8.0, 2.0, 3.0, 1000)) == 1
    blocked = pair_set(pairs, [[0.01, 0, 0], [0.02, 0, 0]], independent(3, 0.1), loop=loop)
    assert pairs_to_merge(blocked, 0.95, 8.0, 2.0, 3.0, 1000) == []


def test_max_gains_bound_what_any_pair_adds():
    rng = np.random.default_rng(4)
    A = rng.normal(size=(12, 12))
    C = A @ A.T * 0.05 + np.eye(12) * 0.01
    pairs = [(4, 0), (5, 1), (6, 2), (7, 3)]
    ids = [0, 1, 2, 3, 4, 5, 6, 7]
    big = np.eye(24) * 0.01
    big[12:, 12:] += C
    ps = PairSet(
        pairs=pairs,
        differences=rng.normal(size=(4, 3)) * 0.1,
        covariance=difference_covariance(big, pairs, {j: k for k, j in enumerate(ids)}, 3),
        log_prior=np.full(4, PRIOR),
        loop=np.zeros(4, bool),
    )
    gains = ps.max_gains()
    for size in range(4):
        for subset in itertools.combinations(range(4), size):
            for p in set(range(4)) - set(subset):
                added = ps.score([*subset, p]) - ps.score(list(subset))
                assert added <= gains[p] + 1e-9


def test_pair_groups_join_shared_landmarks_and_all_loops():
    pairs = [(10, 1), (11, 1), (12, 2), (13, 3), (14, 4)]
    loop = [False, False, True, False, True]
    groups = sorted(sorted(g) for g in pair_groups(pairs, loop))
    assert groups == [[0, 1], [2, 4], [3]]


def test_log_prior_is_added_once_a_pair():
    ps = pair_set([(1, 0), (3, 2)], [[0, 0, 0], [0, 0, 0]], independent(4, 0.1))
    lik, _ = ps.log_likelihood([0, 1])
    assert ps.score([0, 1]) == pytest.approx(lik + 2 * PRIOR)
    assert math.isclose(ps.score([]), 0.0)
