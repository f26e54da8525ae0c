"""Which associations the recording calls wrong, against ground truth: hand-made cases of the
majority vote, and the running tally against a recount from scratch after every change."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.backend.hypotheses import NULL
from pipeline.evaluation import association_counts
from pipeline.viz.correctness import (
    CORRECT,
    NULL_DECISION,
    UNLABELLED,
    WRONG,
    AssociationTally,
    count,
    verdicts,
)


def test_a_landmark_stands_for_what_most_of_its_detections_saw():
    # L10 holds two detections of true 1 and one of true 2: it stands for 1
    truth = [1, 1, 2, None, 5]
    chosen = [10, 10, 10, 11, NULL]
    assert verdicts(truth, chosen) == [CORRECT, CORRECT, WRONG, UNLABELLED, NULL_DECISION]
    # a tie goes to the smaller true id
    assert verdicts([3, 2], [7, 7]) == [WRONG, CORRECT]
    # false positives (true -1) together are right; one among real ones is wrong
    assert verdicts([-1, -1, 4], [8, 8, 8]) == [CORRECT, CORRECT, WRONG]
    assert verdicts([4, 4, -1], [8, 8, 8]) == [CORRECT, CORRECT, WRONG]
    # a duplicate of a true landmark is right by the vote: the metric's rule
    assert verdicts([6, 6], [1, 2]) == [CORRECT, CORRECT]


def test_verdicts_count_as_the_metric_counts_labelled_detections():
    rng = np.random.default_rng(4)
    truth = [int(t) for t in rng.integers(-1, 6, 300)]
    chosen = [int(j) for j in rng.integers(-1, 9, 300)]
    mine = count(verdicts(truth, chosen))
    theirs = association_counts(truth, chosen)
    assert {k: mine[k] for k in ("correct", "wrong", "null")} == theirs
    assert mine[UNLABELLED] == 0


def test_the_tally_follows_associations_changes_and_merges():
    tally = AssociationTally()
    tally.assign((0, 0), 1, 1)
    tally.assign((1, 0), 1, 1)
    tally.assign((2, 0), 2, 2)
    assert tally.counts() == {CORRECT: 3, WRONG: 0, NULL_DECISION: 0, UNLABELLED: 0}
    tally.assign((3, 0), 2, 1)  # L1: true 1 twice, true 2 once
    assert tally.counts()[WRONG] == 1 and tally.verdict((3, 0)) == WRONG
    tally.merge(2, 1)  # L1: true 1 twice, true 2 twice: a tie, it stands for 1
    assert tally.wrong() == [((2, 0), 1), ((3, 0), 1)]
    tally.assign((0, 0), 1, NULL)  # L1: true 1 once, true 2 twice: now it stands for 2
    assert tally.counts() == {CORRECT: 2, WRONG: 1, NULL_DECISION: 1, UNLABELLED: 0}
    assert tally.wrong() == [((1, 0), 1)]
    assert tally.verdict((0, 0)) == NULL_DECISION and tally.verdict((2, 0)) == CORRECT
    tally.assign((4, 1), None, 1)  # unlabelled: neither right nor wrong, never in the vote
    assert tally.counts()[UNLABELLED] == 1 and tally.wrong() == [((1, 0), 1)]
    assert len(tally) == 5


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_tally_agrees_with_a_recount_after_every_change(seed):
    rng = np.random.default_rng(seed)
    tally = AssociationTally()
    held: dict[tuple[int, int], tuple[int | None, int]] = {}
    alive = list(range(6))
    for step in range(400):
        if step % 37 == 36 and len(alive) > 2:  # merge one landmark into another
            duplicate, survivor = (int(j) for j in rng.choice(alive, 2, replace=False))
            alive.remove(duplicate)
            tally.merge(duplicate, survivor)
            held = {k: (t, survivor if j == duplicate else j) for k, (t, j) in held.items()}
        else:  # a new detection, or an earlier one associated again
            if held and rng.random() < 0.4:
                keys = sorted(held)
                key = keys[int(rng.integers(len(keys)))]
                truth = held[key][0]
            else:
                key = (step, 0)
                truth = None if rng.random() < 0.05 else int(rng.integers(-1, 5))
            landmark = NULL if rng.random() < 0.1 else int(rng.choice(alive))
            tally.assign(key, truth, landmark)
            held[key] = (truth, landmark)
        keys = sorted(held)
        expected = verdicts([held[k][0] for k in keys], [held[k][1] for k in keys])
        assert tally.counts() == count(expected)
        assert [k for k, _ in tally.wrong()] == [
            k for k, v in zip(keys, expected, strict=True) if v == WRONG
        ]
        assert [tally.verdict(k) for k in keys] == expected
