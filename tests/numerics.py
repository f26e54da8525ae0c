"""Numerical derivatives for checking the hand-written Jacobians."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np


def numerical_jacobian(
    function: Callable[[Any], np.ndarray],
    x0: Any,
    retract: Callable[[Any, np.ndarray], Any] | None = None,
    dim: int | None = None,
    step: float = 1e-6,
) -> np.ndarray:
    """Central differences of `function` at `x0`, a column per tangent direction.

    `retract(x, d)` moves `x` by the tangent vector `d` (e.g. `Pose3.retract`); by default `x0`
    is a vector and `d` is added to it."""
    if retract is None:
        x0 = np.asarray(x0, float)
        retract = np.add
    dim = np.size(x0) if dim is None else dim
    columns = []
    for k in range(dim):
        d = np.zeros(dim)
        d[k] = step
        plus, minus = function(retract(x0, d)), function(retract(x0, -d))
        columns.append((np.asarray(plus) - np.asarray(minus)) / (2 * step))
    return np.stack(columns, axis=-1)
