"""What the seeds of a cell say beyond their mean: a bootstrap interval for it, and a paired
comparison of two methods over the same seeds. Pure functions of numbers, with scipy.stats.

- `estimate`: the mean of a per-run figure and a 95 % percentile bootstrap interval over the
  runs (resampled 9999 times from a fixed seed, so the same results give the same interval).
  Percentile rather than scipy's default BCa: BCa's corrections are estimated from the same
  few seeds, and it is undefined (NaN, with a warning) where all runs agree, as counts of zero
  often do; the percentile interval is always defined, and can be checked by hand.
- `compare`: method A against method B on the runs both have: wins, ties and losses (a tie:
  within 1 cm or 1 % of the larger of the two), a two-sided Wilcoxon signed-rank p-value of
  the differences (zero differences dropped) and a two-sided sign-test p-value of wins against
  losses. A test with nothing to test (no pair, every difference zero, no win and no loss)
  gives None rather than a number that would look like evidence.
"""

from __future__ import annotations

from collections.abc import Hashable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

CONFIDENCE = 0.95
RESAMPLES = 9999
RANDOM_STATE = 0  # fixed: a report made twice from the same results is the same report
TIE_M = 0.01  # a tie: within 1 cm ...
TIE_SHARE = 0.01  # ... or within 1 % of the larger of the two


@dataclass(frozen=True)
class Estimate:
    """The mean of a figure over runs, with its bootstrap interval."""

    mean: float
    low: float | None  # None with a single run: no interval
    high: float | None
    runs: int


@dataclass(frozen=True)
class Comparison:
    """Method A against method B on the runs both have (lower is better)."""

    pairs: int
    wins: int  # A lower than B, beyond a tie
    ties: int
    losses: int
    wilcoxon_p: float | None
    sign_p: float | None


def estimate(values: Sequence[float]) -> Estimate | None:
    """The mean of `values` and its 95 % percentile bootstrap interval; None without values."""
    from scipy.stats import bootstrap

    data = np.asarray(values, dtype=float)
    if data.size == 0:
        return None
    mean = float(np.mean(data))
    if data.size == 1:
        return Estimate(mean, None, None, 1)
    interval = bootstrap(
        (data,),
        np.mean,
        confidence_level=CONFIDENCE,
        n_resamples=RESAMPLES,
        method="percentile",
        random_state=RANDOM_STATE,
    ).confidence_interval
    return Estimate(mean, float(interval.low), float(interval.high), int(data.size))


def is_tie(a: float, b: float) -> bool:
    return abs(a - b) <= max(TIE_M, TIE_SHARE * max(abs(a), abs(b)))


def wilcoxon_p(differences: Sequence[float]) -> float | None:
    """Two-sided Wilcoxon signed-rank p-value of paired differences (zeros dropped, as
    Wilcoxon's own method); None when no difference is non-zero."""
    from scipy.stats import wilcoxon

    nonzero = [d for d in differences if d != 0]
    if not nonzero:
        return None
    return float(wilcoxon(nonzero, zero_method="wilcox", alternative="two-sided").pvalue)


def sign_p(wins: int, losses: int) -> float | None:
    """Two-sided sign-test p-value (ties left out); None when there is neither."""
    from scipy.stats import binomtest

    if wins + losses == 0:
        return None
    return float(binomtest(wins, wins + losses, 0.5, alternative="two-sided").pvalue)


def compare(a: Mapping[Hashable, float], b: Mapping[Hashable, float]) -> Comparison:
    """A against B over the keys (seeds, or cell and seed) both have."""
    keys = [k for k in a if k in b]
    ties = sum(is_tie(a[k], b[k]) for k in keys)
    wins = sum(a[k] < b[k] and not is_tie(a[k], b[k]) for k in keys)
    losses = len(keys) - ties - wins
    return Comparison(
        pairs=len(keys),
        wins=wins,
        ties=ties,
        losses=losses,
        wilcoxon_p=wilcoxon_p([a[k] - b[k] for k in keys]),
        sign_p=sign_p(wins, losses),
    )
