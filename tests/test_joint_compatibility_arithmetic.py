"""The arithmetic the searches of `joint_compatibility.py` stand on, against references written
out plainly here: a set's factor extended pair by pair against the Cholesky factor of its whole
covariance under each drift scale, the cofactor form of 3 x 3 blocks' terms against LAPACK's,
and each pair's bound against its precision block's determinant taken one at a time."""

import numpy as np
import pytest

from pipeline.backend.association import LOG_2PI
from pipeline.backend.joint_compatibility import (
    NEARLY_SINGULAR,
    PairSet,
    _block_terms,
    _block_terms_3,
    _block_terms_lapack,
)


def random_pair_set(seed: int, n: int = 6, drift: bool = True) -> PairSet:
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(3 * n, 3 * n)) * 0.3
    extra = {}
    if drift:
        extra = {
            "drift": rng.normal(size=(3 * n, 4)) * 0.4,
            "scales": np.array([1.0, 3.0, 10.0, 100.0]),
            "log_scale_weights": np.log(np.array([0.4, 0.3, 0.2, 0.1])),
        }
    return PairSet(
        pairs=[(100 + p, p) for p in range(n)],
        differences=rng.normal(size=(n, 3)),
        covariance=A @ A.T + 0.05 * np.eye(3 * n),
        log_prior=rng.uniform(1.0, 5.0, n),
        loop=np.ones(n, bool),
        **extra,
    )


def scaled(ps: PairSet, chosen: list[int], c: float) -> tuple[np.ndarray, np.ndarray]:
    """(d, C_c) of the pairs `chosen`, C_c = C + (c - 1) G G^T formed whole."""
    rows = np.concatenate([np.arange(3 * p, 3 * p + 3) for p in chosen])
    C = ps.covariance[np.ix_(rows, rows)]
    if ps.drift is not None:
        C = C + (c - 1.0) * ps.drift[rows] @ ps.drift[rows].T
    return ps.differences[chosen].ravel(), C


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("drift", [True, False])
def test_a_factor_extended_pair_by_pair_is_the_whole_sets_cholesky_factor(seed, drift):
    ps = random_pair_set(seed, drift=drift)
    order = [int(p) for p in np.random.default_rng(seed).permutation(len(ps.pairs))]
    factor = ps.empty_factor()
    chosen: list[int] = []
    for depth in range(4):
        new = order[depth:]
        children = ps.extensions(factor, new)
        assert children.log_lik.shape == children.d2.shape == (len(new), len(ps.scales))
        for k, p in enumerate(new):
            for s, c in enumerate(ps.scales):
                d, C = scaled(ps, [*chosen, p], c)
                expected_d2 = d @ np.linalg.solve(C, d)
                expected = -0.5 * (expected_d2 + np.linalg.slogdet(C)[1] + len(d) * LOG_2PI)
                assert children.d2[k, s] == pytest.approx(expected_d2, rel=1e-9)
                assert children.log_lik[k, s] == pytest.approx(expected, rel=1e-9)
        # the same numbers as the sets scored from scratch
        from_scratch = ps.scale_log_likelihoods_of([[*chosen, p] for p in new])
        np.testing.assert_allclose(children.log_lik, from_scratch[0], rtol=1e-9)
        np.testing.assert_allclose(children.d2, from_scratch[1], rtol=1e-9)
        factor = children.child(0)
        chosen.append(new[0])
        for s in range(factor.inverse.shape[0]):
            d, C = scaled(ps, chosen, ps.scales[s] if drift else 1.0)
            L = np.linalg.cholesky(C)
            np.testing.assert_allclose(factor.inverse[s], np.linalg.inv(L), rtol=1e-8, atol=1e-8)
            np.testing.assert_allclose(factor.whitened[s], np.linalg.solve(L, d), rtol=1e-8)
            assert factor.log_det[s] == pytest.approx(np.linalg.slogdet(C)[1], rel=1e-9)


