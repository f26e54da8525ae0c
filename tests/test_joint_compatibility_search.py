"""The searches of `joint_compatibility.py` against references written out plainly here, on
random pair sets (several seeds, with and without a drift mixture): branch and bound against
every assignment enumerated, a set grown pair by pair against a greedy loop over
`PairSet.score`, the seeds' estimates against their definition, and the weakest pairs dropped
one at a time."""

import itertools

import numpy as np
import pytest

from pipeline.backend.association import chi2_gate, gaussian_log_density
from pipeline.backend.joint_compatibility import (
    PairSet,
    SeededSearch,
    _pulling_their_weight,
    best_pairs,
    grown_pairs,
    seed_estimates,
)

CONFIDENCE = 0.95
SEEDS = range(6)


def random_pair_set(seed: int, sources: int = 4, targets: int = 4) -> PairSet:
    """Sources 100.. each paired with one to three of the targets 0.. (targets shared between
    sources), the differences of some small, of others a metre or so; a random joint
    covariance; every other seed a drift mixture."""
    rng = np.random.default_rng(seed)
    pairs = []
    for s in range(sources):
        for t in rng.choice(targets, size=int(rng.integers(1, 4)), replace=False):
            pairs.append((100 + s, int(t)))
    n = len(pairs)
    A = rng.normal(size=(3 * n, 3 * n)) * 0.15
    covariance = A @ A.T + 0.05 * np.eye(3 * n)
    small = rng.random(n) < 0.6
    differences = rng.normal(size=(n, 3)) * np.where(small, 0.2, 1.0)[:, None]
    extra = {}
    if seed % 2:
        extra = {
            "drift": rng.normal(size=(3 * n, 2)) * 0.3,
            "scales": np.array([1.0, 4.0, 16.0]),
            "log_scale_weights": np.log(np.array([0.6, 0.3, 0.1])),
        }
    return PairSet(
        pairs=pairs,
        differences=differences,
        covariance=covariance,
        log_prior=rng.uniform(1.0, 5.0, n),
        loop=rng.random(n) < 0.5,
        **extra,
    )


def admissible(ps: PairSet, chosen: list[int]) -> bool:
    """Each landmark in one pair at most, and every prefix (in the order given) inside the
    joint gate of its size under some drift scale."""
    landmarks = [j for p in chosen for j in ps.pairs[p]]
    if len(landmarks) != len(set(landmarks)):
        return False
    for k in range(1, len(chosen) + 1):
        _, d2 = ps.log_likelihood(chosen[:k])
        if d2 > chi2_gate(k * ps.dim, CONFIDENCE):
            return False
    return True


def enumerated_best(ps: PairSet, required: int | None = None) -> float:
    """The best score over every assignment of one pair or none to each source (sources in
    increasing order, the required pair's first), better than nothing (0) without one."""
    sources = sorted({a for a, _ in ps.pairs})
    if required is not None:
        sources.remove(ps.pairs[required][0])
    options = [[None] + [p for p, (a, _) in enumerate(ps.pairs) if a == s] for s in sources]
    best = -np.inf if required is not None else 0.0
    for choice in itertools.product(*options):
        chosen = ([] if required is None else [required]) + [p for p in choice if p is not None]
        if admissible(ps, chosen):
            best = max(best, ps.score(chosen))
    return best


@pytest.mark.parametrize("seed", SEEDS)
def test_branch_and_bound_finds_the_best_of_every_assignment(seed):
    ps = random_pair_set(seed)
    chosen, score, finished = best_pairs(ps, CONFIDENCE, 100_000)
    assert finished
    expected = enumerated_best(ps)
    assert expected > 0.0  # something to find
    assert score == pytest.approx(expected, rel=1e-9, abs=1e-9)
    assert admissible(ps, sorted(chosen, key=lambda p: ps.pairs[p][0]))
    assert ps.score(list(chosen)) == pytest.approx(score, rel=1e-9)


@pytest.mark.parametrize("seed", SEEDS)
def test_a_rival_search_keeps_its_required_pair(seed):
    ps = random_pair_set(seed)
    tried = 0
    for required in range(len(ps.pairs)):
        if not admissible(ps, [required]):
            continue
        chosen, score, finished = best_pairs(ps, CONFIDENCE, 100_000, required=required)
        assert finished and required in chosen
        assert [p for p in chosen if ps.pairs[p][0] == ps.pairs[required][0]] == [required]
        assert score == pytest.approx(enumerated_best(ps, required), rel=1e-9, abs=1e-9)
        tried += 1
    assert tried >= 2


def greedy(ps: PairSet, start: tuple[int, ...] = ()) -> tuple[list[int], float]:
    """Add the pair that raises the score most, among those sharing no landmark with the set
    and keeping it inside the joint gate, while one raises it."""
    chosen = list(start)
    score = ps.score(chosen) if chosen else 0.0
    while True:
        taken = {j for p in chosen for j in ps.pairs[p]}
        best, best_score = None, score
        for p in range(len(ps.pairs)):
            if p in chosen or set(ps.pairs[p]) & taken:
                continue
            _, d2 = ps.log_likelihood([*chosen, p])
            if d2 > chi2_gate((len(chosen) + 1) * ps.dim, CONFIDENCE):
                continue
            trial = ps.score([*chosen, p])
            if trial > best_score:
                best, best_score = p, trial
        if best is None:
            return chosen, score
        chosen.append(best)
        score = best_score


