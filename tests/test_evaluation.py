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


# --- against independent computations --------------------------------------------------------


def random_pose(rng: np.random.Generator, spread: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rng.normal(size=3) * spread).as_matrix()
    T[:3, 3] = rng.normal(size=3) * 10 * spread
    return T


@pytest.mark.parametrize("seed", range(3))
def test_absolute_errors_are_those_after_aligning_the_first_poses(seed):
    """An estimate in another frame (its first pose anywhere) with errors of its own: APE
    computed here by hand, in metres and radians."""
    from pipeline.evaluation import absolute_errors

    rng = np.random.default_rng(seed)
    reference = np.array([random_pose(rng, 1.0) for _ in range(12)])
    elsewhere = random_pose(rng, 2.0)  # the estimate's frame
    estimated = np.array([elsewhere @ T @ random_pose(rng, 0.05) for T in reference])
    estimated[0] = elsewhere @ reference[0]  # the first poses agree once aligned
    translation, rotation = absolute_errors(estimated, reference, np.arange(12) * 0.1)

    align = reference[0] @ np.linalg.inv(estimated[0])
    t_err, r_err = [], []
    for est, ref in zip(estimated, reference, strict=True):
        aligned = align @ est
        t_err.append(np.linalg.norm(aligned[:3, 3] - ref[:3, 3]))
        cos = (np.trace(ref[:3, :3].T @ aligned[:3, :3]) - 1) / 2
        r_err.append(np.arccos(np.clip(cos, -1.0, 1.0)))
    for stats, errors in ((translation, np.array(t_err)), (rotation, np.array(r_err))):
        expected = {
            "max": errors.max(),
            "mean": errors.mean(),
            "median": np.median(errors),
            "rmse": np.sqrt(np.mean(errors**2)),
        }
        assert stats == pytest.approx(expected, rel=1e-6, abs=1e-9)
    assert 0.01 < rotation["max"] < 1.0  # radians, not degrees


def test_majority_counts_by_hand():
    from pipeline.evaluation import association_counts, landmark_truth_by_majority

    # landmark 5: true 3 twice, true 2 twice (a tie: the smaller true id); detections without
    # truth (None) do not vote; landmark 6: true 0 once
    truth = [3, 3, 2, 2, None, None, None, 0, 1]
    chosen = [5, 5, 5, 5, 5, 5, 6, 6, -1]
    assert landmark_truth_by_majority(truth, chosen) == {5: 2, 6: 0}
    assert association_counts(truth, chosen) == {"correct": 3, "wrong": 5, "null": 1}


def test_scores_by_hand_true_landmark_zero_included():
    # true 0: 3 on landmark 7, 1 on 8 (a duplicate), 1 null; true 1: 2 on 9; false positives:
    # one on 7 (matched to a real landmark: used), one on 4 (a landmark of false ones only)
    truth = [0, 0, 0, 0, 0, 1, 1, -1, -1]
    chosen = [7, 7, 7, 8, -1, 9, 9, 7, 4]
    assert landmark_truth_one_to_one(truth, chosen) == {7: 0, 9: 1}
    scores = association_scores(truth, chosen)
    assert scores == {
        "correct": 5,
        "wrong": 1,
        "null": 1,
        "precision": round(5 / 6, 6),
        "recall": round(5 / 7, 6),
        "false_positives_used": 1,
        "true_landmarks_seen": 2,
        "landmarks_per_true": 1.5,  # 7, 8 and 9 hold real detections, of 2 true landmarks
    }


def test_the_matching_keeps_the_most_detections_and_never_matches_on_none():
    # landmark 1 shares 3 detections with true 10 and 2 with true 11; landmark 2 shares 2 with
    # true 11 and none with true 10: the best matching is 1-10, 2-11 (5 kept, not 4)
    truth = [10, 10, 10, 11, 11, 11, 11]
    chosen = [1, 1, 1, 1, 1, 2, 2]
    assert landmark_truth_one_to_one(truth, chosen) == {1: 10, 2: 11}
    # landmark 1: true 10 three times, true 11 once; landmark 2: true 10 once. The best
    # assignment pairs 1-10 and leaves 2 with 11, which it shares nothing with: unmatched
    assert landmark_truth_one_to_one([10, 10, 10, 11, 10], [1, 1, 1, 1, 2]) == {1: 10}
