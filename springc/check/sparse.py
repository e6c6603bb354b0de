"""Spectral facts about large sparse symmetric matrices in near-linear time, for the checks'
large components (`linear.DENSE_MAX`, `checks.PSD_DENSE_MAX`).

- The largest eigenvalue as a value that is not an underestimate: the Gershgorin bound,
  replaced by a Lanczos Ritz value plus its residual where that is lower. Ritz values are
  Rayleigh quotients, so `TopBound.ritz <= lambda_max <= TopBound.bound` up to round-off
  (the upper one holds when the Krylov space has found the top of the spectrum, which a start
  vector with a part along every mode makes certain in exact arithmetic), and
  `TopBound.margin` is the certified relative overestimate.
- Inertia (how many eigenvalues lie below a shift) from one sparse LDL^T factorisation:
  SuperLU with a symmetric fill-reducing ordering and pivots on the diagonal only, so that
  L U = L D L^T and the signs of D are the inertia (Sylvester's law).
- Null spaces and lowest modes by inverse subspace iteration on that factorisation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.sparse as sp
import scipy.sparse.linalg as sla
from scipy.sparse.csgraph import breadth_first_order

LANCZOS_STEPS = 60  # Lanczos steps for the top of a spectrum, at least ...
LANCZOS_WORK = 4_000_000  # ... and more while steps times size stays below this
LANCZOS_TOL = 1e-8  # stop earlier once the certified margin is below this
SUBSPACE_ITERATIONS = 60  # most inverse subspace iterations
SUBSPACE_TOL = 1e-11  # ... stopped once the Ritz values move less than this, relatively


def gershgorin(a: sp.spmatrix) -> tuple[np.ndarray, np.ndarray]:
    """Per row, the low and high ends of the Gershgorin interval of a symmetric matrix."""
    a = sp.csr_matrix(a)
    diag = a.diagonal()
    radius = np.asarray(abs(a).sum(axis=1)).ravel() - np.abs(diag)
    return diag - radius, diag + radius


@dataclass
class TopBound:
    """The top of a symmetric matrix's spectrum: `ritz <= lambda_max <= bound`, and the
    top Ritz vectors (columns, the highest first) as candidates for the fastest modes."""

    bound: float
    ritz: float
    vectors: np.ndarray

    @property
    def margin(self) -> float:
        """Certified relative overestimate of `bound` (bound / lambda_max - 1 at most)."""
        return self.bound / self.ritz - 1.0 if self.ritz > 0 else 0.0


def top(a: sp.spmatrix, count: int, work: int = LANCZOS_WORK) -> TopBound:
    """Largest eigenvalue of a symmetric sparse matrix, as `TopBound`, and its `count` top
    Ritz vectors, from `LANCZOS_STEPS` products with `a`, or more while their number times
    the size stays within `work`."""
    a = sp.csr_matrix(a)
    n = a.shape[0]
    high = float(gershgorin(a)[1].max(initial=0.0))
    if high <= 0.0 or a.nnz == 0:
        return TopBound(0.0, 0.0, np.zeros((n, 0)))
    start = _start(a)
    steps = min(n, max(LANCZOS_STEPS, work // n))
    alpha, beta = _lanczos(a, start, steps, high)
    vals, coeffs = scipy.linalg.eigh_tridiagonal(alpha, beta[:-1])
    # |beta_m s_m|: the residual norm of each Ritz pair of the tridiagonal projection
    residual = abs(beta[-1] * coeffs[-1])
    bound = min(high, float(vals[-1] + residual[-1]))
    pick = np.arange(len(vals))[::-1][:count]
    vectors = _ritz_vectors(a, start, alpha, beta, coeffs[:, pick]) if count else np.zeros((n, 0))
    return TopBound(max(bound, float(vals[-1])), float(vals[-1]), vectors)


def _start(a: sp.csr_matrix) -> np.ndarray:
    """A start vector with a part along every mode that leans towards the top: the signs of
    a two-colouring by breadth-first depth (the top mode of a bipartite network with
    restoring couplings alternates like that) times the root of the Gershgorin row sums,
    plus seeded noise."""
    n = a.shape[0]
    order, pred = breadth_first_order(a, 0, directed=False, return_predecessors=True)
    parity = np.zeros(n, np.int64)
    up = np.where(pred >= 0, pred, np.arange(n))
    step = (pred >= 0).astype(np.int64)
    for _ in range(int(np.ceil(np.log2(max(n, 2)))) + 1):  # pointer jumping to the root
        parity += step
        step = step[up]
        up = up[up]
    signs = np.where(parity % 2 == 0, 1.0, -1.0)
    weight = np.sqrt(np.asarray(abs(a).sum(axis=1)).ravel())
    noise = np.random.default_rng(0).standard_normal(n)
    return signs * weight + 0.1 * noise * weight.mean()


def _lanczos(a: sp.csr_matrix, start: np.ndarray, steps: int,
             high: float) -> tuple[np.ndarray, np.ndarray]:
    """Lanczos coefficients (alpha, beta) of up to `steps` steps, without reorthogonalisation
    (only the extreme Ritz values are used; a lost orthogonality repeats them); stops once the
    top Ritz value plus residual is within `LANCZOS_TOL` of itself or under `high`'s."""
    q = start / np.linalg.norm(start)
    prev = np.zeros_like(q)
    alpha, beta = [], []
    b = 0.0
    check = 20  # steps at which convergence is tested: 20, 30, 45, ... (cost linear in all)
    for j in range(steps):
        w = a @ q - b * prev
        alpha.append(float(q @ w))
        w -= alpha[-1] * q
        b = float(np.linalg.norm(w))
        beta.append(b)
        if b <= 1e-14 * high:  # an invariant subspace: the Ritz values are exact
            break
        prev, q = q, w / b
        if j + 1 == check:
            if _settled(alpha, beta):
                break
            check = check * 3 // 2
    return np.array(alpha), np.array(beta)


