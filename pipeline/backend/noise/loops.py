"""How far a loop's covariance may still be understated: what the loops closed so far say.

The loop tests of `merges.py` must close a first loop before the drift windows have read the
odometry's noise (`drift.py`): where a log understates it, the drift since a loop's old
landmarks were seen is larger than the map's covariance says, and every revisit fails a test
built on it. A loop's pairs are therefore tested under a mixture over how far the drift part
of their covariance is understated, c times the map's (`joint_compatibility.PairSet`), with
these weights.
"""

from __future__ import annotations

from typing import Any

import numpy as np


class DriftScaleBelief:
    """A distribution over a log grid of factors c by which the odometry's drift may exceed
    what the map's covariance holds, the noise scales in use included.

    It starts as a prior: the map right (c = 1) with probability 1 - `weight`, the rest spread
    evenly in log over `steps` factors up to `max_scale`. Each set of pairs merged across a
    loop multiplies it by its likelihood under each factor, so that once loops close where
    the map says, a lookalike street that only a drift of many times the stated one could
    explain is no longer weighed as one; and once they close far from it, the next loop is
    tested there. When the noise scales change the map's covariance, the belief starts
    again (`restart`): it was about the map as it was."""

    def __init__(self, weight: float, max_scale: float, steps: int):
        self._settings = (weight, max_scale, steps)
        self.loops = 0  # loops observed since the last restart
        if weight <= 0.0 or max_scale <= 1.0:
            self.scales, self.log_weights = np.ones(1), np.zeros(1)
        else:
            grid = np.geomspace(max_scale ** (1.0 / steps), max_scale, steps)
            self.scales = np.concatenate([[1.0], grid])
            self.log_weights = np.log(
                np.concatenate([[1.0 - weight], np.full(steps, weight / steps)])
            )

    def restart(self) -> None:
        """Back to the prior: the map's covariance changed."""
        self.__init__(*self._settings)  # type: ignore[misc]

    def observe(self, log_likelihoods: np.ndarray) -> None:
        """A loop closed: its log-likelihood under each of `scales`."""
        posterior = self.log_weights + log_likelihoods
        self.log_weights = posterior - np.logaddexp.reduce(posterior)
        self.loops += 1

    def report(self) -> dict[str, Any]:
        """For metrics.json: the loops observed, the factors and their probabilities now."""
        return {
            "loops": self.loops,
            "scales": [round(float(c), 4) for c in self.scales],
            "probabilities": [round(float(p), 4) for p in np.exp(self.log_weights)],
        }
