"""The SVM feature vector Phi: group structure and the exact rewrite of Eq. (conv-model)."""

from __future__ import annotations

from math import comb

import numpy as np
import pytest

from springc.kws.features.digital import FeatureSettings
from springc.kws.features.phi import (delayed, gram, group_index, kernels, n_features, phi_vector,
                                      readout, readout_weights, spread)

SIZES = [(2, 1), (4, 2), (6, 3), (8, 3), (5, 4)]


@pytest.mark.parametrize("n,m", SIZES)
def test_group_index_has_the_papers_feature_count(n, m):
    g = group_index(n, m)
    assert n_features(n, m) == n * m + comb(n, 2) * (2 * m - 1)
    assert np.array_equal(g, g.T)
    assert np.array_equal(np.unique(g), np.arange(n_features(n, m)))


def test_group_index_groups_by_bins_and_lag():
    n, m = 3, 3
    g = group_index(n, m)
    k = lambda i, j: i * m + j  # noqa: E731 - index of x_i(t - j td) in phi
    assert g[k(1, 0), k(1, 2)] == g[k(1, 2), k(1, 0)] == 1 * m + 2  # same bin, lag 2
    assert g[k(0, 0), k(2, 1)] == g[k(0, 1), k(2, 2)]  # bins 0<2, lag +1 in both
    assert g[k(0, 1), k(2, 0)] != g[k(0, 0), k(2, 1)]  # lag -1 differs from +1


def _random_features(rng, n, k):
    return np.abs(rng.normal(size=(n, k))) ** 0.7 + 0.1  # positive, like |y|^(2/3)


@pytest.mark.parametrize("n,m", SIZES)
def test_phi_equals_brute_force_conv_model_readout(n, m):
    """c . Phi equals int exp(-(T-t)/tau) sum_k lambda_k (Q_k . phi(t))^2 dt for random c:
    the SVM rewrite of the paper's Eq. (conv-model) is exact."""
    rng = np.random.default_rng(n * 10 + m)
    s = FeatureSettings(bins=n, delays=m, td=0.004, tau=0.05, feature_rate=1000.0)
    x = _random_features(rng, n, 60)
    c = rng.normal(size=n_features(n, m))
    lam, q = np.linalg.eigh(spread(c, n, m))
    lag, dt = 4, 1e-3
    total = 0.0
    for t in range(x.shape[1]):  # brute force, one time step and one channel at a time
        phi_t = np.array([x[i, t - j * lag] if t >= j * lag else 0.0
                          for i in range(n) for j in range(m)])
        y_t = sum(lam[k] * (q[:, k] @ phi_t) ** 2 for k in range(n * m))
        trap = 0.5 if t in (0, x.shape[1] - 1) else 1.0
        total += trap * dt * np.exp(-(x.shape[1] - 1 - t) * dt / s.tau) * y_t
    assert readout(c, phi_vector(x, s)) == pytest.approx(total, rel=1e-10)


def test_phi_groups_match_their_definition():
    """Phi for a same-bin lag and a cross-bin lag, integrated directly from the definition."""
    rng = np.random.default_rng(3)
    n, m = 3, 3
    s = FeatureSettings(bins=n, delays=m, td=0.005, tau=0.2, feature_rate=1000.0)
    x = _random_features(rng, n, 40)
    w = readout_weights(40, 1e-3, s.tau)
    shift = lambda v, j: np.concatenate([np.zeros(5 * j), v[: 40 - 5 * j]])  # noqa: E731
    phi = phi_vector(x, s)
    g = group_index(n, m)
    same = 2 * sum(w @ (shift(x[1], j) * shift(x[1], j + 1)) for j in range(m - 1))
    assert phi[g[1 * m + 0, 1 * m + 1]] == pytest.approx(same, rel=1e-12)
    cross = 2 * sum(w @ (shift(x[0], j) * shift(x[2], j - 2)) for j in range(2, m))
    assert phi[g[0 * m + 2, 2 * m + 0]] == pytest.approx(cross, rel=1e-12)


def test_readout_weights_integrate_the_exponential_kernel():
    dt, tau, k = 1e-3, 0.08, 1001
    w = readout_weights(k, dt, tau)
    exact = tau * (1 - np.exp(-(k - 1) * dt / tau))
    trapezoid_error = dt**2 / (12 * tau**2)  # 1.3e-5 relative
    assert w.sum() == pytest.approx(exact, rel=2 * trapezoid_error)


def test_kernels_realise_the_coefficient_matrix():
    rng = np.random.default_rng(1)
    n, m = 4, 3
    c = rng.normal(size=n_features(n, m))
    w, signs = kernels(c, n, m)
    flat = w.reshape(n * m, n * m)
    assert np.allclose((flat.T * signs) @ flat, spread(c, n, m), atol=1e-12)


def test_delays_are_causal():
    x = np.arange(1.0, 7.0)[None, :]
    phi = delayed(x, 3, 2)
    assert np.array_equal(phi[1], [0, 0, 1, 2, 3, 4])
    assert np.array_equal(phi[2], [0, 0, 0, 0, 1, 2])


def test_gram_is_batched_like_single_clips():
    rng = np.random.default_rng(2)
    s = FeatureSettings(bins=3, delays=2, td=0.003, feature_rate=1000.0)
    x = _random_features(rng, 3, 30)
    batch = np.stack([x, 2 * x])
    assert np.allclose(gram(batch, s)[1], 4 * gram(x, s), rtol=1e-13)
    assert np.allclose(phi_vector(batch, s)[0], phi_vector(x, s), rtol=1e-13)