def test_a_factor_without_a_drift_serves_every_scale():
    ps = random_pair_set(5, drift=False)
    ps = PairSet(ps.pairs, ps.differences, ps.covariance, ps.log_prior, ps.loop,
                 scales=np.array([1.0, 2.0]), log_scale_weights=np.log([0.5, 0.5]))  # fmt: skip
    children = ps.extensions(ps.empty_factor(), [0, 1])
    assert children.log_lik.shape == (2, 2)
    np.testing.assert_array_equal(children.log_lik[:, 0], children.log_lik[:, 1])


def random_blocks(rng, shape, condition=1.0):
    """Symmetric positive definite 3 x 3 blocks, their eigenvalues spread `condition` apart."""
    Q, _ = np.linalg.qr(rng.normal(size=(*shape, 3, 3)))
    values = np.exp(rng.uniform(0.0, np.log(condition), size=(*shape, 3))) * 0.1
    return (Q * values[..., None, :]) @ np.swapaxes(Q, -1, -2)


@pytest.mark.parametrize("condition", [1.0, 1e3, 1e5])
def test_3_by_3_blocks_by_cofactors_score_as_lapack(condition):
    rng = np.random.default_rng(11)
    blocks = random_blocks(rng, (4, 50), condition)
    mean = rng.normal(size=(4, 50, 3))
    log_lik, d2 = _block_terms_3(mean, blocks)
    solved = np.linalg.solve(blocks, mean[..., None])[..., 0]
    expected_d2 = np.einsum("...i,...i->...", mean, solved)
    expected = -0.5 * (expected_d2 + np.linalg.slogdet(blocks)[1] + 3 * LOG_2PI)
    np.testing.assert_allclose(d2, expected_d2, rtol=1e-9)
    np.testing.assert_allclose(log_lik, expected, rtol=1e-9)


def test_nearly_singular_and_indefinite_3_by_3_blocks_score_as_lapack():
    rng = np.random.default_rng(12)
    B = rng.normal(size=(30, 3, 2))
    blocks = B @ np.swapaxes(B, 1, 2) + 1e-9 * np.eye(3)  # nearly singular: LAPACK's path
    blocks[:5] = np.diag([0.2, -0.1, 0.3])  # indefinite: -inf, inf
    blocks[5:10] = np.diag([-0.2, -0.1, 0.3])  # two negative eigenvalues, a positive determinant
    mean = rng.normal(size=(30, 3))
    got = _block_terms(mean, blocks)
    expected = _block_terms_lapack(mean, blocks)
    for a, b in zip(got, expected, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-12)
    assert np.all(np.isneginf(got[0][:5])) and np.all(np.isposinf(got[1][:5]))
    # how near singular a block must be to go to LAPACK: below its correlations' determinant
    correlation = np.linalg.det(blocks[10:]) / np.prod(np.diagonal(blocks[10:], 0, 1, 2), axis=1)
    assert np.all(correlation < NEARLY_SINGULAR)


def test_blocks_of_another_size_go_to_lapack():
    rng = np.random.default_rng(13)
    A = rng.normal(size=(7, 6, 6))
    blocks = A @ np.swapaxes(A, 1, 2) + np.eye(6)
    mean = rng.normal(size=(7, 6))
    got, expected = _block_terms(mean, blocks), _block_terms_lapack(mean, blocks)
    for a, b in zip(got, expected, strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("seed", range(3))
def test_max_gains_are_each_precision_blocks_bound(seed):
    ps = random_pair_set(seed, n=5, drift=False)
    n = len(ps.covariance)
    jitter = 1e-9 * float(np.trace(ps.covariance)) / n
    precision = np.linalg.inv(ps.covariance + jitter * np.eye(n))
    for p in range(len(ps.pairs)):
        block = precision[3 * p : 3 * p + 3, 3 * p : 3 * p + 3]
        expected = 0.5 * (np.linalg.slogdet(block)[1] - 3 * LOG_2PI) + ps.log_prior[p]
        assert ps.max_gains[p] == pytest.approx(max(expected, 0.0), rel=1e-12, abs=1e-12)
