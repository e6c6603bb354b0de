"""Linear analysis of a netlist at rest: mass, damping and stiffness matrices, connected
components, modes and the largest stable integration step.

The linearisation of m x'' + B x' + dV/dx = f at x = 0 is M x'' + B x' + K x = f with K the
Hessian of V at rest. Everything here is sparse and works per connected component of the
coupling graph: small components (up to `DENSE_MAX` dofs) are solved exactly with batched
dense eigensolvers (components of equal size share one call), larger ones in time about
linear in their size (`sparse`): the top of the spectrum by Lanczos with an upper bound, zero
modes from the inertia of one factorisation, and the fastest modes only, which is all the
step limit needs.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cache
from typing import TYPE_CHECKING

import numpy as np
from threadpoolctl import ThreadpoolController

from springc.check import sparse
from springc.kernels.integrators import (
    DEFAULT_METHOD,
    Tableau,
    amplification,
    get_tableau,
    stability_polynomial,
)
from springc.lang.ir import GROUND, FlatNetlist

# scipy is imported in the functions that use it: a checked netlist loaded from the cache
# (springc.check.store) needs none of it, a third of a second of start-up
if TYPE_CHECKING:
    import scipy.sparse as sp

DENSE_MAX = 300  # largest component solved with dense eigensolvers
ZERO_TOL = 1e-6  # |lambda| below this fraction of a component's largest counts as zero
SPARSE_MODES = 6  # fastest (and zero) modes computed per large component

@dataclass
class Linearisation:
    """Sparse mass `M` (diagonal), damping `B` and stiffness `K` (Hessian of V at rest)."""

    M: sp.csr_matrix
    B: sp.csr_matrix
    K: sp.csr_matrix

    def first_order(self) -> sp.csr_matrix:
        """The first-order system matrix [[0, I], [-M^-1 K, -M^-1 B]] acting on (x, v)."""
        import scipy.sparse as sp

        minv = sp.diags(1.0 / self.M.diagonal())
        eye = sp.identity(self.M.shape[0], format="csr")
        return sp.bmat([[None, eye], [-minv @ self.K, -minv @ self.B]], format="csr")


def linearise(net: FlatNetlist) -> Linearisation:
    """The linearisation at rest. Matches `physics.stiffness_matrix(net)` and
    `physics.damping_matrix(net)` but sparse and vectorised (10^4 elements in milliseconds)."""
    import scipy.sparse as sp

    n = net.n
    mass = sp.diags(net.mass()).tocsr()
    damping = _sparse(n, *damping_entries(net))
    return Linearisation(mass, damping, _sparse(n, *_stiffness_entries(net)))


def _sparse(n: int, rows, cols, vals) -> sp.csr_matrix:
    import scipy.sparse as sp

    rows = np.concatenate(rows).astype(np.int64)
    cols = np.concatenate(cols).astype(np.int64)
    return sp.coo_matrix((np.concatenate(vals), (rows, cols)), shape=(n, n)).tocsr()


def spring_entries(net: FlatNetlist) -> tuple[list, list, list]:
    """(rows, cols, values) of the springs' and couplings' stiffness, the part of the Hessian
    that is the same at every x, as lists of arrays (repeated entries sum)."""
    s, c = net.springs, net.couplings
    return ([s.node, c.i, c.j, c.i, c.j], [s.node, c.i, c.j, c.j, c.i],
            [s.k, c.k / c.a, c.k * c.a, -c.k, -c.k])


def _stiffness_entries(net: FlatNetlist):
    q = net.quads
    rows, cols, vals = spring_entries(net)
    rows.append(q.j)
    cols.append(q.j)
    vals.append(q.g * q.a)
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


def damping_entries(net: FlatNetlist) -> tuple[list, list, list]:
    """(rows, cols, values) of the linear damping matrix (local dampers and dashpots), as lists
    of arrays (repeated entries sum)."""
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
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

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
    conjugate pair, Im >= 0), natural frequency |lam|, and its displacement shape (amplitudes
    `amps` on the node indices `where`, the largest 1; `shape` names them)."""

    lam: complex
    omega: float  # |lam|, rad/s: the undamped frequency for a single oscillator
    freq_hz: float
    damping_rate: float  # -Re(lam), 1/s
    q: float  # |lam| / (2 damping_rate); 0.5 for an overdamped (real) eigenvalue
    where: np.ndarray = field(repr=False)
    amps: np.ndarray = field(repr=False)
    names: list[str] = field(repr=False)

    @property
    def oscillating(self) -> bool:
        """False for an overdamped mode (a real eigenvalue: a decay, no frequency)."""
        return self.lam.imag > 0

    @property
    def shape(self) -> dict[str, complex]:
        """Node name -> amplitude (the largest is 1) for every node that moves."""
        keep = np.nonzero(np.abs(self.amps) > 1e-12)[0]
        return {self.names[int(self.where[j])]: complex(self.amps[j]) for j in keep}

    def dominant(self, count: int = 3) -> list[tuple[str, float]]:
        """The `count` nodes with the largest amplitude, with |amplitude| (ties in node
        order)."""
        size = np.abs(self.amps)
        if len(size) > count:  # only the entries that can make the top `count` are sorted
            cut = np.partition(size, len(size) - count)[len(size) - count]
            pick = np.nonzero((size >= cut) & (size > 1e-12))[0]
        else:
            pick = np.nonzero(size > 1e-12)[0]
        pick = pick[np.argsort(-size[pick], kind="stable")[:count]]
        return [(self.names[int(self.where[j])], float(size[j])) for j in pick]

    def describe(self) -> str:
        """One line for people: frequency (a decay rate if overdamped), damping and dominant
        nodes."""
        nodes = ", ".join(f"{k} ({v:.2f})" for k, v in self.dominant())
        if not self.oscillating:
            return (f"overdamped mode decaying at {self.damping_rate:.6g} 1/s, dominant "
                    f"nodes {nodes}")
        return (f"oscillating mode at {self.freq_hz:.6g} Hz ({self.omega:.6g} rad/s), damping "
                f"rate {self.damping_rate:.6g} 1/s, Q {self.q:.4g}, dominant nodes {nodes}")


