"""Trajectory and association metrics against a log's ground truth.

Trajectory errors are evo's absolute pose errors (APE) after aligning the first poses, as in
the paper: translation in metres, rotation as the angle of the relative rotation in radians.
"""

from __future__ import annotations

from collections import Counter

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
