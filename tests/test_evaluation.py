"""Association scores against truth: the one-to-one matching, group by group, against the
assignment over one dense matrix of every estimated by every true landmark."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from pipeline.evaluation import association_scores, landmark_truth_one_to_one


def dense_matching_weight(truth_ids, landmark_ids) -> int:
    """Detections kept together by the best one-to-one matching, solved on one dense matrix."""
    pairs = Counter(
        (e, t) for t, e in zip(truth_ids, landmark_ids, strict=True) if e >= 0 and t is not None
        and t >= 0
    )  # fmt: skip
    estimated = sorted({e for e, _ in pairs})
    true = sorted({t for _, t in pairs})
    shared = np.zeros((len(estimated), len(true)))
    for (e, t), n in pairs.items():
        shared[estimated.index(e), true.index(t)] = n
    rows, cols = linear_sum_assignment(shared, maximize=True)
    return int(shared[rows, cols].sum())


def test_a_duplicate_and_a_lookalike_by_hand():
    # true 0 seen 5 times: 3 on landmark 10, 2 on its duplicate 11; true 1 seen twice on 12
    # and once on 10 (a lookalike confused with it); a false detection (-1) on 10
    truth = [0, 0, 0, 0, 0, 1, 1, 1, -1, None]
    chosen = [10, 10, 10, 11, 11, 12, 12, 10, 10, 12]
    assert landmark_truth_one_to_one(truth, chosen) == {10: 0, 12: 1}
    scores = association_scores(truth, chosen)
    assert (scores["correct"], scores["wrong"], scores["null"]) == (5, 3, 0)
    assert scores["false_positives_used"] == 1


@pytest.mark.parametrize("seed", range(6))
def test_groups_matched_apart_keep_what_the_whole_matching_keeps(seed):
    rng = np.random.default_rng(seed)
    true_count = 40
    truth, chosen = [], []
    for _ in range(600):
        t = int(rng.integers(-1, true_count))
        # mostly its own landmark, sometimes a duplicate, a neighbour's, or the null
        e = int(rng.choice([t, t + 100, (t + 1) % true_count, -1], p=[0.7, 0.15, 0.1, 0.05]))
        truth.append(t)
        chosen.append(e if t >= 0 else int(rng.integers(0, true_count)))
    matched = landmark_truth_one_to_one(truth, chosen)
    assert len(set(matched.values())) == len(matched)  # one to one
    kept = sum(1 for t, e in zip(truth, chosen, strict=True) if e >= 0 and matched.get(e) == t)
    assert kept == dense_matching_weight(truth, chosen)