@dataclass
class ZeroModes:
    """Zero-stiffness modes (free motion) of one component: how many, and the nodes that
    move most in them (weight: row norm of the normalised null-space basis)."""

    count: int
    nodes: list[tuple[str, float]]
    at_least: bool = False  # always False: large components are counted exactly too

    def describe(self) -> str:
        more = "at least " if self.at_least else ""
        names = ", ".join(n for n, _ in self.nodes)
        s = "" if self.count == 1 else "s"
        return f"{more}{self.count} zero-stiffness mode{s} (free motion), dominant nodes {names}"


@dataclass
class Modes:
    """Modes of the linearisation, sorted by natural frequency. For components larger than
    `DENSE_MAX` only a few candidates for the fastest are computed (`complete` is False), with
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
    # certified relative overestimate of omega_max^2 (0: exact; see `sparse.TopBound`)
    omega_margin: float = 0.0
    # omega_max bounded from another netlist's by perturbation (`modes_many`'s `near`)
    near: bool = False

    def __len__(self) -> int:
        return len(self.eigenvalues)

    def mode(self, k: int) -> Mode:
        lam = complex(self.eigenvalues[k])
        nodes, amps = self.shapes[k]
        big = int(np.argmax(np.abs(amps)))
        amps = amps / amps[big] if amps[big] != 0 else amps
        return Mode(lam, abs(lam), float(self.freqs_hz[k]), float(self.damping_rates[k]),
                    float(self.q_factors[k]), nodes, amps, self.nodes)

    def shape(self, k: int) -> dict[str, complex]:
        """Displacement shape of mode k by node name, scaled so its largest entry is 1."""
        return self.mode(k).shape

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
    margin: float = 0.0
    complete: bool = True
    near: bool = False


def modes(net: FlatNetlist, lin: Linearisation | None = None) -> Modes:
    """All modes of the linearisation at rest (see `Modes` for large components)."""
    return modes_many([net], [lin])[0]


def modes_many(nets: list[FlatNetlist], lins: list[Linearisation | None] | None = None,
               near: bool = False) -> list[Modes]:
    """`modes` of every netlist, each the same as alone; the Lanczos runs of all their large
    components go together (`sparse.top_many`: a population's points in lockstep). With
    `near`, a large component whose stiffness has the sparsity of the first of its size
    takes the top of its spectrum from that one's by a perturbation bound where it is
    certified within `sparse.NEAR_MARGIN` (`sparse.near`; its `Modes.near` is True): the
    fastest mode then is an upper bound up to 10% above its own, never below it."""
    lins = lins or [None] * len(nets)
    raws: list = [None] * len(nets)
    large: list = []
    with _blas().limit(limits=1, user_api="blas"):
        for batch, labels in _dense_batches(nets, lins):
            for i, raw in zip(batch, _dense_modes_batch([nets[i] for i in batch], labels)):
                raws[i] = raw
        for i, (net, lin) in enumerate(zip(nets, lins)):
            if raws[i] is None:
                raws[i] = _dense_modes(net, lin, large)
    for comp, (top, by_near) in zip(large, _tops([c.kt for c in large], near)):
        comp.raw.near = comp.raw.near or by_near
        _sparse_component(comp, top)
    return _assemble_many(raws, [net.nodes for net in nets])


def _tops(mats: list, near: bool) -> list[tuple[sparse.TopBound, bool]]:
    """`sparse.top` of every large component's stiffness, and whether it came by
    perturbation from the first of its size (`modes_many`'s `near`); the others' Lanczos
    runs go in lockstep."""
    first: dict[int, int] = {}  # size -> its reference, the first component of that size
    if near:
        for k, a in enumerate(mats):
            first.setdefault(a.shape[0], k)
    found: dict[int, sparse.TopBound | None] = {k: None for k in range(len(mats))}
    refs = list(first.values())
    found.update(zip(refs, sparse.top_many([mats[k] for k in refs], SPARSE_MODES)))
    by_near = set()
    for size, ref in first.items():
        others = [k for k in range(len(mats)) if mats[k].shape[0] == size and k != ref]
        for k, top in zip(others, sparse.near(mats[ref], found[ref], [mats[k] for k in others])):
            if top is not None:
                found[k] = top
                by_near.add(k)
    rest = [k for k, top in found.items() if top is None]
    found.update(zip(rest, sparse.top_many([mats[k] for k in rest], SPARSE_MODES)))
    return [(found[k], k in by_near) for k in range(len(mats))]


@cache
def _blas() -> ThreadpoolController:
    """The process's BLAS thread pools. The dense eigensolves here are of at most 2 DENSE_MAX
    rows, where BLAS threads gain nothing, and on cores that Dask workers or numba threads
    keep busy OpenBLAS's spinning threads cost a hundredfold: 2.2 s instead of 0.024 s for
    the 280-row eig of a tuned 4x2 classifier (docs/performance.md)."""
    return ThreadpoolController()


def _dense_modes(net: FlatNetlist, lin: Linearisation | None, large: list) -> _Raw:
    """The modes of a netlist's small components; its large ones appended to `large`."""
    lin = lin or linearise(net)
    count, labels = component_labels(net)
    raw = _Raw()
    sizes = np.bincount(labels, minlength=count)
    # ascending sizes: every dense group comes before the first large component
    for size in np.unique(sizes):
        members = np.nonzero(sizes == size)[0]
        if size <= DENSE_MAX:
            _dense_group(net, lin, labels, members, int(size), raw)
        else:
            large += [_Large.of(net, lin, np.nonzero(labels == comp)[0], raw)
                      for comp in members]
    return raw


def pattern(net: FlatNetlist) -> tuple:
    """Every index array of the element tables and the node count: netlists with equal
    patterns differ in coefficients alone (the linearisation's sparsity, the components and
    each table's length are the same)."""
    return (net.n, *(a.tobytes() for a in _index_arrays(net)))


def patterns(nets: list[FlatNetlist]) -> list[tuple]:
    """`pattern` of every netlist, computed once for netlists that hold the same index
    array objects (a population's samples share them)."""
    known: dict[tuple, tuple] = {}
    out = []
    for net in nets:  # the netlists stay alive here, so ids name the same arrays
        ids = (net.n, *map(id, _index_arrays(net)))
        if ids not in known:
            known[ids] = pattern(net)
        out.append(known[ids])
    return out


def _index_arrays(net: FlatNetlist) -> tuple[np.ndarray, ...]:
    m, s, du, c, q, d, p = (net.masses, net.springs, net.duffings, net.couplings, net.quads,
                            net.dashpots, net.monomials)
    return (m.node, s.node, du.node, c.i, c.j, q.i, q.j, d.i, d.j, p.ptr, p.var, p.exp)


def _dense_batches(nets: list[FlatNetlist], lins: list) -> list[tuple[list[int], np.ndarray]]:
    """The netlists whose modes `_dense_modes_batch` finds, as lists of indices of equal
    pattern with their component labels: those with no linearisation given and every
    component dense."""
    batches: dict[tuple, list[int]] = {}
    labels: dict[tuple, np.ndarray | None] = {}
    for i, (net, lin, key) in enumerate(zip(nets, lins, patterns(nets))):
        if lin is not None:
            continue
        if key not in labels:
            count, found = component_labels(net)
            dense = np.bincount(found, minlength=count).max(initial=0) <= DENSE_MAX
            labels[key] = found if dense else None
        if labels[key] is not None:
            batches.setdefault(key, []).append(i)
    return [(batch, labels[key]) for key, batch in batches.items()]


def _dense_modes_batch(nets: list[FlatNetlist], labels: np.ndarray) -> list[_Raw]:
    """The modes of netlists of one pattern whose components (`labels`, `component_labels`)
    are all dense, each the same as alone (a netlist alone is a batch of one): the blocks
    are summed entry by entry in the same order for every netlist, and the eigensolvers
    solve each block on its own."""
    first = nets[0]
    sizes = np.bincount(labels, minlength=int(labels.max(initial=-1)) + 1)
    k_rows, k_cols, _ = (np.concatenate(a) for a in _stiffness_entries(first))
    b_rows, b_cols, _ = (np.concatenate(a) for a in damping_entries(first))
    k_vals = np.array([np.concatenate(_stiffness_entries(net)[2]) for net in nets])
    b_vals = np.array([np.concatenate(damping_entries(net)[2]) for net in nets])
    mass = np.array([net.mass() for net in nets])
    raws = [_Raw() for _ in nets]
    for size in np.unique(sizes):
        nodes = _group_nodes(labels, np.nonzero(sizes == size)[0], int(size))
        _dense_blocks(nets, nodes, mass[:, nodes], _scatter_blocks(k_rows, k_cols, k_vals, nodes),
                      _scatter_blocks(b_rows, b_cols, b_vals, nodes), raws)
    return raws


def _scatter_blocks(rows: np.ndarray, cols: np.ndarray, vals: np.ndarray,
                    nodes: np.ndarray) -> np.ndarray:
    """(netlists, groups, size, size) dense diagonal blocks for a (groups, size) array of
    node indices, from entries (rows, cols) with one row of values per netlist (repeated
    entries sum, in entry order)."""
    g, s = nodes.shape
    top = max(rows.max(initial=-1), cols.max(initial=-1), nodes.max()) + 1
    group, place = np.full(top, -1), np.zeros(top, np.int64)
    group[nodes.ravel()] = np.repeat(np.arange(g), s)
    place[nodes.ravel()] = np.tile(np.arange(s), g)
    inside = (group[rows] >= 0) & (group[rows] == group[cols])
    target = (group[rows] * s + place[rows]) * s + place[cols]
    out = np.zeros((len(vals), g * s * s))
    np.add.at(out, (slice(None), target[inside]), vals[:, inside])
    return out.reshape(len(vals), g, s, s)


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
    _dense_blocks([net], nodes, net.mass()[nodes][None], _blocks(lin.K, nodes)[None],
                  _blocks(lin.B, nodes)[None], [raw])


def _dense_blocks(nets: list, nodes: np.ndarray, m: np.ndarray, k: np.ndarray, b: np.ndarray,
                  raws: list[_Raw]) -> None:
    """The modes of the dense components `nodes` ((groups, size) node indices) of every
    netlist in `nets`, from their masses (nets, groups, size) and stiffness and damping
    blocks (nets, groups, size, size). Each block is solved on its own, so that a
    netlist's modes are the same in any batch."""
    _, groups, size = m.shape
    sq = np.sqrt(m)
    scale = sq[..., :, None] * sq[..., None, :]
    omega2, vecs = np.linalg.eigh(k / scale)
    shapes = vecs / sq[..., :, None]
    modal_b = np.swapaxes(vecs, -1, -2) @ (b / scale) @ vecs
    # where damping does not couple the undamped modes (e.g. b = alpha m) each is exact
    diagonal = _is_diagonal(modal_b)
    lam = _pair_roots(np.diagonal(modal_b, axis1=-2, axis2=-1), np.maximum(omega2, 0.0))
    coupled = np.nonzero(~diagonal)[0]
    a = np.zeros((len(coupled), groups, 2 * size, 2 * size))
    a[..., :size, size:] = np.eye(size)
    a[..., size:, :size] = -k[coupled] / m[coupled][..., None]
    a[..., size:, size:] = -b[coupled] / m[coupled][..., None]
    lam_c, vec_c = np.linalg.eig(a) if len(coupled) else (a, a)
    top = omega2.reshape(len(nets), -1).max(axis=1, initial=0.0)
    for n, raw in enumerate(raws):
        raw.omega2_max = max(raw.omega2_max, float(top[n]))
    _record_zeros(nets, nodes, omega2, shapes, raws)
    lam = lam.astype(complex)
    if len(coupled):
        lam[coupled] = lam_c
    vectors = [np.concatenate([shapes, shapes], axis=-1), vec_c[..., :size, :]]
    where = np.zeros(len(nets), np.int64)
    where[coupled] = np.arange(len(coupled))
    _record_kept(nodes, lam, vectors, diagonal, where, raws)


def _is_diagonal(mats: np.ndarray) -> np.ndarray:
    """Per netlist (the first axis of (nets, groups, size, size) blocks): whether every
    block is diagonal to 1e-10 of the netlist's largest diagonal entry."""
    diag = np.abs(np.diagonal(mats, axis1=-2, axis2=-1))
    off = np.abs(mats).sum(axis=-1) - diag
    flat = len(mats), -1
    bound = 1e-10 * (diag.reshape(flat).max(axis=1, initial=0.0) + 1e-300)
    return np.all(off.reshape(flat) <= bound[:, None], axis=1)


def _pair_roots(gamma: np.ndarray, omega2: np.ndarray) -> np.ndarray:
    """Roots of lambda^2 + gamma lambda + omega^2 = 0 for every mode: the '+' roots of all
    modes, then the '-' roots (shape (..., 2 modes))."""
    root = np.sqrt((gamma**2 / 4 - omega2).astype(complex))
    return np.concatenate([-gamma / 2 + root, -gamma / 2 - root], axis=-1)


def _record_zeros(nets: list, nodes: np.ndarray, omega2: np.ndarray, shapes: np.ndarray,
                  raws: list[_Raw]) -> None:
    """Each block's zero modes (|omega^2| within ZERO_TOL^2 of its largest, all where that
    is 0) as a `ZeroModes` entry of its netlist, blocks in order."""
    scale = np.abs(omega2).max(axis=-1, initial=0.0)[..., None]
    zero = np.where(scale > 0, np.abs(omega2) <= ZERO_TOL**2 * scale, True)
    for n, g in zip(*np.nonzero(zero.any(axis=-1))):
        raws[n].zero.append(_zero_entry(nets[n], nodes[g], shapes[n, g][:, zero[n, g]],
                                        int(zero[n, g].sum())))


def _record_kept(nodes: np.ndarray, lam: np.ndarray, vectors: list[np.ndarray],
                 diagonal: np.ndarray, where: np.ndarray, raws: list[_Raw]) -> None:
    """`_record_modes` of every block ((nets, groups, 2 size) eigenvalues; netlist n's
    shapes from vectors[0][n] where its damping is diagonal, else vectors[1][where[n]]),
    the masks for all blocks at once."""
    mag = np.abs(lam)
    scale = mag.max(axis=-1, initial=0.0)[..., None]
    keep = (mag > ZERO_TOL * scale) & (lam.imag >= -ZERO_TOL * mag)
    fixed = np.where(np.abs(lam.imag) <= ZERO_TOL * mag, lam.real.astype(complex), lam)
    for n, raw in enumerate(raws):
        vecs = vectors[0][n] if diagonal[n] else vectors[1][where[n]]
        for g in range(len(nodes)):
            kept = np.flatnonzero(keep[n, g])
            raw.lam += fixed[n, g, kept].tolist()
            raw.shapes += [(nodes[g], vecs[g][:, j]) for j in kept]


def _zero_entry(net, nodes, basis: np.ndarray, count: int) -> ZeroModes:
    """`count` zero modes whose dominant nodes are those of the columns of `basis`."""
    basis = basis / np.abs(basis).max(axis=0)
    weight = np.linalg.norm(basis, axis=1)
    weight = weight / weight.max()
    top = np.argsort(-weight, kind="stable")[:3]
    return ZeroModes(count, [(net.nodes[nodes[t]], float(weight[t])) for t in top])


def _record_modes(nodes, lam, shapes, raw: _Raw) -> None:
    scale = float(np.max(np.abs(lam), initial=0.0))
    keep = (np.abs(lam) > ZERO_TOL * scale) & (lam.imag >= -ZERO_TOL * np.abs(lam))
    for j in np.nonzero(keep)[0]:
        real = abs(lam[j].imag) <= ZERO_TOL * abs(lam[j])
        raw.lam.append(complex(lam[j].real, 0.0) if real else complex(lam[j]))
        raw.shapes.append((nodes, shapes[:, j]))


@dataclass
class _Large:
    """A large component of a netlist: its nodes and masses, stiffness and damping in
    mass-weighted coordinates, and the raw data of its netlist's modes."""

    net: FlatNetlist
    nodes: np.ndarray
    m: np.ndarray
    kt: sp.csr_matrix
    bt: sp.csr_matrix
    raw: _Raw

    @classmethod
    def of(cls, net: FlatNetlist, lin: Linearisation, nodes: np.ndarray, raw: _Raw) -> _Large:
        import scipy.sparse as sp

        m = net.mass()[nodes]
        isq = sp.diags(1.0 / np.sqrt(m))
        kt = (isq @ lin.K[nodes][:, nodes] @ isq).tocsr()
        bt = (isq @ lin.B[nodes][:, nodes] @ isq).tocsr()
        return cls(net, nodes, m, kt, bt, raw)


def _sparse_component(comp: _Large, top: sparse.TopBound) -> None:
    """Fastest modes of a large component, in time linear in its size for the common case.
    Candidates: the top of the undamped spectrum (Lanczos, `sparse.top`; the top candidate
    gets the upper bound of lambda_max, so that no step is judged against an underestimate),
    the zero modes, the most damped directions and, where damping is strong enough for an
    overdamped mode to be the fastest, the lowest modes; each gives the eigenvalue pair of its
    modal mass, damping and stiffness. Exact when damping does not couple the undamped modes
    (e.g. b = alpha m): oscillating modes are fastest at the top of the spectrum, overdamped
    ones at the bottom. `top`: `sparse.top` of its stiffness `comp.kt`."""
    net, nodes, m, kt, bt, raw = comp.net, comp.nodes, comp.m, comp.kt, comp.bt, comp.raw
    raw.omega2_max = max(raw.omega2_max, top.bound)
    raw.margin = max(raw.margin, top.margin)
    raw.complete = False
    zero = _sparse_zero_modes(net, kt, nodes, m, top.bound, raw)
    cand = np.hstack([top.vectors, zero, _top_damping_vectors(bt)]).T
    w2, gamma = _rayleigh(kt, bt, cand)
    w2[:min(1, top.vectors.shape[1])] = top.bound
    if _overdamped_may_lead(bt, gamma, w2):
        low = _lowest_modes(kt, top.bound, zero.shape[1])
        more_w2, more_gamma = _rayleigh(kt, bt, low.T)
        cand = np.vstack([cand, low.T])
        w2, gamma = np.append(w2, more_w2), np.append(gamma, more_gamma)
    lam = _pair_roots(gamma, np.maximum(w2, 0.0))
    shapes = np.vstack([cand, cand]).T / np.sqrt(m)[:, None]
    _record_modes(nodes, lam, shapes, raw)


def _rayleigh(kt, bt, cand: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Modal stiffness and damping (Rayleigh quotients) of unit candidate rows."""
    w2 = np.einsum("ij,ij->i", cand, (kt @ cand.T).T)
    gamma = np.einsum("ij,ij->i", cand, (bt @ cand.T).T)
    return w2, gamma


# Real (overdamped) eigenvalues are at most the largest damping rate in size; along the
# negative real axis every tableau's stability boundary is at least 0.91 of its farthest
# point on any other ray of the left half-plane, so below half the fastest candidate's
# |lambda| they cannot set the step, and the lowest modes are not needed.
OVERDAMPED_SHARE = 0.5


def _overdamped_may_lead(bt, gamma: np.ndarray, w2: np.ndarray) -> bool:
    """Whether damping is strong enough that a slow overdamped mode may be the fastest."""
    if bt.nnz == 0:
        return False
    fastest = float(np.abs(_pair_roots(gamma, np.maximum(w2, 0.0))).max(initial=0.0))
    return float(sparse.gershgorin(bt)[1].max()) >= OVERDAMPED_SHARE * fastest


def _lowest_modes(kt, scale: float, zeros: int) -> np.ndarray:
    """The lowest `SPARSE_MODES` non-zero modes (and the zero modes below them), as unit
    columns in mass-weighted coordinates."""
    factor = sparse.Factor(kt, -ZERO_TOL**2 * scale)
    count = min(kt.shape[0] - 1, min(zeros, SPARSE_MODES) + SPARSE_MODES)
    return sparse.lowest(kt, factor, count)[1]


def _top_damping_vectors(bt: sp.csr_matrix) -> np.ndarray:
    """Directions of strongest damping (unit vectors when damping is local only)."""
    import scipy.sparse as sp

    if bt.nnz == 0 or not np.any(bt.data):
        return np.zeros((bt.shape[0], 0))
    if (bt - sp.diags(bt.diagonal())).count_nonzero() == 0:
        top = np.argsort(-bt.diagonal(), kind="stable")[: min(SPARSE_MODES, bt.shape[0])]
        out = np.zeros((bt.shape[0], len(top)))
        out[top, np.arange(len(top))] = 1.0
        return out
    return sparse.top(bt, SPARSE_MODES).vectors


def _sparse_zero_modes(net, kt, nodes, m, scale: float, raw: _Raw) -> np.ndarray:
    """Record the zero modes of a large component (|lambda| <= ZERO_TOL^2 of its largest, as
    `_record_zero` counts them): counted by the inertia of one factorisation of the blocks
    of the stiffness that Gershgorin's discs do not prove stiff, with a basis (of up to
    `SPARSE_MODES`, in mass-weighted coordinates) from inverse iteration; return it."""
    n = len(nodes)
    if scale == 0.0:  # no stiffness at all: every node moves freely
        weight = 1 / np.sqrt(m)
        top = np.argsort(-weight, kind="stable")[:3]
        names = [(net.nodes[nodes[t]], float(weight[t] / weight.max())) for t in top]
        raw.zero.append(ZeroModes(n, names))
        return np.zeros((n, 0))
    tau = ZERO_TOL**2 * scale
    loose = _loose_blocks(kt, tau)
    if len(loose) == 0:
        return np.zeros((n, 0))
    sub = kt[loose][:, loose]
    count, factor = _count_zero(sub, tau)
    if count == 0:
        return np.zeros((n, 0))
    basis = np.zeros((n, min(count, SPARSE_MODES)))
    basis[loose] = sparse.lowest(sub, factor, basis.shape[1])[1]
    raw.zero.append(_zero_entry(net, nodes, basis / np.sqrt(m)[:, None], count))
    return basis


def _loose_blocks(kt, tau: float) -> np.ndarray:
    """Nodes of the connected blocks of the stiffness whose Gershgorin discs do not all lie
    above `tau` (the others have no eigenvalue at or below it)."""
    from scipy.sparse.csgraph import connected_components

    _, labels = connected_components(kt, directed=False)
    low = sparse.gershgorin(kt)[0]
    least = np.full(labels.max(initial=-1) + 1, np.inf)
    np.minimum.at(least, labels, low)
    return np.nonzero(least[labels] <= tau)[0]


def _count_zero(sub, tau: float) -> tuple[int, sparse.Factor]:
    """Eigenvalues of `sub` within [-tau, tau], and the factorisation of `sub - tau I`."""
    factor = sparse.Factor(sub, tau)
    below = factor.negative
    if below is None:  # an off-diagonal pivot: shift a little further (no inertia else)
        factor = sparse.Factor(sub, tau * (1 + 1e-3))
        below = factor.negative
    if below is None:
        raise RuntimeError("INTERNAL ERROR: no symmetric factorisation of the stiffness; "
                           "please report this netlist")
    if below and sparse.gershgorin(sub)[0].min() < -tau:
        below -= sparse.Factor(sub, -tau).negative or 0
    return below, factor


def _assemble_many(raws: list[_Raw], names: list[list[str]]) -> list[Modes]:
    """Every netlist's `Modes` from its raw data, sorted by |lambda|: the raws with equal
    mode counts as one array (each row what it gives alone: the operations are
    elementwise, the sort per row)."""
    out: list = [None] * len(raws)
    by_count: dict[int, list[int]] = {}
    for i, raw in enumerate(raws):
        by_count.setdefault(len(raw.lam), []).append(i)
    for count, idx in by_count.items():
        lam = np.array([raws[i].lam for i in idx], dtype=complex).reshape(len(idx), count)
        omega = np.abs(lam)
        order = np.argsort(omega, axis=1, kind="stable")
        lam, omega = np.take_along_axis(lam, order, 1), np.take_along_axis(omega, order, 1)
        rate = -lam.real
        rate[np.abs(rate) <= 1e-12 * omega] = 0.0  # round-off of undamped modes
        with np.errstate(divide="ignore", invalid="ignore"):
            q = np.where(rate > 0, omega / (2 * rate), np.inf)
        freqs = omega / (2 * np.pi)
        top = np.sqrt(np.array([raws[i].omega2_max for i in idx]))
        for r, i in enumerate(idx):
            raw = raws[i]
            out[i] = Modes(lam[r], freqs[r], rate[r], q[r], [raw.shapes[k] for k in order[r]],
                           raw.zero, float(top[r]), list(names[i]), raw.complete, raw.margin,
                           raw.near)
    return out


def step_limit(found: Modes, method: str = DEFAULT_METHOD) -> StepLimit:
    """Largest stable step of `method` for these modes, and the mode that sets it: the same
    answer as `integrators.max_stable_step` over all eigenvalues, vectorised."""
    return step_limits([found], method)[0]


def step_limits(founds: list[Modes], method: str = DEFAULT_METHOD) -> list[StepLimit]:
    """`step_limit` of every set of modes, each the same as alone (one `ray_limits` call
    for all their candidate modes: each ray's limit is computed on its own)."""
    tab = get_tableau(method)
    out = [StepLimit(method, np.inf) for _ in founds]
    some = [k for k, found in enumerate(founds) if len(found.eigenvalues)]
    if not some:
        return out
    sizes = np.array([len(founds[k].eigenvalues) for k in some])
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    lam = np.concatenate([founds[k].eigenvalues for k in some])
    mag = np.abs(lam)
    unstable = np.logical_or.reduceat(lam.real > ZERO_TOL * mag, starts)
    for k, first in zip(np.array(some)[unstable], starts[unstable]):
        own = lam[first:first + len(founds[k].eigenvalues)]
        out[k] = StepLimit(method, 0.0, founds[k].mode(int(np.argmax(own.real))))
    owner = np.repeat(np.arange(len(some)), sizes)
    cand = _candidates(tab, lam, mag, starts, owner)
    cand = cand[~unstable[owner[cand]]]
    if not len(cand):
        return out
    steps = ray_limits(tab, lam[cand] / mag[cand]) / mag[cand]
    # each netlist's first candidate with the smallest step (np.argmin's choice)
    order = np.lexsort((cand, steps, owner[cand]))
    best = order[np.r_[True, np.diff(owner[cand][order]) != 0]]
    for b in best:
        j = int(owner[cand[b]])
        k = some[j]
        out[k] = (StepLimit(method, np.inf) if not np.isfinite(steps[b]) else
                  StepLimit(method, float(steps[b]), founds[k].mode(int(cand[b] - starts[j]))))
    return out


def _candidates(tab: Tableau, lam: np.ndarray, mag: np.ndarray, starts: np.ndarray,
                owner: np.ndarray) -> np.ndarray:
    """The modes that may set each netlist's step (`lam`: every netlist's eigenvalues one
    after another from `starts`, `owner` the netlist of each): h = s(angle) / |lam|, s
    estimated from a cached table of angles, and only the modes whose estimate is within the
    table's interpolation error of their netlist's smallest are computed exactly."""
    angles, table, error = _ray_table(tab)
    estimate = np.interp(np.clip(np.angle(lam), angles[0], angles[-1]), angles, table) / mag
    lowest = np.minimum.reduceat(estimate, starts)
    return np.nonzero(estimate <= lowest[owner] * (1 + 2 * error + 1e-3) + 1e-300)[0]


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


EXIT_TOL = 1e-12  # |R| above 1 + EXIT_TOL is outside (integrators._ray_limit's tolerance)
# rays whose angles lie within this many radians of their group's middle ray are found from
# that ray's scan (`_grouped_exits`); groups of fewer rays are scanned ray by ray
GROUP_SPAN = 1e-3
GROUP_MIN = 8


def ray_limits(tab: Tableau, directions: np.ndarray, chunk: int = 4096) -> np.ndarray:
    """For unit complex `directions` d, the largest s with |R(t d)| <= 1 + 1e-12 for all
    0 < t <= s (first exit along the ray; inf if none before 8), as `integrators._ray_limit`
    computes it one at a time: the first of 4000 radii outside (`_first_exits`), then
    bisection, for all rays at once."""
    radii = np.linspace(0.0, 8.0, 4001)[1:]
    d_all = np.asarray(directions, dtype=complex)
    first_all = _first_exits(tab, d_all, radii)
    out = np.empty(len(d_all))
    for lo in range(0, len(d_all), chunk):
        d, first = d_all[lo:lo + chunk], first_all[lo:lo + chunk]
        exits = first < len(radii)
        first = np.minimum(first, len(radii) - 1)
        low = np.where(first > 0, radii[np.maximum(first - 1, 0)], 0.0)
        high = radii[first]
        for _ in range(60):
            mid = 0.5 * (low + high)
            over = _outside(tab, mid * d)
            high, low = np.where(over, mid, high), np.where(over, low, mid)
        out[lo:lo + chunk] = np.where(exits, np.where(first > 0, low, 0.0), np.inf)
    return out


def _outside(tab: Tableau, z: np.ndarray) -> np.ndarray:
    """Whether |R(z)| > 1 + EXIT_TOL, as evaluated in floating point."""
    return np.abs(amplification(tab, z)) > 1 + EXIT_TOL


def _first_exits(tab: Tableau, d: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """For every direction, the index of the first radius where |R| > 1 + 1e-12 (len(radii)
    where there is none). Rays sorted by angle: where at least GROUP_MIN lie within
    GROUP_SPAN of each other (a population's modes), `_grouped_exits`; the rest `_scan`."""
    first = np.full(len(d), len(radii))
    order = np.argsort(np.angle(d), kind="stable")
    angle = np.angle(d)[order]
    alone: list[np.ndarray] = []
    lo = 0
    while lo < len(order):
        hi = int(np.searchsorted(angle, angle[lo] + GROUP_SPAN, side="right"))
        group = order[lo:hi]
        if len(group) >= GROUP_MIN:
            first[group] = _grouped_exits(tab, d[group], radii)
        else:
            alone.append(group)
        lo = hi
    if alone:
        rest = np.concatenate(alone)
        first[rest] = _scan(tab, d[rest], radii, np.zeros(len(rest), dtype=int))
    return first


def _scan(tab: Tableau, d: np.ndarray, radii: np.ndarray, start: np.ndarray,
          block: int = 250, chunk: int = 256) -> np.ndarray:
    """For every direction, the index of the first radius from its `start` on that is
    outside (len(radii) where none is): the radii in blocks, each evaluated only for the
    rays still inside, so a ray costs the radii up to its exit."""
    first = np.full(len(d), len(radii))
    for c in range(0, len(d), chunk):
        inside = np.arange(c, min(c + chunk, len(d)))
        for lo in range(int(start[inside].min(initial=len(radii))) // block * block,
                        len(radii), block):
            if not len(inside):
                break
            idx = np.arange(lo, min(lo + block, len(radii)))
            bad = _outside(tab, radii[None, idx] * d[inside, None])
            bad &= idx[None, :] >= start[inside, None]
            out = bad.any(axis=1)
            first[inside[out]] = lo + np.argmax(bad[out], axis=1)
            inside = inside[~out]
    return first


def _grouped_exits(tab: Tableau, d: np.ndarray, radii: np.ndarray, tries: int = 16,
                   chunk: int = 256) -> np.ndarray:
    """`_scan`'s first exits of rays close in angle, from one scan of their middle ray d0.

    Where d0 is inside by a margin m at radius t, another ray d is inside there too if
    m exceeds what moving z = t d0 to t d can change |R| by: at most |R'| on the chord
    (below sum_j j |r_j| t^(j-1)) times t |d - d0|, plus what rounding can change each
    evaluation by (below 1e-13 sum_j |r_j| t^j, tens of times a Horner sum's bound). A
    ray's first exit is then among the radii not so certified, which are evaluated in order
    (`tries` of them; a ray still undecided is scanned on from there): the same index as
    `_scan` gives it, at the cost of a few evaluations instead of thousands."""
    r = np.abs(stability_polynomial(tab))
    powers = np.arange(len(r))
    t = radii * (1 + 1e-12)
    size = np.polynomial.polynomial.polyval(t, r)
    slope = np.polynomial.polynomial.polyval(t, r[1:] * powers[1:])
    d0 = d[len(d) // 2]
    margin = 1 + EXIT_TOL - np.abs(amplification(tab, radii * d0)) - 2 * (1e-13 * size + 1e-15)
    reach = margin / (slope * t)  # the largest |d - d0| certified at each radius
    first = np.full(len(d), len(radii))
    for c in range(0, len(d), chunk):
        rows = np.arange(c, min(c + chunk, len(d)))
        delta = np.abs(d[rows] - d0) * (1 + 1e-12) + 1e-15
        open_ = reach[None, :] < delta[:, None]  # radii left to evaluate, per ray
        undecided = np.ones(len(rows), dtype=bool)
        for _ in range(tries):
            some = undecided & open_.any(axis=1)
            undecided &= some  # nothing left open: no exit (len(radii))
            if not some.any():
                break
            live = np.nonzero(some)[0]
            k = np.argmax(open_[live], axis=1)
            bad = _outside(tab, radii[k] * d[rows[live]])
            first[rows[live[bad]]] = k[bad]
            undecided[live[bad]] = False
            open_[live[~bad], k[~bad]] = False
        else:
            left = np.nonzero(undecided)[0]
            if len(left):
                start = np.argmax(open_[left], axis=1)
                first[rows[left]] = _scan(tab, d[rows[left]], radii, start)
    return first


def dt_max(net: FlatNetlist, method: str = DEFAULT_METHOD) -> float:
    """Largest stable step of `method` for the linearisation at rest (inf: nothing limits)."""
    return step_limit(modes(net), method).dt


def fastest_mode(net: FlatNetlist) -> Mode | None:
    """The mode with the largest |lambda| (None if there is none)."""
    found = modes(net)
    return found.mode(len(found) - 1) if len(found) else None
