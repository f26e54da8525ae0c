"""Trajectory and association metrics against a log's ground truth.

Trajectory errors are evo's absolute pose errors (APE) after aligning the first poses, as in
the paper: translation in metres, rotation as the angle of the relative rotation in radians.
"""

from __future__ import annotations

from collections import Counter
from typing import Any

import numpy as np

STATISTICS = ("max", "mean", "median", "rmse")


def absolute_errors(
    estimated: np.ndarray, reference: np.ndarray, stamps_s: np.ndarray
) -> tuple[dict[str, float], dict[str, float]]:
    """Translation (m) and rotation (rad) APE statistics of (N, 4, 4) poses, origin-aligned."""
    from evo.core import metrics
    from evo.core.trajectory import PoseTrajectory3D

    est = PoseTrajectory3D(poses_se3=list(estimated), timestamps=np.asarray(stamps_s, float))
    ref = PoseTrajectory3D(poses_se3=list(reference), timestamps=np.asarray(stamps_s, float))
    est.align_origin(ref)
    out = []
    for relation in (
        metrics.PoseRelation.translation_part,
        metrics.PoseRelation.rotation_angle_rad,
    ):
        ape = metrics.APE(relation)
        ape.process_data((ref, est))
        stats = ape.get_all_statistics()
        out.append({name: float(stats[name]) for name in STATISTICS})
    return out[0], out[1]


def landmark_truth_by_majority(
    truth_ids: list[int | None], landmark_ids: list[int]
) -> dict[int, int]:
    """Each estimated landmark stands for the true landmark most of its detections saw
    (ties to the smallest true id, so that results are deterministic)."""
    votes: dict[int, Counter[int]] = {}
    for truth, landmark in zip(truth_ids, landmark_ids, strict=True):
        if landmark < 0 or truth is None:
            continue
        votes.setdefault(landmark, Counter())[truth] += 1
    return {
        landmark: min(counter.items(), key=lambda kv: (-kv[1], kv[0]))[0]
        for landmark, counter in votes.items()
    }


def association_counts(truth_ids: list[int | None], landmark_ids: list[int]) -> dict[str, int]:
    """Detections whose final landmark stands for their true landmark (`correct`), for another
    (`wrong`), or that the null hypothesis took (`null`). A false positive (truth -1) is correct
    on a landmark made of false positives."""
    stands_for = landmark_truth_by_majority(truth_ids, landmark_ids)
    counts = {"correct": 0, "wrong": 0, "null": 0}
    for truth, landmark in zip(truth_ids, landmark_ids, strict=True):
        if landmark < 0:
            counts["null"] += 1
        elif truth is not None and stands_for.get(landmark) == truth:
            counts["correct"] += 1
        else:
            counts["wrong"] += 1
    return counts


def landmark_truth_one_to_one(
    truth_ids: list[int | None], landmark_ids: list[int]
) -> dict[int, int]:
    """Each true landmark stands for at most one estimated landmark, and each estimated one
    for at most one true one: the matching that keeps the most detections together (an
    assignment problem). A duplicate of a true landmark is left unmatched, so its detections
    count as wrong, which majority voting hides.

    The landmarks that share detections form small groups (a true landmark, its duplicates,
    the lookalikes they were confused with): each group is matched on its own. One dense
    matrix of every estimated by every true landmark held 8,400 x 8,400 entries on a 50,000-pose
    log, gigabytes and the assignment's cubic time."""
    from scipy.optimize import linear_sum_assignment
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    pairs = Counter(
        (landmark, truth)
        for truth, landmark in zip(truth_ids, landmark_ids, strict=True)
        if landmark >= 0 and truth is not None and truth >= 0
    )
    if not pairs:
        return {}
    estimated = sorted({e for e, _ in pairs})
    true = sorted({t for _, t in pairs})
    row = {e: i for i, e in enumerate(estimated)}
    col = {t: i for i, t in enumerate(true)}
    rows = np.array([row[e] for e, _ in pairs])
    cols = np.array([col[t] for _, t in pairs])
    shared = coo_matrix(
        (np.array(list(pairs.values())), (rows, cols)), shape=(len(estimated), len(true))
    ).tocsr()
    # the bipartite graph's groups: estimated landmarks first, then the true ones
    n = len(estimated)
    links = coo_matrix((np.ones(len(rows)), (rows, n + cols)), shape=(n + len(true),) * 2)
    _, group = connected_components(links, directed=False)
    order = np.argsort(group, kind="stable")
    starts = np.flatnonzero(np.diff(group[order], prepend=-1))
    matched: dict[int, int] = {}
    for members in np.split(order, starts[1:]):
        mine, theirs = members[members < n], members[members >= n] - n
        block = shared[mine][:, theirs].toarray()
        for r, c in zip(*linear_sum_assignment(block, maximize=True), strict=True):
            if block[r, c] > 0:
                matched[estimated[mine[r]]] = true[theirs[c]]
    return matched


def association_scores(truth_ids: list[int | None], landmark_ids: list[int]) -> dict[str, Any]:
    """Association quality with landmarks matched to truth one to one.

    Over detections of real landmarks (truth >= 0): `correct` went to the landmark matched to
    their truth, `wrong` to another landmark (a duplicate included), `null` to none.
    `precision` = correct / (correct + wrong), `recall` = correct / all of them.
    `false_positives_used`: detections of nothing (truth -1) that pull on a landmark matched
    to a real one. `landmarks_per_true`: estimated landmarks holding a real landmark's
    detection, per real landmark seen."""
    stands_for = landmark_truth_one_to_one(truth_ids, landmark_ids)
    correct = wrong = null = false_used = 0
    holding: set[int] = set()
    seen: set[int] = set()
    for truth, landmark in zip(truth_ids, landmark_ids, strict=True):
        if truth is None:
            continue
        if truth < 0:
            false_used += int(landmark in stands_for)
            continue
        seen.add(truth)
        if landmark < 0:
            null += 1
            continue
        holding.add(landmark)
        if stands_for.get(landmark) == truth:
            correct += 1
        else:
            wrong += 1
    decided = correct + wrong
    total = decided + null
    return {
        "correct": correct,
        "wrong": wrong,
        "null": null,
        "precision": round(correct / decided, 6) if decided else 1.0,
        "recall": round(correct / total, 6) if total else 1.0,
        "false_positives_used": false_used,
        "true_landmarks_seen": len(seen),
        "landmarks_per_true": round(len(holding) / len(seen), 6) if seen else 0.0,
    }
