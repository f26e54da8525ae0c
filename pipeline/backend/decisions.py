"""Where a detection goes when it arrives: the max-mixture at its first linearisation.

A detection's max-mixture factor max_k w_k N(h(x, l_k) - z; 0, Gamma), null hypothesis
included, is first linearised at the predicted pose. So that is where its component is first
chosen: each candidate's cost is -log w_k + 0.5 log det(2 pi Gamma) + 0.5 |h - z|^2_Gamma, with
h evaluated at the prediction. A candidate that fits the prediction badly (a loop closure the
odometry does not support) loses to the null and pulls on nothing; the detection then starts
a landmark of its own, which a later merge can join to the old one once enough evidence agrees
(`merging.py`).

The null hypothesis's cost: the paper's is a Gaussian of standard deviation `null_sigma` in
whatever units the measurement has ("literal"); its crossover moves with the measurement's
covariance. mmslam's default ("relative") puts the crossover at a fixed squared Mahalanobis
distance in the measurement's own metric: the null costs what a component of full weight costs
at `null_crossover_sq`.
"""

from __future__ import annotations

import math

import numpy as np

from pipeline.backend.mixture import component_nll, null_component_nll
from pipeline.geometry import bearing_elevation_range

NULL = -1


def relative_null_nll(null_weight: float, log_normaliser: float, crossover_sq: float) -> float:
    """The null's cost: that of a component of weight 1 - null_weight (all the candidates'
    weight on one) at squared distance `crossover_sq` in the measurement's metric."""
    return float(component_nll(math.log(1.0 - null_weight), crossover_sq, log_normaliser))


def null_cost(
    model: str,
    null_weight: float,
    null_sigma: float,
    crossover_sq: float,
    dim: int,
    log_normaliser: float,
) -> float:
    """Negative log-likelihood of the null component under `model` ("literal" or "relative")."""
    if model == "literal":
        return null_component_nll(null_weight, null_sigma, dim)
    return relative_null_nll(null_weight, log_normaliser, crossover_sq)


class MeasurementSpace:
    """Where detections fall: the box their measurement vectors span, learnt as they come.

    A detection that is no landmark mapped yet (a new landmark, or clutter) could be anywhere
    the sensor sees: its density is uniform over that box. Each side is at least sqrt(12)
    times the smallest sigma seen on it (a uniform spread with the same variance), so that a
    component every detection shares (the elevation of a planar sensor) weighs alike under
    both hypotheses."""

    def __init__(self) -> None:
        self.low: np.ndarray | None = None
        self.high: np.ndarray | None = None
        self.floor: np.ndarray | None = None

    def observe(self, vector: np.ndarray, covariance: np.ndarray) -> None:
        vector = np.asarray(vector, dtype=float)
        floor = math.sqrt(12.0) * np.sqrt(np.diag(covariance))
        if self.low is None or self.high is None or self.floor is None:
            self.low, self.high, self.floor = vector.copy(), vector.copy(), floor
            return
        np.minimum(self.low, vector, out=self.low)
        np.maximum(self.high, vector, out=self.high)
        np.minimum(self.floor, floor, out=self.floor)

    def box(self) -> tuple[np.ndarray, np.ndarray]:
        """(low, high) corners, each side at least its floor."""
        if self.low is None or self.high is None or self.floor is None:
            raise ValueError("no detection observed yet")
        middle = (self.low + self.high) / 2
        half = np.maximum(self.high - self.low, self.floor) / 2
        return middle - half, middle + half

    def contains(self, vectors: np.ndarray) -> np.ndarray:
        """Which of the measurement vectors (N, 3) fall inside the box."""
        low, high = self.box()
        vectors = np.asarray(vectors, dtype=float).reshape(-1, len(low))
        return np.all((vectors >= low) & (vectors <= high), axis=1)

    def log_volume(self) -> float:
        """log of the box's volume in measurement units."""
        low, high = self.box()
        return float(np.sum(np.log(high - low)))

    def log_world_volume(self) -> float:
        """log of the volume (m^3) the box of (bearing, elevation, range) sweeps in space:
        the integral of r^2 cos(elevation) over it."""
        (b0, e0, r0), (b1, e1, r1) = self.box()
        r0 = max(r0, 0.0)
        e0, e1 = max(e0, -math.pi / 2), min(e1, math.pi / 2)
        volume = (r1**3 - r0**3) / 3.0 * min(b1 - b0, 2 * math.pi) * (math.sin(e1) - math.sin(e0))
        return math.log(max(volume, 1e-12))


def clutter_log_density(null_weight: float, report_likelihood: float, log_volume: float) -> float:
    """log of the null's density in the joint association: not a mapped landmark (prior
    `null_weight`), uniform over the measurement space, reporting its class with the
    detector's average likelihood."""
    return math.log(null_weight) + math.log(report_likelihood) - log_volume


def first_component(
    weights: np.ndarray, fit_sq: np.ndarray, log_normaliser: float, null_nll: float
) -> int:
    """Index of the component a max-mixture uses at the prediction, or NULL.

    `weights` are the components' weights (null excluded), `fit_sq` their squared distances
    in the measurement's metric at the predicted pose; `null_nll` = inf without a null."""
    costs = component_nll(np.log(np.asarray(weights, dtype=float)), fit_sq, log_normaliser)
    best = int(np.argmin(costs))
    return NULL if null_nll < costs[best] else best


def in_view(rotation: np.ndarray, translation: np.ndarray, points: np.ndarray, space) -> int:
    """How many of the world `points` (N, 3) a sensor at pose (rotation, translation) would
    measure inside the measurement space's box."""
    if len(points) == 0:
        return 0
    body = (np.asarray(points, dtype=float) - translation) @ rotation
    return int(np.count_nonzero(space.contains(bearing_elevation_range(body))))


def loop_pairs_needed(marginal_weights: list[float], alone: int, crowded: int) -> int:
    """How many pairings with landmarks not seen lately a keyframe needs to close a loop, given
    each pairing's weight on its own (among its detection's candidates weighed alone): `alone`
    where each holds at least half, `crowded` where the keyframe's pattern took one that its
    detection's other candidates outweigh. Among lookalikes in rows (parked cars), a pattern
    shifted by one slot explains two detections together better than the truth does when the
    truth holds a landmark not mapped yet (city-grid, true covariance, seed 4: cars 103 and 102
    paired with the mapped 96 and 95, the second at weight 0.10 alone against 0.79 for car
    102's own landmark)."""
    return crowded if any(w < 0.5 for w in marginal_weights) else alone
