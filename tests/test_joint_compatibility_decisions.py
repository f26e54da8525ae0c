"""`pairs_to_merge`'s sureness rule on a case worked out by hand: two local pairs whose
differences agree along a strong correlation, each alone less likely than a landmark of its
own, together more likely, but by less than `local_log_odds`: nothing merged; with a larger
prior, by more: both merged."""

import numpy as np
import pytest

from pipeline.backend.association import gaussian_log_density
from pipeline.backend.joint_compatibility import PairSet, best_pairs, pairs_to_merge

SIGMA, RHO = 0.1, 0.99
LOCAL_LOG_ODDS = 2.0


def correlated_pairs(prior: float) -> PairSet:
    C = np.zeros((6, 6))
    C[:3, :3] = C[3:, 3:] = np.eye(3) * SIGMA**2
    C[:3, 3:] = C[3:, :3] = np.eye(3) * SIGMA**2 * RHO
    return PairSet(
        pairs=[(100, 0), (101, 1)],
        differences=np.array([[0.1, 0.0, 0.0], [0.1, 0.0, 0.0]]),
        covariance=C,
        log_prior=np.full(2, prior),
        loop=np.zeros(2, bool),
    )


@pytest.mark.parametrize(("prior", "merged"), [(-6.4, False), (-6.0, False), (-5.6, True)])
def test_local_pairs_together_must_reach_local_log_odds(prior, merged):
    ps = correlated_pairs(prior)
    d = ps.differences.ravel()
    together = gaussian_log_density(d, ps.covariance) + 2 * prior
    alone = gaussian_log_density(d[:3], ps.covariance[:3, :3]) + prior
    assert ps.score([0, 1]) == pytest.approx(together, rel=1e-9)
    assert alone < 0.0 < together  # each alone unlikely, together the best set
    assert together - alone >= LOCAL_LOG_ODDS  # each pulls its weight given the other
    assert sorted(best_pairs(ps, 0.999, 1000)[0]) == [0, 1]
    assert (together >= LOCAL_LOG_ODDS) == merged
    result = pairs_to_merge(ps, 0.999, 8.0, LOCAL_LOG_ODDS, 3.0, 1000)
    assert result == ([(100, 0), (101, 1)] if merged else [])


def test_loop_pairs_left_after_rivals_must_still_reach_loop_log_odds_together():
    """Two independent loop pairs scoring 5.15 each: together 10.3, past loop_log_odds (8),
    alone not. A rival of the first (its source with another target, 5.13) comes within the
    ambiguity and takes it out; the second, left alone, adds 5.15 < 8: nothing merges."""
    ps = PairSet(
        pairs=[(100, 0), (101, 1), (100, 2)],
        differences=np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.02, 0.0, 0.0]]),
        covariance=np.eye(9) * 0.1**2,
        log_prior=np.full(3, 1.0),
        loop=np.ones(3, bool),
    )
    alone = gaussian_log_density(np.zeros(3), np.eye(3) * 0.1**2) + 1.0
    assert ps.score([1]) == pytest.approx(alone, rel=1e-9)
    assert ps.score([0, 1]) >= 8.0 > ps.score([1])
    assert ps.score([2, 1]) > ps.score([0, 1]) - 3.0  # the rival is within the ambiguity
    assert pairs_to_merge(ps, 0.95, 8.0, LOCAL_LOG_ODDS, 3.0, 1000) == []
    # without the rival, both close the loop
    sure = PairSet(
        ps.pairs[:2], ps.differences[:2], np.eye(6) * 0.1**2, ps.log_prior[:2], ps.loop[:2]
    )
    assert sorted(pairs_to_merge(sure, 0.95, 8.0, LOCAL_LOG_ODDS, 3.0, 1000)) == ps.pairs[:2]
