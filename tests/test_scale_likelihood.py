"""The scale likelihood's bookkeeping and evidence (`noise/components.py`) on one direction,
worked out by hand: which observations it keeps, the evidence for a move (profile likelihood
ratio less the `drop` best gains, less the prior's part), and the deadband inside which no
evidence is asked."""

import numpy as np
import pytest

from pipeline.backend.noise.components import (
    OUTLIER_SCALE,
    OUTLIER_SHARE,
    PRIOR_LOG_SIGMA,
    ScaleLikelihood,
    ScaleObservation,
)

BOUNDS = (0.01, 1e4)
REST = 1e-3  # what does not depend on the scale; the basis is 1


def observation(y: float, used: float) -> ScaleObservation:
    """y ~ N(0, REST + s), taken with the scale `used` in force."""
    return ScaleObservation.made(
        np.array([y]), REST * np.eye(1), np.ones((1, 1, 1)), np.array([[0, 0]]), np.array([used])
    )


def log_density(y: np.ndarray, s: float, used: float) -> np.ndarray:
    """Each observation's mixture log density at scale s, by hand."""

    def normal(variance):
        return np.exp(-0.5 * y**2 / variance) / np.sqrt(2.0 * np.pi * variance)

    model = normal(REST + s)
    outlier = normal(REST + OUTLIER_SCALE * used)
    return np.log((1.0 - OUTLIER_SHARE) * model + OUTLIER_SHARE * outlier)


def likelihood(ys, used: float, kept: int = 10_000) -> ScaleLikelihood:
    out = ScaleLikelihood(("only",), kept)
    for y in ys:
        out.add(observation(float(y), used))
    return out


def test_only_the_latest_kept_observations_count():
    ys = np.array([0.3, -2.0, 1.1, 0.7, -0.2])
    kept = likelihood(ys, used=1.0, kept=3)
    assert len(kept) == 3
    for s in (0.5, 1.0, 4.0):
        np.testing.assert_allclose(
            kept.per_observation(np.log([s])), log_density(ys[-3:], s, 1.0), rtol=1e-9
        )


@pytest.mark.parametrize(("seed", "now", "true", "drop"), [(0, 2.0, 16.0, 2), (1, 1.0, 0.1, 0)])
def test_the_evidence_is_the_profile_ratio_less_the_best_gains_and_the_prior(seed, now, true, drop):
    rng = np.random.default_rng(seed)
    ys = rng.normal(0.0, np.sqrt(REST + true), 40)
    reading = likelihood(ys, used=now).reading(np.array([now]), BOUNDS, 3.0, 1.5, drop)
    best = float(reading.fit[0])
    assert best == pytest.approx(true, rel=0.6)  # the fit is the scan's; the evidence is exact
    # one direction: held at `now`, nothing else to fit
    gains = np.sort(log_density(ys, best, now) - log_density(ys, now, now))[::-1]
    prior = 0.5 * (np.log(best) ** 2 - np.log(now) ** 2) / PRIOR_LOG_SIGMA**2
    expected = float(np.sum(gains[drop:]) - prior)
    assert reading.evidence[0] == pytest.approx(expected, rel=1e-6, abs=1e-6)
    assert reading.scales is not None
    assert reading.scales[0] == pytest.approx(best, rel=1e-9)


@pytest.mark.parametrize("seed", [0, 1])
def test_a_fit_inside_the_deadband_asks_no_evidence_and_moves_nothing(seed):
    """2,000 observations of a scale 4: read at 1 they move it; read again at 3 (the last fit,
    4, is tens of nats more probable, so the fit is made) the fit lies within the deadband of
    1.5, and nothing is asked or moved."""
    rng = np.random.default_rng(seed)
    ys = rng.normal(0.0, np.sqrt(REST + 4.0), 2000)
    scales = likelihood(ys, used=1.0)
    first = scales.reading(np.ones(1), BOUNDS, 3.0, 1.5, drop=2)
    assert first.scales is not None and first.scales[0] == pytest.approx(4.0, rel=0.15)
    reading = scales.reading(np.array([3.0]), BOUNDS, 3.0, 1.5, drop=2)
    assert 3.0 < reading.fit[0] < 4.5
    sure = log_density(ys, float(reading.fit[0]), 1.0).sum() - log_density(ys, 3.0, 1.0).sum()
    assert sure > 10.0
    assert reading.scales is None
    assert reading.evidence[0] == pytest.approx(0.0, abs=1e-12)  # 0: not far enough to ask
