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
from typing import TYPE_CHECKING

import numpy as np

# scipy is imported in the functions that use it: a checked netlist loaded from the cache
# (springc.check.store) needs none of it, a third of a second of start-up
if TYPE_CHECKING:
    import scipy.sparse as sp

LANCZOS_STEPS = 60  # Lanczos steps for the top of a spectrum, at least ...
LANCZOS_WORK = 4_000_000  # ... and more while steps times size stays below this
LANCZOS_TOL = 1e-8  # stop earlier once the certified margin is below this
NEAR_MARGIN = 0.1  # largest certified overestimate `near` gives instead of a Lanczos run
SUBSPACE_ITERATIONS = 60  # most inverse subspace iterations
SUBSPACE_TOL = 1e-11  # ... stopped once the Ritz values move less than this, relatively


def gershgorin(a: sp.spmatrix) -> tuple[np.ndarray, np.ndarray]:
    """Per row, the low and high ends of the Gershgorin interval of a symmetric matrix."""
    import scipy.sparse as sp

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
    return top_many([a], count, work)[0]


def top_many(mats: list, count: int, work: int = LANCZOS_WORK) -> list[TopBound]:
    """`top` of every matrix in `mats`, each the same as alone: the Lanczos runs of matrices
    of one size go in lockstep, one product with their block-diagonal matrix per step, and
    every other operation is the lone run's on that matrix's row (a population's points
    share the Python overhead of the steps, not their numbers)."""
    import scipy.linalg
    import scipy.sparse as sp

    mats = [sp.csr_matrix(a) for a in mats]
    out: list[TopBound | None] = [None] * len(mats)
    sizes: dict[int, list[int]] = {}
    highs = [float(gershgorin(a)[1].max(initial=0.0)) for a in mats]
    for k, a in enumerate(mats):
        if highs[k] <= 0.0 or a.nnz == 0:
            out[k] = TopBound(0.0, 0.0, np.zeros((a.shape[0], 0)))
        else:
            sizes.setdefault(a.shape[0], []).append(k)
    for n, ks in sizes.items():
        group = [mats[k] for k in ks]
        starts = np.array([_start(a) for a in group])
        steps = min(n, max(LANCZOS_STEPS, work // n))
        runs = _lanczos(group, starts, steps, np.array([highs[k] for k in ks]))
        picks = []
        for k, (alpha, beta) in zip(ks, runs):
            vals, coeffs = scipy.linalg.eigh_tridiagonal(alpha, beta[:-1])
            # |beta_m s_m|: the residual norm of each Ritz pair of the tridiagonal projection
            residual = abs(beta[-1] * coeffs[-1])
            bound = min(highs[k], float(vals[-1] + residual[-1]))
            picks.append(coeffs[:, np.arange(len(vals))[::-1][:count]])
            out[k] = TopBound(max(bound, float(vals[-1])), float(vals[-1]), np.zeros((n, 0)))
        if count:
            for k, vectors in zip(ks, _ritz_vectors(group, starts, runs, picks)):
                out[k].vectors = vectors
    return out


def near(ref: sp.csr_matrix, top_ref: TopBound, mats: list,
         margin: float = NEAR_MARGIN) -> list[TopBound | None]:
    """`top` of each matrix in `mats` from the reference's (`top_ref`, of `ref`) without a
    Lanczos run, where Weyl's inequality certifies it closely: lambda_max(a) <= lambda_max(ref)
    + ||a - ref||_2 <= `top_ref.bound` + the largest absolute row sum of a - ref, and the
    Rayleigh quotients of the reference's Ritz vectors on `a` are a lower bound (and its
    candidate vectors). None for a matrix whose sparsity differs from the reference's or
    whose certified overestimate exceeds `margin`: it needs a run of its own (`top_many`)."""
    import scipy.sparse as sp

    ref = sp.csr_matrix(ref)
    out: list[TopBound | None] = []
    for a in mats:
        a = sp.csr_matrix(a)
        if (a.shape != ref.shape or top_ref.vectors.shape[1] == 0
                or not (np.array_equal(a.indptr, ref.indptr)
                        and np.array_equal(a.indices, ref.indices))):
            out.append(None)
            continue
        change = np.add.reduceat(np.abs(a.data - ref.data), a.indptr[:-1]) \
            if a.nnz else np.zeros(1)
        change[np.diff(a.indptr) == 0] = 0.0  # reduceat repeats a value at an empty row
        bound = min(float(gershgorin(a)[1].max(initial=0.0)),
                    top_ref.bound + float(change.max(initial=0.0)))
        v = top_ref.vectors
        ritz = float(np.einsum("ij,ij->j", v, a @ v).max())
        top = TopBound(max(bound, ritz), ritz, v)
        out.append(top if ritz > 0 and top.margin <= margin else None)
    return out


def _start(a: sp.csr_matrix) -> np.ndarray:
    """A start vector with a part along every mode that leans towards the top: the signs of
    a two-colouring by breadth-first depth (the top mode of a bipartite network with
    restoring couplings alternates like that) times the root of the Gershgorin row sums,
    plus seeded noise."""
    from scipy.sparse.csgraph import breadth_first_order

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


class _Lockstep:
    """The products of several matrices of one size with one row each of a (runs, n) array:
    one product with their block-diagonal matrix (each row's sum is its own matrix's, in the
    same order), rebuilt for the runs still going."""

    def __init__(self, mats: list) -> None:
        self.mats = mats
        self.use(np.arange(len(mats)))

    def use(self, rows: np.ndarray) -> None:
        """Multiply only the matrices `rows` from now on."""
        import scipy.sparse as sp

        self.rows = rows
        picked = [self.mats[r] for r in rows]
        if len(picked) == 1:
            self.block = picked[0]
            return
        n = picked[0].shape[0]
        ends = np.cumsum([a.indptr[-1] for a in picked])
        indptr = np.concatenate([[0]] + [a.indptr[1:] + (ends[i] - a.indptr[-1])
                                         for i, a in enumerate(picked)])
        indices = np.concatenate([a.indices.astype(np.int64) + i * n
                                  for i, a in enumerate(picked)])
        data = np.concatenate([a.data for a in picked])
        size = n * len(picked)
        self.block = sp.csr_matrix((data, indices, indptr), shape=(size, size))

    def __matmul__(self, q: np.ndarray) -> np.ndarray:
        return (self.block @ q.ravel()).reshape(q.shape)


def _lanczos(mats: list, starts: np.ndarray, steps: int,
             highs: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Lanczos coefficients (alpha, beta) of up to `steps` steps of each matrix from its row
    of `starts`, without reorthogonalisation (only the extreme Ritz values are used; a lost
    orthogonality repeats them); a run stops once its top Ritz value plus residual is within
    `LANCZOS_TOL` of itself or under its `highs` entry's."""
    product = _Lockstep(mats)
    q = _normalised(starts)
    prev = np.zeros_like(q)
    alpha: list[list[float]] = [[] for _ in mats]
    beta: list[list[float]] = [[] for _ in mats]
    b = np.zeros(len(mats))
    check = 20  # steps at which convergence is tested: 20, 30, 45, ... (cost linear in all)
    for j in range(steps):
        rows = product.rows
        w = product @ q - b[:, None] * prev
        a = np.array([float(q[i] @ w[i]) for i in range(len(rows))])
        w -= a[:, None] * q
        b = np.array([float(np.linalg.norm(w[i])) for i in range(len(rows))])
        going = np.ones(len(rows), bool)
        for i, r in enumerate(rows):
            alpha[r].append(a[i])
            beta[r].append(b[i])
            # an invariant subspace: the Ritz values are exact
            going[i] = b[i] > 1e-14 * highs[r]
        prev, q = q, w / np.where(going, b, 1.0)[:, None]
        if j + 1 == check:
            for i, r in enumerate(rows):
                going[i] = going[i] and not _settled(alpha[r], beta[r])
            check = check * 3 // 2
        if not going.all():
            if not going.any():
                break
            product.use(rows[going])
            q, prev, b = q[going], prev[going], b[going]
    return [(np.array(a), np.array(b)) for a, b in zip(alpha, beta)]


def _normalised(starts: np.ndarray) -> np.ndarray:
    """Each row over its norm, as a lone run normalises its start vector."""
    q = np.empty_like(starts)
    for r in range(len(starts)):
        q[r] = starts[r] / np.linalg.norm(starts[r])
    return q


def _settled(alpha: list, beta: list) -> bool:
    import scipy.linalg

    last = len(alpha) - 1
    vals, coeffs = scipy.linalg.eigh_tridiagonal(np.array(alpha), np.array(beta[:-1]),
                                                 select="i", select_range=(last, last))
    return abs(beta[-1] * coeffs[-1, -1]) <= LANCZOS_TOL * max(vals[-1], 1e-300)


def _ritz_vectors(mats: list, starts: np.ndarray, runs: list, coeffs: list) -> list:
    """Each matrix's Ritz vectors sum_j q_j coeffs[j] by running its recurrence again, in
    lockstep as `_lanczos`, the longest runs first so that the runs still going are the
    first rows (the Lanczos vectors are not stored: for a million masses they would take
    gigabytes)."""
    lengths = np.array([len(alpha) for alpha, _ in runs])
    order = np.argsort(-lengths, kind="stable")
    lengths, steps = lengths[order], int(lengths.max())
    alpha, beta = np.zeros((len(runs), steps)), np.zeros((len(runs), steps))
    # a run shorter than the vectors asked for has fewer: zero columns, cut off at the end
    picked = np.zeros((len(runs), steps, max(c.shape[1] for c in coeffs)))
    for i, r in enumerate(order):
        alpha[i, :lengths[i]], beta[i, :lengths[i]] = runs[r]
        picked[i, :lengths[i], :coeffs[r].shape[1]] = coeffs[r]
    product = _Lockstep([mats[r] for r in order])
    q = _normalised(starts[order])
    prev = np.zeros_like(q)
    # (runs, vectors, n): the long axis innermost; every entry is the lone run's sum
    out = np.zeros((len(runs), picked.shape[2], q.shape[1]))
    term = np.empty_like(out)
    for j in range(steps):
        live = len(q)
        np.multiply(picked[:live, j, :, None], q[:, None, :], out=term[:live])
        out[:live] += term[:live]
        live = int(np.count_nonzero(lengths > j + 1))
        if live == 0:
            break
        if live < len(q):
            product.use(np.arange(live))
            q, prev = q[:live], prev[:live]
        back = beta[:live, j - 1] if j else np.zeros(live)
        w = product @ q - back[:, None] * prev  # as `_lanczos`, operation by operation
        w -= alpha[:live, j, None] * q
        prev, q = q, w / beta[:live, j, None]
    vectors = [np.ascontiguousarray(out[i, :coeffs[r].shape[1]].T) for i, r in enumerate(order)]
    vectors = [v / np.linalg.norm(v, axis=0) for v in vectors]
    return [vectors[i] for i in np.argsort(order)]


class Factor:
    """LDL^T of a sparse symmetric matrix `a - shift I`: `negative` is the number of
    eigenvalues of `a` below `shift` (None when SuperLU had to pivot off the diagonal, which
    spoils the symmetric form; then the inertia is unknown), `solve` applies its inverse."""

    def __init__(self, a: sp.spmatrix, shift: float) -> None:
        import scipy.sparse as sp
        import scipy.sparse.linalg as sla

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
