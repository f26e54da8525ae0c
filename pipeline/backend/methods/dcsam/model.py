"""The discrete-continuous model of `--method dcsam`, as pure functions: what each mode of a
detection's association costs, and what the detections a landmark holds say of its class.

A detection with candidates has a discrete association A whose modes are, in order, its K
candidate landmarks, a landmark of its own (mode K) and the null hypothesis (mode K + 1). A
mode's cost is its negative log prior times likelihood (DC-SAM's `HybridNonlinearFactor`
scalar plus the selected factor's error):

- candidate k: -log((1 - w_null)(1 - w_new) g_k) + 0.5 log det(2 pi Gamma) + error_k, where
  g_k is the gate's weight of k with its class divided out (the class has a discrete variable
  of its own) and error_k the measurement factor's error at the estimate;
- a new landmark: -log((1 - w_null) w_new) + log V, uniform over the volume V that the
  detections span (as mm-nh's joint association weighs "a landmark not mapped yet"), plus its
  own factor's error once other detections hold it too (zero while it is its alone);
- the null: mm-nh's null cost (`decisions.null_cost`).

Classes: a landmark's class C is a discrete variable; a detection reporting class r that
takes landmark j contributes P(r | C_j) (the detector's confusion), a new landmark's report
max_c P(r | c) (its class is its own), the null's the report averaged over classes.
"""

from __future__ import annotations

import math

import numpy as np

from pipeline.backend.decisions import MeasurementSpace
from pipeline.backend.landmarks import LandmarkKind

# The volume of SO(3) in exponential coordinates (the Haar measure's, 8 pi^2): a pose
# landmark's orientation, for a new one, could be any.
LOG_ROTATION_VOLUME = math.log(8.0 * math.pi**2)


def geometric_weights(weights: np.ndarray, semantic: np.ndarray) -> np.ndarray:
    """The gate's weights (semantic x geometric, normalised) with the semantic part divided
    out, normalised again."""
    geometric = np.asarray(weights, dtype=float) / np.asarray(semantic, dtype=float)
    return geometric / geometric.sum()


def mode_constants(
    geometric: np.ndarray,
    null_weight: float,
    new_weight: float,
    log_normaliser: float,
    new_log_volume: float,
    null_nll: float,
) -> np.ndarray:
    """The K + 2 modes' costs before any factor's error: K candidates (weights `geometric`),
    a new landmark, the null."""
    share = 1.0 - null_weight
    with np.errstate(divide="ignore"):
        candidates = -np.log(share * (1.0 - new_weight) * np.asarray(geometric, dtype=float))
    new = -math.log(share * new_weight) + new_log_volume
    return np.concatenate([candidates + log_normaliser, [new, null_nll]])


def new_landmark_log_volume(kind: LandmarkKind, space: MeasurementSpace) -> float:
    """log of the volume a new landmark is uniform over, in its measurement's units: the box
    the detections span (bearing, elevation, range), or for a 6-DoF landmark the space that
    box sweeps (m^3) times every orientation."""
    if kind is LandmarkKind.POSE:
        return LOG_ROTATION_VOLUME + space.log_world_volume()
    return space.log_volume()


def class_log_evidence(report_counts: np.ndarray, confusion: np.ndarray) -> np.ndarray:
    """log P(reports | class c) for each c: the detections a landmark holds, as counts of each
    reported class, under the confusion matrix (row: true class, column: reported)."""
    counts = np.asarray(report_counts, dtype=float)
    reported = counts > 0
    with np.errstate(divide="ignore"):
        logs = np.log(np.asarray(confusion, dtype=float)[:, reported])
    return logs @ counts[reported]


def class_posterior(log_evidence: np.ndarray) -> np.ndarray:
    """The class posterior from a uniform prior and `log_evidence` (uniform where nothing is
    possible: every class ruled out)."""
    log_evidence = np.asarray(log_evidence, dtype=float)
    top = np.max(log_evidence)
    if not np.isfinite(top):
        return np.full(log_evidence.shape, 1.0 / log_evidence.size)
    weights = np.exp(log_evidence - top)
    return weights / weights.sum()


def mode_probabilities(costs: np.ndarray) -> np.ndarray:
    """exp(-cost) normalised over the modes."""
    costs = np.asarray(costs, dtype=float)
    weights = np.exp(-(costs - np.min(costs)))
    return weights / weights.sum()
