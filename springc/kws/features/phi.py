"""The SVM feature vector Phi of the paper (Sec. II.B) and the exact SVM <-> CNN rewrite.

Stack the delayed features phi_l(t) = x_i(t - j t_d), l = i m + j (i = 0..n-1 bins,
j = 0..m-1 delays; causal: the mass-spring delay lines delay). The readout of Eq. (conv-model),

    y(T) = int_0^T exp(-(T-t)/tau) sum_k (W^(k) . phi(t))^2 dt = int_0^T w(t) phi^T C phi dt,

depends on phi only through the Gram matrix G_kl = int_0^T w(t) phi_k phi_l dt, and on the
weights only through C = sum_k W^(k) W^(k)T. G is symmetric and unchanged by shifting both
delays (up to the ends of the window), so C is parameterised by one coefficient per *group*
g = (i, i', lag): same bin i = i', lag |j1 - j2| in 0..m-1 (n m groups); bins i < i', lag
j2 - j1 in -(m-1)..m-1 (C(n,2)(2m-1) groups); N = n m + C(n,2)(2m-1) in all. With

    Phi_g = sum over ordered pairs (k, l) in group g of G_kl

(weight 2 for k != l, 1 for k == l), c . Phi = sum_kl C_kl G_kl with C_kl = c_g(k,l) = the
readout exactly. The time integral is a fixed quadrature (trapezoid on the feature grid), so the
identity holds to rounding for any weights. A trained c becomes kernels through the eigen
decomposition C = Q Lambda Q^T: W^(k) = sqrt|lambda_k| Q_k with sign(lambda_k) on its square.
"""

from __future__ import annotations

import functools

import numpy as np

from springc.kws.features.digital import FeatureSettings


def n_features(n: int, m: int) -> int:
    """N = n m + C(n,2)(2m-1), the length of Phi."""
    return n * m + n * (n - 1) // 2 * (2 * m - 1)


@functools.lru_cache(maxsize=64)
def group_index(n: int, m: int) -> np.ndarray:
    """The (k, l) -> g map, an (nm, nm) int array, symmetric. k = i m + j.

    Groups 0..nm-1: same bin i, lag L = |j1 - j2|, g = i m + L. Then for each pair of bins
    i < i' in lexicographic order (pair index p), lag d = j' - j in -(m-1)..m-1 (j the delay
    on bin i, j' on bin i'): g = n m + p (2m-1) + d + m - 1."""
    bins = np.repeat(np.arange(n), m)
    delays = np.tile(np.arange(m), n)
    lo = np.minimum(bins[:, None], bins[None, :])
    hi = np.maximum(bins[:, None], bins[None, :])
    j_lo = np.where(bins[:, None] <= bins[None, :], delays[:, None], delays[None, :])
    j_hi = np.where(bins[:, None] <= bins[None, :], delays[None, :], delays[:, None])
    pair = lo * n - lo * (lo + 1) // 2 + (hi - lo - 1)  # index of (lo, hi) among i < i'
    cross = n * m + pair * (2 * m - 1) + (j_hi - j_lo) + m - 1
    same = lo * m + np.abs(j_hi - j_lo)
    g = np.where(lo == hi, same, cross)
    g.setflags(write=False)
    return g


def spread(c: np.ndarray, n: int, m: int) -> np.ndarray:
    """The symmetric (nm, nm) matrix C with C_kl = c[g(k, l)]; c has shape (N,) or (..., N)."""
    c = np.asarray(c, dtype=np.float64)
    return c[..., group_index(n, m)]


def kernels(c: np.ndarray, n: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    """Convolution kernels realising coefficients c: (W, signs) with W of shape (nm, n, m)
    (W[k] = sqrt|lambda_k| Q_k reshaped to bins x delays) and signs = sign(lambda_k), so that
    phi^T C phi = sum_k signs[k] (W[k] . phi)^2 (Eq. conv-model with signed channels)."""
    lam, q = np.linalg.eigh(spread(c, n, m))
    w = (np.sqrt(np.abs(lam))[:, None] * q.T).reshape(n * m, n, m)
    return w, np.sign(lam)


def delayed(x: np.ndarray, m: int, lag: int) -> np.ndarray:
    """phi(t): x of shape (..., n, K) -> (..., n m, K), phi_(i m + j)(t) = x_i(t - j lag dt),
    zero before t = 0."""
    *lead, n, k = x.shape
    out = np.zeros((*lead, n, m, k), dtype=np.float64)
    for j in range(m):  # m <= a handful of delays: a loop over taps, not samples
        if j * lag < k:
            out[..., j, j * lag:] = x[..., : k - j * lag]
    return out.reshape(*lead, n * m, k)


def readout_weights(k: int, dt: float, tau: float) -> np.ndarray:
    """Quadrature weights on t_0..t_{k-1} = 0..T: trapezoid times exp(-(T - t)/tau)."""
    t = np.arange(k) * dt
    w = np.full(k, dt)
    w[[0, -1]] = dt / 2
    return w * np.exp(-(t[-1] - t) / tau)


def gram(x: np.ndarray, settings: FeatureSettings) -> np.ndarray:
    """G_kl = int_0^T exp(-(T-t)/tau) phi_k phi_l dt for features x (..., n, K+1)."""
    lag = round(settings.td * settings.feature_rate)
    phi = delayed(x, settings.delays, lag)
    q = readout_weights(x.shape[-1], 1.0 / settings.feature_rate, settings.tau)
    return np.einsum("...kt,...lt->...kl", phi * q, phi)


def phi_vector(x: np.ndarray, settings: FeatureSettings) -> np.ndarray:
    """Phi (..., N) from features x (..., n, K+1) sampled at settings.feature_rate."""
    n, m = x.shape[-2], settings.delays
    g = gram(x, settings)
    idx = group_index(n, m).ravel()
    flat = g.reshape(-1, (n * m) ** 2)
    out = np.zeros((flat.shape[0], n_features(n, m)))
    for row, values in zip(out, flat):  # one bincount per clip
        row[:] = np.bincount(idx, weights=values, minlength=out.shape[1])
    return out.reshape(*g.shape[:-2], out.shape[1])


def readout(c: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """The physical readout c . Phi (without bias) for Phi of shape (..., N)."""
    return np.asarray(phi) @ np.asarray(c)