@pytest.mark.parametrize("seed", SEEDS)
def test_a_grown_set_is_the_greedy_one(seed):
    ps = random_pair_set(seed)
    for start in [(), *((p,) for p in range(len(ps.pairs)) if admissible(ps, [p]))]:
        chosen, score, _ = grown_pairs(ps, CONFIDENCE, start)
        expected, expected_score = greedy(ps, start)
        assert list(chosen) == expected
        assert score == pytest.approx(expected_score, rel=1e-9, abs=1e-9)


def estimates_by_definition(ps: PairSet) -> np.ndarray:
    """Per pair q, under each scale: its own log density and prior, plus for every other
    source the most (at least 0) that one of its pairs adds given q alone, inside the gate,
    prior included; mixed over the scales. -inf where q is outside the gate under every
    scale."""
    n, d = len(ps.pairs), ps.dim
    gate = chi2_gate(d, CONFIDENCE)
    covariances = ps.scaled_covariances(np.arange(n * d))
    sources = [a for a, _ in ps.pairs]
    out = np.full(n, -np.inf)
    for q in range(n):
        totals = []
        inside = False
        for C in covariances:

            def block(a, b, C=C):
                return C[a * d : (a + 1) * d, b * d : (b + 1) * d]

            D_q, C_qq = ps.differences[q], block(q, q)
            inside |= D_q @ np.linalg.solve(C_qq, D_q) <= gate
            total = gaussian_log_density(D_q, C_qq) + ps.log_prior[q]
            for s in sorted(set(sources) - {sources[q]}):
                best = 0.0
                for r in (r for r in range(n) if sources[r] == s):
                    K = block(r, q) @ np.linalg.inv(C_qq)
                    mean = ps.differences[r] - K @ D_q
                    cov = block(r, r) - K @ block(q, r)
                    if mean @ np.linalg.solve(cov, mean) <= gate:
                        best = max(best, gaussian_log_density(mean, cov) + ps.log_prior[r])
                total += best
            totals.append(total)
        if inside:
            out[q] = np.logaddexp.reduce(ps.log_scale_weights + np.array(totals))
    return out


@pytest.mark.parametrize("seed", SEEDS)
def test_a_seed_s_estimate_is_as_defined(seed):
    ps = random_pair_set(seed)
    expected = estimates_by_definition(ps)
    assert np.isfinite(expected).sum() >= 2
    np.testing.assert_allclose(seed_estimates(ps, CONFIDENCE), expected, rtol=1e-9, atol=1e-9)


def test_a_seeded_rival_scores_at_least_its_pair_s_estimate():
    raised = 0
    for seed in SEEDS:
        ps = random_pair_set(seed)
        search = SeededSearch(ps, CONFIDENCE, seeds=3)
        for q in range(len(ps.pairs)):
            _, score, finished = search(ps, CONFIDENCE, 10, frozenset(), required=q)
            _, grown, _ = grown_pairs(ps, CONFIDENCE, (q,))
            assert finished
            assert score == pytest.approx(max(grown, search.estimates[q]), rel=1e-9)
            raised += search.estimates[q] > grown + 1e-6
    assert raised >= 1  # some estimate lies above what growth found


def weakest_dropped(ps: PairSet, chosen: list[int], minimum: float) -> list[int]:
    chosen = list(chosen)
    while chosen:
        adds = {p: ps.score(chosen) - ps.score([q for q in chosen if q != p]) for p in chosen}
        weakest = min(adds, key=adds.get)
        if adds[weakest] >= minimum:
            return chosen
        chosen.remove(weakest)
    return chosen


@pytest.mark.parametrize("seed", SEEDS)
def test_the_pair_that_adds_least_goes_first(seed):
    ps = random_pair_set(seed)
    chosen = list(best_pairs(ps, CONFIDENCE, 100_000)[0])
    adds = sorted(ps.score(chosen) - ps.score([q for q in chosen if q != p]) for p in chosen)
    for minimum in [adds[0] + 1e-6, *(a + 1e-6 for a in adds[1:2])]:
        kept = _pulling_their_weight(ps, chosen, minimum)
        assert kept == weakest_dropped(ps, chosen, minimum)
        assert len(kept) < len(chosen)


@pytest.mark.parametrize("spread", [7.0, 7.5])
def test_a_grown_set_stays_inside_the_joint_gate_of_its_size(spread):
    """Three independent pairs, each alone inside the gate (d^2 = spread < 7.81) and worth
    adding (prior 8): two together are outside it (2 spread > 12.59), so growth stops at
    one, as the greedy loop does."""
    sigma = 0.1
    ps = PairSet(
        pairs=[(100, 0), (101, 1), (102, 2)],
        differences=np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
        * sigma
        * np.sqrt(spread),
        covariance=np.eye(9) * sigma**2,
        log_prior=np.full(3, 8.0),
        loop=np.zeros(3, bool),
    )
    chosen, score, _ = grown_pairs(ps, CONFIDENCE)
    assert len(chosen) == 1
    assert (list(chosen), score) == (greedy(ps)[0], pytest.approx(greedy(ps)[1]))
    assert ps.score([0, 1]) > ps.score([0])  # the second pair would raise the score
