"""Linear analysis of a netlist at rest: mass, damping and stiffness matrices, connected
components, modes and the largest stable integration step.

The linearisation of m x'' + B x' + dV/dx = f at x = 0 is M x'' + B x' + K x = f with K the
Hessian of V at rest. Everything here is sparse and works per connected component of the
coupling graph: small components (up to `DENSE_MAX` dofs) are solved exactly with batched
dense eigensolvers (components of equal size share one call), larger ones by sparse
shift-invert Lanczos for the fastest modes only, which is all the step limit needs.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cache

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla
from scipy.sparse.csgraph import connected_components

from springc.kernels.integrators import (
    DEFAULT_METHOD,
    Tableau,
    amplification,
    get_tableau,
)
from springc.lang.ir import GROUND, FlatNetlist

DENSE_MAX = 300  # largest component solved with dense eigensolvers
ZERO_TOL = 1e-6  # |lambda| below this fraction of a component's largest counts as zero
SPARSE_MODES = 6  # fastest modes computed per large component
# ARPACK's convergence tolerance for those: machine precision (its default) costs twice the
# iterations on the clustered top of a long chain's spectrum for no change in the step limit
# (1e-10 and 0 agree to 1e-16 on the 10,000-element benchmark)
ARPACK_TOL = 1e-10


@dataclass
class Linearisation:
    """Sparse mass `M` (diagonal), damping `B` and stiffness `K` (Hessian of V at rest)."""

    M: sp.csr_matrix
    B: sp.csr_matrix
    K: sp.csr_matrix

    def first_order(self) -> sp.csr_matrix:
        """The first-order system matrix [[0, I], [-M^-1 K, -M^-1 B]] acting on (x, v)."""
        minv = sp.diags(1.0 / self.M.diagonal())
        eye = sp.identity(self.M.shape[0], format="csr")
        return sp.bmat([[None, eye], [-minv @ self.K, -minv @ self.B]], format="csr")


def linearise(net: FlatNetlist) -> Linearisation:
    """The linearisation at rest. Matches `physics.stiffness_matrix(net)` and
    `physics.damping_matrix(net)` but sparse and vectorised (10^4 elements in milliseconds)."""
    n = net.n
    mass = sp.diags(net.mass()).tocsr()
    damping = _sparse(n, *_damping_entries(net))
    return Linearisation(mass, damping, _sparse(n, *_stiffness_entries(net)))


def _sparse(n: int, rows, cols, vals) -> sp.csr_matrix:
    rows = np.concatenate(rows).astype(np.int64)
    cols = np.concatenate(cols).astype(np.int64)
    return sp.coo_matrix((np.concatenate(vals), (rows, cols)), shape=(n, n)).tocsr()


def _stiffness_entries(net: FlatNetlist):
    s, c, q = net.springs, net.couplings, net.quads
    rows = [s.node, c.i, c.j, c.i, c.j, q.j]
    cols = [s.node, c.i, c.j, c.j, c.i, q.j]
    vals = [s.k, c.k / c.a, c.k * c.a, -c.k, -c.k, q.g * q.a]
    for r, cc, v in _monomial_hessian_at_rest(net):
        rows.append(np.array([r]))
        cols.append(np.array([cc]))
        vals.append(np.array([v]))
    return rows, cols, vals


def _monomial_hessian_at_rest(net: FlatNetlist):
    """Only monomials of total degree 2 have a Hessian at x = 0."""
    p = net.monomials
    if len(p) == 0:
        return
    degree = np.add.reduceat(np.append(p.exp, 0), p.ptr[:-1])
    degree[p.ptr[:-1] == p.ptr[1:]] = 0
    for e in np.nonzero(degree == 2)[0]:
        powers: dict[int, int] = {}
        for k in range(p.ptr[e], p.ptr[e + 1]):
            powers[int(p.var[k])] = powers.get(int(p.var[k]), 0) + int(p.exp[k])
        live = [v for v, d in powers.items() if d > 0]
        if len(live) == 1:
            yield live[0], live[0], 2.0 * p.c[e]
        else:
            yield live[0], live[1], p.c[e]
            yield live[1], live[0], p.c[e]


def _damping_entries(net: FlatNetlist):
    d = net.dashpots
    inner = d.j != GROUND
    i2, j2, b2 = d.i[inner], d.j[inner], d.b[inner]
    nodes = np.arange(net.n)
    rows = [nodes, d.i, j2, i2, j2]
    cols = [nodes, d.i, j2, j2, i2]
    vals = [net.local_damping(), d.b, b2, -b2, -b2]
    return rows, cols, vals


def components(net: FlatNetlist) -> list[np.ndarray]:
    """Connected components of the coupling graph (C, Q, B between nodes, and the nodes of
    each P element), as arrays of node indices, in order of their first node."""
    count, labels = component_labels(net)
    order = np.argsort(labels, kind="stable")
    bounds = np.searchsorted(labels[order], np.arange(count + 1))
    return [order[bounds[c]:bounds[c + 1]] for c in range(count)]


def component_labels(net: FlatNetlist) -> tuple[int, np.ndarray]:
    """(number of components, component label of every node)."""
    c, q, d, p = net.couplings, net.quads, net.dashpots, net.monomials
    inner = d.j != GROUND
    owner = np.repeat(np.arange(len(p)), np.diff(p.ptr))
    first = p.var[p.ptr[:-1][owner]] if len(p.var) else p.var
    rows = np.concatenate([c.i, q.i, d.i[inner], p.var]).astype(np.int64)
    cols = np.concatenate([c.j, q.j, d.j[inner], first]).astype(np.int64)
    graph = sp.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(net.n, net.n))
    count, labels = connected_components(graph, directed=False)
    # Renumber so that components appear in the order of their first node.
    _, first_seen = np.unique(labels, return_index=True)
    rank = np.empty(count, np.int64)
    rank[np.argsort(first_seen)] = np.arange(count)
    return count, rank[labels]


@dataclass
class Mode:
    """One mode of the linearisation: eigenvalue `lam` of the first-order system (one of a
    conjugate pair, Im >= 0), natural frequency |lam|, and its displacement shape."""

    lam: complex
    omega: float  # |lam|, rad/s: the undamped frequency for a single oscillator
    freq_hz: float
    damping_rate: float  # -Re(lam), 1/s
    q: float  # |lam| / (2 damping_rate); 0.5 for an overdamped (real) eigenvalue
    shape: dict[str, complex]  # node name -> amplitude, the largest is 1

    def dominant(self, count: int = 3) -> list[tuple[str, float]]:
        """The `count` nodes with the largest amplitude, with |amplitude|."""
        return _dominant(self.shape, count)

    def describe(self) -> str:
        """One line for people: frequency, damping and dominant nodes."""
        nodes = ", ".join(f"{k} ({v:.2f})" for k, v in self.dominant())
        kind = "oscillating" if self.lam.imag > 0 else "overdamped"
        return (f"{kind} mode at {self.freq_hz:.6g} Hz ({self.omega:.6g} rad/s), damping rate "
                f"{self.damping_rate:.6g} 1/s, Q {self.q:.4g}, dominant nodes {nodes}")


@dataclass
class ZeroModes:
    """Zero-stiffness modes (free motion) of one component: how many, and the nodes that
    move most in them (weight: row norm of the normalised null-space basis)."""

    count: int
    nodes: list[tuple[str, float]]
    at_least: bool = False  # True when a large component was only searched for a few

    def describe(self) -> str:
        more = "at least " if self.at_least else ""
        names = ", ".join(n for n, _ in self.nodes)
        s = "" if self.count == 1 else "s"
        return f"{more}{self.count} zero-stiffness mode{s} (free motion), dominant nodes {names}"


@dataclass
class Modes:
    """Modes of the linearisation, sorted by natural frequency. For components larger than
    `DENSE_MAX` only the fastest `SPARSE_MODES` are computed (`complete` is False), with
    damping from the projection of B on the undamped modes (exact for proportional damping)."""

    eigenvalues: np.ndarray
    freqs_hz: np.ndarray
    damping_rates: np.ndarray
    q_factors: np.ndarray
    shapes: list[tuple[np.ndarray, np.ndarray]]  # (node indices, complex amplitudes)
    zero_modes: list[ZeroModes]
    omega_max: float  # largest undamped eigenfrequency sqrt(eig(M^-1 K)), rad/s
    nodes: list[str] = field(default_factory=list)
    complete: bool = True

    def __len__(self) -> int:
        return len(self.eigenvalues)

    def mode(self, k: int) -> Mode:
        lam = complex(self.eigenvalues[k])
        return Mode(lam, abs(lam), float(self.freqs_hz[k]), float(self.damping_rates[k]),
                    float(self.q_factors[k]), self.shape(k))

    def shape(self, k: int) -> dict[str, complex]:
        """Displacement shape of mode k by node name, scaled so its largest entry is 1."""
        nodes, amps = self.shapes[k]
        big = int(np.argmax(np.abs(amps)))
        amps = amps / amps[big] if amps[big] != 0 else amps
        keep = np.nonzero(np.abs(amps) > 1e-12)[0]
        return {self.nodes[int(nodes[j])]: complex(amps[j]) for j in keep}

    @property
    def zero_count(self) -> int:
        return sum(z.count for z in self.zero_modes)


@dataclass
class StepLimit:
    """The largest stable step of an integrator and the mode that sets it (None: no mode
    limits the step, e.g. no stiffness and no damping)."""

    method: str
    dt: float
    mode: Mode | None = None


@dataclass
class _Raw:
    """Per-component raw eigen-data collected before building `Modes`."""

    lam: list = field(default_factory=list)
    shapes: list = field(default_factory=list)
    zero: list = field(default_factory=list)
    omega2_max: float = 0.0
    complete: bool = True


def modes(net: FlatNetlist, lin: Linearisation | None = None) -> Modes:
    """All modes of the linearisation at rest (see `Modes` for large components)."""
    lin = lin or linearise(net)
    count, labels = component_labels(net)
    raw = _Raw()
    sizes = np.bincount(labels, minlength=count)
    for size in np.unique(sizes):
        members = np.nonzero(sizes == size)[0]
        if size <= DENSE_MAX:
            _dense_group(net, lin, labels, members, int(size), raw)
        else:
            for comp in members:
                _sparse_component(net, lin, np.nonzero(labels == comp)[0], raw)
    return _assemble(raw, net.nodes)


def _blocks(mat: sp.csr_matrix, nodes: np.ndarray) -> np.ndarray:
    """Dense diagonal blocks of `mat` for a (groups, size) array of node indices."""
    g, s = nodes.shape
    flat = nodes.ravel()
    sub = mat[flat][:, flat].tocoo()
    same = sub.row // s == sub.col // s
    out = np.zeros((g, s, s))
    r, c = sub.row[same], sub.col[same]
    out[r // s, r % s, c % s] = sub.data[same]
    return out


def _group_nodes(labels: np.ndarray, members: np.ndarray, size: int) -> np.ndarray:
    """(len(members), size) node indices of the given components."""
    mask = np.isin(labels, members)
    idx = np.nonzero(mask)[0]
    order = np.argsort(labels[idx], kind="stable")
    return idx[order].reshape(len(members), size)


def _dense_group(net, lin: Linearisation, labels, members, size: int, raw: _Raw) -> None:
    nodes = _group_nodes(labels, members, size)
    m = net.mass()[nodes]
    k, b = _blocks(lin.K, nodes), _blocks(lin.B, nodes)
    sq = np.sqrt(m)
    scale = sq[:, :, None] * sq[:, None, :]
    omega2, vecs = np.linalg.eigh(k / scale)
    raw.omega2_max = max(raw.omega2_max, float(omega2.max(initial=0.0)))
    shapes = vecs / sq[:, :, None]
    for g in range(len(members)):
        _record_zero(net, nodes[g], omega2[g], shapes[g], raw)
    modal_b = np.swapaxes(vecs, 1, 2) @ (b / scale) @ vecs
    if _is_diagonal(modal_b):
        # Damping does not couple the undamped modes (e.g. b = alpha m): each mode is exact.
        lam = _pair_roots(np.diagonal(modal_b, axis1=1, axis2=2), np.maximum(omega2, 0.0))
        for g in range(len(members)):
            _record_modes(nodes[g], lam[g], np.hstack([shapes[g], shapes[g]]), raw)
        return
    a = np.zeros((len(members), 2 * size, 2 * size))
    a[:, :size, size:] = np.eye(size)
    a[:, size:, :size] = -k / m[:, :, None]
    a[:, size:, size:] = -b / m[:, :, None]
    lam, vec = np.linalg.eig(a)
    for g in range(len(members)):
        _record_modes(nodes[g], lam[g], vec[g][:size], raw)


def _is_diagonal(mats: np.ndarray) -> bool:
    diag = np.abs(np.diagonal(mats, axis1=1, axis2=2))
    off = np.abs(mats).sum(axis=2) - diag
    return bool(np.all(off <= 1e-10 * (diag.max(initial=0.0) + 1e-300)))


def _pair_roots(gamma: np.ndarray, omega2: np.ndarray) -> np.ndarray:
    """Roots of lambda^2 + gamma lambda + omega^2 = 0 for every mode: the '+' roots of all
    modes, then the '-' roots (shape (..., 2 modes))."""
    root = np.sqrt((gamma**2 / 4 - omega2).astype(complex))
    return np.concatenate([-gamma / 2 + root, -gamma / 2 - root], axis=-1)


def _record_zero(net, nodes, omega2, shapes, raw: _Raw, at_least: bool = False) -> None:
    scale = float(np.max(np.abs(omega2), initial=0.0))
    zero = np.abs(omega2) <= ZERO_TOL**2 * scale if scale > 0 else np.ones(len(omega2), bool)
    if not zero.any():
        return
    basis = shapes[:, zero]
    basis = basis / np.abs(basis).max(axis=0)
    weight = np.linalg.norm(basis, axis=1)
    weight = weight / weight.max()
    top = np.argsort(-weight, kind="stable")[:3]
    raw.zero.append(ZeroModes(int(zero.sum()), [(net.nodes[nodes[t]], float(weight[t]))
                                                 for t in top], at_least))


def _record_modes(nodes, lam, shapes, raw: _Raw) -> None:
    scale = float(np.max(np.abs(lam), initial=0.0))
    keep = (np.abs(lam) > ZERO_TOL * scale) & (lam.imag >= -ZERO_TOL * np.abs(lam))
    for j in np.nonzero(keep)[0]:
        real = abs(lam[j].imag) <= ZERO_TOL * abs(lam[j])
        raw.lam.append(complex(lam[j].real, 0.0) if real else complex(lam[j]))
        raw.shapes.append((nodes, shapes[:, j]))


def _sparse_component(net, lin: Linearisation, nodes: np.ndarray, raw: _Raw) -> None:
    """Fastest modes of a large component. Candidates: the highest and the lowest undamped
    modes (shift-invert Lanczos above a Gershgorin bound and just below zero) and the most
    damped directions; each gives the eigenvalue pair of its modal mass, damping and
    stiffness. Exact when damping does not couple the undamped modes (e.g. b = alpha m):
    oscillating modes are fastest at the top of the spectrum, overdamped ones at the bottom."""
    m = net.mass()[nodes]
    isq = sp.diags(1.0 / np.sqrt(m))
    kt = (isq @ lin.K[nodes][:, nodes] @ isq).tocsc()
    bt = (isq @ lin.B[nodes][:, nodes] @ isq).tocsc()
    kvals, kvecs = _top_eigs(kt)
    _, lvecs = _sparse_zero_modes(net, kt, nodes, m, kvals, raw)
    raw.omega2_max = max(raw.omega2_max, float(kvals.max(initial=0.0)))
    raw.complete = False
    cand = np.hstack([kvecs, lvecs, _top_damping_vectors(bt)]).T
    w2 = np.einsum("ij,ij->i", cand, (kt @ cand.T).T)
    gamma = np.einsum("ij,ij->i", cand, (bt @ cand.T).T)
    lam = _pair_roots(gamma, np.maximum(w2, 0.0))
    shapes = np.vstack([cand, cand]).T / np.sqrt(m)[:, None]
    _record_modes(nodes, lam, shapes, raw)


def _top_eigs(mat: sp.csc_matrix) -> tuple[np.ndarray, np.ndarray]:
    """Largest eigenvalues of a symmetric positive semidefinite sparse matrix."""
    n = mat.shape[0]
    bound = float(np.max(np.asarray(abs(mat).sum(axis=1)).ravel(), initial=0.0))
    if bound == 0.0:
        return np.zeros(0), np.zeros((n, 0))
    k = min(SPARSE_MODES, n - 1)
    return sla.eigsh(mat, k=k, sigma=bound * (1 + 1e-6), which="LM", tol=ARPACK_TOL)


def _top_damping_vectors(bt: sp.csc_matrix) -> np.ndarray:
    """Directions of strongest damping (unit vectors when damping is local only)."""
    if bt.nnz == 0 or not np.any(bt.data):
        return np.zeros((bt.shape[0], 0))
    if (bt - sp.diags(bt.diagonal())).count_nonzero() == 0:
        top = np.argsort(-bt.diagonal(), kind="stable")[: min(SPARSE_MODES, bt.shape[0])]
        out = np.zeros((bt.shape[0], len(top)))
        out[top, np.arange(len(top))] = 1.0
        return out
    return _top_eigs(bt)[1]


def _sparse_zero_modes(net, kt, nodes, m, kvals, raw: _Raw) -> tuple[np.ndarray, np.ndarray]:
    """Record the zero modes of a large component; return its lowest modes (values, vectors
    in mass-weighted coordinates)."""
    n = len(nodes)
    scale = float(kvals.max(initial=0.0))
    if scale == 0.0:  # no stiffness at all: every node moves freely
        weight = 1 / np.sqrt(m)
        top = np.argsort(-weight, kind="stable")[:3]
        names = [(net.nodes[nodes[t]], float(weight[t] / weight.max())) for t in top]
        raw.zero.append(ZeroModes(n, names))
        return np.zeros(0), np.zeros((n, 0))
    k = min(SPARSE_MODES, n - 1)
    low, vecs = sla.eigsh(kt, k=k, sigma=-ZERO_TOL * scale, which="LM", tol=ARPACK_TOL)
    zero = np.abs(low) <= ZERO_TOL**2 * scale
    _record_zero(net, nodes, np.where(zero, 0.0, scale), vecs / np.sqrt(m)[:, None], raw,
                 at_least=bool(zero.all()))
    return low, vecs


def _assemble(raw: _Raw, names: list[str]) -> Modes:
    lam = np.asarray(raw.lam, dtype=complex)
    omega = np.abs(lam)
    order = np.argsort(omega, kind="stable")
    lam, omega = lam[order], omega[order]
    rate = -lam.real
    rate[np.abs(rate) <= 1e-12 * omega] = 0.0  # round-off of undamped modes
    with np.errstate(divide="ignore", invalid="ignore"):
        q = np.where(rate > 0, omega / (2 * rate), np.inf)
    shapes = [raw.shapes[k] for k in order]
    return Modes(lam, omega / (2 * np.pi), rate, q, shapes, raw.zero,
                 float(np.sqrt(raw.omega2_max)), list(names), raw.complete)


def _dominant(shape: dict[str, complex], count: int) -> list[tuple[str, float]]:
    items = sorted(shape.items(), key=lambda kv: -abs(kv[1]))
    return [(k, abs(v)) for k, v in items[:count]]


def step_limit(found: Modes, method: str = DEFAULT_METHOD) -> StepLimit:
    """Largest stable step of `method` for these modes, and the mode that sets it: the same
    answer as `integrators.max_stable_step` over all eigenvalues, vectorised."""
    tab = get_tableau(method)
    lam = found.eigenvalues
    if len(lam) == 0:
        return StepLimit(method, np.inf)
    if np.any(lam.real > ZERO_TOL * np.abs(lam)):
        worst = int(np.argmax(lam.real))
        return StepLimit(method, 0.0, found.mode(worst))
    # h = s(angle) / |lam|: estimate s from a cached table of angles, then compute exactly
    # only for the modes whose estimate is within the table's interpolation error of the
    # smallest.
    mag = np.abs(lam)
    angles, table, error = _ray_table(tab)
    estimate = np.interp(np.clip(np.angle(lam), angles[0], angles[-1]), angles, table) / mag
    cand = np.nonzero(estimate <= estimate.min() * (1 + 2 * error + 1e-3) + 1e-300)[0]
    steps = ray_limits(tab, lam[cand] / mag[cand]) / mag[cand]
    best = int(np.argmin(steps))
    if not np.isfinite(steps[best]):
        return StepLimit(method, np.inf)
    return StepLimit(method, float(steps[best]), found.mode(int(cand[best])))


@cache
def _ray_table(tab: Tableau) -> tuple[np.ndarray, np.ndarray, float]:
    """Stable |h lambda| along 181 directions from the positive imaginary axis to the
    negative real axis (eigenvalues with Im >= 0 lie in that quadrant), and the largest
    relative error of linear interpolation in it, measured halfway between its angles."""
    angles = np.linspace(np.pi / 2, np.pi, 181)
    table = ray_limits(tab, np.exp(1j * angles))
    half = (angles[1:] + angles[:-1]) / 2
    exact = ray_limits(tab, np.exp(1j * half))
    guess = np.interp(half, angles, table)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.abs(guess / exact - 1)
    return angles, table, float(np.nanmax(np.where(exact > 0, rel, 0.0)))


def ray_limits(tab: Tableau, directions: np.ndarray, chunk: int = 256) -> np.ndarray:
    """For unit complex `directions` d, the largest s with |R(t d)| <= 1 + 1e-12 for all
    0 < t <= s (first exit along the ray; inf if none before 8), as `integrators._ray_limit`
    computes it one at a time: a grid of 4000 radii, then bisection, for all rays at once."""
    radii = np.linspace(0.0, 8.0, 4001)[1:]
    out = np.empty(len(directions))
    for lo in range(0, len(directions), chunk):
        d = np.asarray(directions[lo:lo + chunk], dtype=complex)
        bad = np.abs(amplification(tab, radii[None, :] * d[:, None])) > 1 + 1e-12
        first = np.argmax(bad, axis=1)
        low = np.where(first > 0, radii[np.maximum(first - 1, 0)], 0.0)
        high = radii[first]
        for _ in range(60):
            mid = 0.5 * (low + high)
            over = np.abs(amplification(tab, mid * d)) > 1 + 1e-12
            high, low = np.where(over, mid, high), np.where(over, low, mid)
        out[lo:lo + chunk] = np.where(bad.any(axis=1), np.where(first > 0, low, 0.0), np.inf)
    return out


def dt_max(net: FlatNetlist, method: str = DEFAULT_METHOD) -> float:
    """Largest stable step of `method` for the linearisation at rest (inf: nothing limits)."""
    return step_limit(modes(net), method).dt


def fastest_mode(net: FlatNetlist) -> Mode | None:
    """The mode with the largest |lambda| (None if there is none)."""
    found = modes(net)
    return found.mode(len(found) - 1) if len(found) else None