def _settled(alpha: list, beta: list) -> bool:
    last = len(alpha) - 1
    vals, coeffs = scipy.linalg.eigh_tridiagonal(np.array(alpha), np.array(beta[:-1]),
                                                 select="i", select_range=(last, last))
    return abs(beta[-1] * coeffs[-1, -1]) <= LANCZOS_TOL * max(vals[-1], 1e-300)


def _ritz_vectors(a: sp.csr_matrix, start: np.ndarray, alpha: np.ndarray, beta: np.ndarray,
                  coeffs: np.ndarray) -> np.ndarray:
    """Ritz vectors sum_j q_j coeffs[j] by running the recurrence again (the Lanczos vectors
    are not stored: for a million masses they would take gigabytes)."""
    q = start / np.linalg.norm(start)
    prev = np.zeros_like(q)
    out = np.zeros((len(q), coeffs.shape[1]))
    for j in range(len(alpha)):
        out += np.outer(q, coeffs[j])
        if j + 1 == len(alpha):
            break
        w = a @ q - (beta[j - 1] if j else 0.0) * prev  # as `_lanczos`, operation by operation
        w -= alpha[j] * q
        prev, q = q, w / beta[j]
    return out / np.linalg.norm(out, axis=0)


class Factor:
    """LDL^T of a sparse symmetric matrix `a - shift I`: `negative` is the number of
    eigenvalues of `a` below `shift` (None when SuperLU had to pivot off the diagonal, which
    spoils the symmetric form; then the inertia is unknown), `solve` applies its inverse."""

    def __init__(self, a: sp.spmatrix, shift: float) -> None:
        mat = sp.csc_matrix(a - shift * sp.identity(a.shape[0], format="csc"))
        try:
            self.lu = sla.splu(mat, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                               options={"SymmetricMode": True})
        except RuntimeError:  # an exactly singular pivot
            self.lu = None
        symmetric = self.lu is not None and np.array_equal(self.lu.perm_r, self.lu.perm_c)
        self.negative = int(np.sum(self.lu.U.diagonal() < 0)) if symmetric else None

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        return self.lu.solve(rhs)


def lowest(a: sp.spmatrix, factor: Factor, count: int) -> tuple[np.ndarray, np.ndarray]:
    """The `count` eigenpairs of `a` nearest the factor's shift (the lowest ones when the
    shift is at or below the bottom of the spectrum): inverse subspace iteration with
    `count` + 2 vectors and Rayleigh-Ritz, ascending."""
    n = a.shape[0]
    width = min(n, count + 2)
    x = np.random.default_rng(1).standard_normal((n, width))
    vals = np.full(width, np.inf)
    for _ in range(SUBSPACE_ITERATIONS):
        x, _ = np.linalg.qr(factor.solve(x))
        small = x.T @ (a @ x)
        new, rot = np.linalg.eigh((small + small.T) / 2)
        x = x @ rot
        moved = np.abs(new[:count] - vals[:count])
        vals = new
        if np.all(moved <= SUBSPACE_TOL * max(float(np.abs(new).max()), 1e-300)):
            break
    return vals[:count], x[:, :count]
