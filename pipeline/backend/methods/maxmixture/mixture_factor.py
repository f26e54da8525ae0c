"""A max-mixture as one GTSAM `CustomFactor` that picks its component at every linearisation.

The alternative to `hypotheses.py`'s native factors swapped between updates (the default). Each
component is a native factor; the custom factor evaluates all of them, keeps the one with the
smallest negative log-likelihood `c_k + 0.5 |e_k|^2` (c_k = -log w_k + 0.5 log det(2 pi Sigma_k))
and returns its whitened error and Jacobians, plus one extra row sqrt(2 (c_k - c_min)) so that
0.5 |error|^2 equals the winner's negative log-likelihood up to one constant for the factor:
the optimiser's cost stays consistent when the component switches. The null hypothesis is a
component with no residual and no pull.

It is exact to the letter of Olson & Agarwal's max-mixtures, and costs a Python call per
linearisation; `make bench` measures both.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import gtsam
import numpy as np

from pipeline.backend.mixture import gaussian_log_normaliser


@dataclass(frozen=True)
class Component:
    factor: gtsam.NoiseModelFactor  # native, on (pose, landmark)
    constant: float  # -log w + 0.5 log det(2 pi Sigma)


def component(
    factor: gtsam.NoiseModelFactor, weight: float, log_normaliser: float | None = None
) -> Component:
    """`factor` with association weight `weight`; its Gaussian's normaliser `log_normaliser`
    (0.5 log det(2 pi Gamma) in the measurement's own coordinates, where the null's cost is
    set), by default its noise model's."""
    if log_normaliser is None:
        log_normaliser = gaussian_log_normaliser(factor.noiseModel().covariance())
    return Component(factor, -math.log(weight) + log_normaliser)


class MaxMixtureFactor:
    """Builds the `CustomFactor` of one detection's mixture; `winner` tells the last choice."""

    def __init__(
        self,
        pose_key: int,
        components: list[Component],
        dim: int,
        null_nll: float = math.inf,
    ):
        """`null_nll`: the null component's cost (`decisions.null_cost`), inf for none."""
        self.pose_key = pose_key
        self.components = components
        self.dim = dim
        self.null_constant = null_nll
        self.c_min = min(self.null_constant, *(c.constant for c in components))
        self.keys = [pose_key] + [int(c.factor.keys()[1]) for c in components]
        self.winner = -1

    def nll(self, values: gtsam.Values) -> np.ndarray:
        """Negative log-likelihood of every component, null last (inf if none)."""
        costs = [c.constant + c.factor.error(values) for c in self.components]
        return np.array([*costs, self.null_constant])

    def error(self, _this, values: gtsam.Values, H) -> np.ndarray:
        costs = self.nll(values)
        best = int(np.argmin(costs))
        is_null = best == len(self.components)
        self.winner = -1 if is_null else best
        constant = self.null_constant if is_null else self.components[best].constant
        error = np.zeros(self.dim + 1)
        error[-1] = math.sqrt(max(2.0 * (constant - self.c_min), 0.0))
        if H is not None:
            landmark_dim = 6 if self.dim == 6 else 3  # a pose landmark, or a point
            H[0] = np.zeros((self.dim + 1, 6), order="F")
            for i in range(1, len(self.keys)):
                H[i] = np.zeros((self.dim + 1, landmark_dim), order="F")
        if is_null:
            return error
        winner = self.components[best].factor
        if H is None:
            error[: self.dim] = winner.whitenedError(values)
            return error
        A, b = winner.linearize(values).jacobian()  # whitened, columns [pose | landmark]
        error[: self.dim] = -b
        H[0] = np.asfortranarray(np.vstack([A[:, :6], np.zeros((1, 6))]))
        H[best + 1] = np.asfortranarray(np.vstack([A[:, 6:], np.zeros((1, A.shape[1] - 6))]))
        return error

    def factor(self) -> gtsam.CustomFactor:
        noise = gtsam.noiseModel.Unit.Create(self.dim + 1)
        return gtsam.CustomFactor(noise, self.keys, self.error)
