"""Exponential splitting: small input-driven linear blocks exactly, the rest with Runge-Kutta.

The problem it solves (issue 7): the Mel filter pairs are linear, high-Q and fast (up to ~8 kHz
against a 32 kHz step, omega h ~ 1.6); classic RK4 damps and detunes them badly there, while the
rest of a keyword spotter (low-pass, delay lines, mvm block, readout) is slow. Scheme
`strang-rk4`, per step h (Strang splitting, second order in the coupling, exact in the blocks):

    blocks: z <- E(h/2) z + P0 u(t) + P1 u(t + h/2)              (exact, piecewise-linear input)
    rest:   one RK4 step of everything else, block positions frozen (their back-action moves
            their velocities; the rest sees them at mid-step)
    blocks: z <- E(h/2) z + P0 u(t + h/2) + P1 u(t + h)

A *block* is a connected component of the linear graph (couplings and node-to-node dashpots)
with at most `MAX_BLOCK` nodes, at least one `in(k)` force and no Duffing or `P` term on its
nodes: the driven linear filters. Its springs, couplings, dashpots, local damping and input
forces move into the exact propagator, for which the inputs' linear interpolation between
samples is exact (phi functions, computed with Van Loan's augmented matrix exponential).
Everything else, including quadratic couplings that touch a block, stays in the RK4 part. A
netlist without blocks gets plain RK4.

Schemes are data (`SplitScheme`); `generate` writes the kernel text (it reuses the force code
of `springc.codegen`), `split_netlist` and `block_arrays` prepare its arguments.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np
import scipy.linalg
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from springc import codegen
from springc.codegen import KernelOptions, _Code
from springc.errors import UsageError
from springc.integrators import Tableau, get_tableau
from springc.ir import GROUND, FlatNetlist

MAX_BLOCK = 4  # nodes: filter pairs are 2; larger components are chains or blocks, not filters


@dataclass(frozen=True)
class SplitScheme:
    """A splitting scheme: the blocks' exact flow for `half` of the step before and after one
    step of the explicit Runge-Kutta method `inner` on the rest (Strang: half = 0.5)."""

    name: str
    inner: str
    description: str
    half: float = 0.5

    @property
    def tableau(self) -> Tableau:
        return get_tableau(self.inner)


SCHEMES: dict[str, SplitScheme] = {
    s.name: s
    for s in [
        SplitScheme("strang-rk4", "rk4",
                    "Strang split: driven linear blocks exact (matrix exponential), rest RK4"),
    ]
}


def is_split(method: str) -> bool:
    """Whether `method` names a splitting scheme (not a plain tableau)."""
    return method in SCHEMES


@dataclass
class Blocks:
    """The exactly propagated blocks of a netlist: per block its node indices, its input force
    elements, the first-order matrix A (state [x; v] of the block) and the input matrix B
    (one column per input force, acceleration per unit input)."""

    nodes: list[np.ndarray]
    forces: list[np.ndarray]
    a: list[np.ndarray]
    b: list[np.ndarray]

    def __len__(self) -> int:
        return len(self.nodes)

    def node_set(self) -> np.ndarray:
        """All block nodes (sorted)."""
        if not self.nodes:
            return np.zeros(0, np.int64)
        return np.sort(np.concatenate(self.nodes))

    def eigenvalues(self) -> np.ndarray:
        """Eigenvalues of every block's A (the modes the split integrates exactly)."""
        if not self.a:
            return np.zeros(0, complex)
        return np.concatenate([np.linalg.eigvals(a) for a in self.a])


def find_blocks(net: FlatNetlist, max_size: int = MAX_BLOCK) -> Blocks:
    """The driven linear blocks of `net` (see the module docstring)."""
    labels = _linear_components(net)
    nonlinear = np.zeros(net.n, bool)
    nonlinear[net.duffings.node] = True
    nonlinear[net.monomials.var] = True
    driven = np.zeros(net.n, bool)
    inputs = [e for e, s in enumerate(net.forces.source) if s.kind == "in"]
    driven[net.forces.node[inputs]] = True
    found = Blocks([], [], [], [])
    for comp in np.unique(labels):
        nodes = np.flatnonzero(labels == comp)
        if len(nodes) > max_size or nonlinear[nodes].any() or not driven[nodes].any():
            continue
        forces = np.array([e for e in inputs if net.forces.node[e] in set(nodes)], np.int64)
        a, b = _block_system(net, nodes, forces)
        found.nodes.append(nodes)
        found.forces.append(forces)
        found.a.append(a)
        found.b.append(b)
    return found


def _linear_components(net: FlatNetlist) -> np.ndarray:
    """Component label per node of the graph of couplings and node-to-node dashpots."""
    c, d = net.couplings, net.dashpots
    keep = d.j != GROUND
    rows = np.concatenate([c.i, d.i[keep]]).astype(np.int64)
    cols = np.concatenate([c.j, d.j[keep]]).astype(np.int64)
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(net.n, net.n))
    return connected_components(graph, directed=False)[1]


def _block_system(net: FlatNetlist, nodes: np.ndarray,
                  forces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A (2m, 2m) and B (2m, forces) of the linear elements inside one block."""
    m = len(nodes)
    where = {int(g): k for k, g in enumerate(nodes)}
    stiff, damp = np.zeros((m, m)), np.zeros((m, m))
    s = net.springs
    for node, k in zip(s.node, s.k):
        if node in where:
            stiff[where[node], where[node]] += k
    c = net.couplings
    for i, j, k, a in zip(c.i, c.j, c.k, c.a):
        if i in where:  # potential k/(2a) (x_i - a x_j)^2
            p, q = where[i], where[j]
            stiff[np.ix_([p, q], [p, q])] += np.array([[k / a, -k], [-k, k * a]])
    d = net.dashpots
    for i, j, bb in zip(d.i, d.j, d.b):
        if i in where:
            p = where[i]
            damp[p, p] += bb
            if j != GROUND:
                q = where[j]
                damp[np.ix_([p, q], [p, q])] += np.array([[0.0, -bb], [-bb, bb]])
    damp[np.diag_indices(m)] += net.local_damping()[nodes]
    minv = 1.0 / net.mass()[nodes]
    a = np.zeros((2 * m, 2 * m))
    a[:m, m:] = np.eye(m)
    a[m:, :m] = -minv[:, None] * stiff
    a[m:, m:] = -minv[:, None] * damp
    b = np.zeros((2 * m, len(forces)))
    for col, e in enumerate(forces):
        b[m + where[int(net.forces.node[e])], col] = net.forces.gain[e] * minv[
            where[int(net.forces.node[e])]]
    return a, b


def propagator(a: np.ndarray, b: np.ndarray,
               tau: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact flow of z' = A z + B u(t) over `tau` for u linear from u0 to u1:
    z(tau) = E z0 + P0 u0 + P1 u1. Returns (E, P0, P1) (Van Loan's augmented exponential)."""
    n, k = b.shape
    big = np.zeros((n + 2 * k, n + 2 * k))
    big[:n, :n] = a
    big[:n, n:n + k] = b
    big[n:n + k, n + k:] = np.eye(k)
    full = scipy.linalg.expm(big * tau)
    e, f, g = full[:n, :n], full[:n, n:n + k], full[:n, n + k:]
    return e, f - g / tau, g / tau


def split_netlist(net: FlatNetlist, blocks: Blocks) -> FlatNetlist:
    """`net` without what the blocks integrate exactly: their springs, couplings, dashpots and
    local damping are removed and their input forces get gain 0 (kept, so the channel layout
    and the input array stay those of `net`). The kernel's force code on this netlist is the
    RK part of the split."""
    inside = np.zeros(net.n, bool)
    inside[blocks.node_set()] = True
    masses = replace(net.masses, b=np.where(inside[net.masses.node], 0.0, net.masses.b))
    gain = net.forces.gain.copy()
    if len(blocks):
        gain[np.concatenate(blocks.forces)] = 0.0
    return replace(
        net, masses=masses, forces=replace(net.forces, gain=gain),
        springs=_subset(net.springs, ~inside[net.springs.node]),
        couplings=_subset(net.couplings, ~inside[net.couplings.i]),
        dashpots=_subset(net.dashpots, ~inside[net.dashpots.i]),
    )


def _subset(table, keep: np.ndarray):
    """The rows of an element table where `keep` is true (arrays and name/location lists)."""
    out = {}
    for f in fields(table):
        value = getattr(table, f.name)
        if isinstance(value, np.ndarray):
            out[f.name] = value[keep]
        else:
            out[f.name] = [item for item, k in zip(value, keep) if k]
    return replace(table, **out)


BLOCK_ARGS = ("frz", "bk_ptr", "bk_node", "bk_eoff", "bk_e", "bk_fptr", "bk_fchan", "bk_poff",
              "bk_p0", "bk_p1")


def block_arrays(net: FlatNetlist, blocks: Blocks, h: float, scheme: SplitScheme,
                 dtype) -> dict[str, np.ndarray]:
    """The kernel's block arguments for step `h`: flattened per-block propagators E, P0, P1 of
    the partial step `scheme.half * h`, node lists and input channels, and the frozen-position
    mask `frz` of the RK part."""
    f = lambda a: np.ascontiguousarray(np.concatenate(a) if a else np.zeros(0), dtype=dtype)  # noqa
    i = lambda a: np.ascontiguousarray(a, dtype=np.int64)  # noqa: E731
    es, p0s, p1s, eoff, poff = [], [], [], [0], [0]
    for a, b in zip(blocks.a, blocks.b):
        e, p0, p1 = propagator(a, b, scheme.half * h)
        es.append(e.ravel())
        eoff.append(eoff[-1] + e.size)
        for col in range(b.shape[1]):
            p0s.append(p0[:, col])
            p1s.append(p1[:, col])
            poff.append(poff[-1] + a.shape[0])
    chans = [net.forces.source[e].channel for fs in blocks.forces for e in fs]
    frz = np.zeros(net.n, np.bool_)
    frz[blocks.node_set()] = True
    return {
        "frz": frz,
        "bk_ptr": i(np.cumsum([0] + [len(n) for n in blocks.nodes])),
        "bk_node": i(np.concatenate(blocks.nodes) if len(blocks) else []),
        "bk_eoff": i(eoff[:-1]), "bk_e": f(es),
        "bk_fptr": i(np.cumsum([0] + [len(fs) for fs in blocks.forces])),
        "bk_fchan": i(chans), "bk_poff": i(poff[:-1]), "bk_p0": f(p0s), "bk_p1": f(p1s),
    }


def run_args(feat: codegen.Features, opts: KernelOptions) -> list[str]:
    """Arguments of the generated split `run`: those of a Runge-Kutta kernel, then the blocks."""
    names = codegen.run_args(feat, opts)
    at = names.index("xf")
    return names[:at] + list(BLOCK_ARGS) + names[at:]


def generate(rest: FlatNetlist, options: KernelOptions) -> str:
    """Python source of the split kernel; `rest` is `split_netlist(net, blocks)` and
    `options.method` a scheme of `SCHEMES`. Input work and damper dissipation are not
    available (their forces are split between the two parts)."""
    scheme = SCHEMES[options.method]
    if options.work or options.dissipation:
        raise UsageError(f"{scheme.name} does not accumulate input work or dissipation; "
                         "use a Runge-Kutta method for work:/dissipated:/loss: reductions")
    feat = codegen.features(rest)
    tab = scheme.tableau
    c = _Code()
    c('"""Generated by springc.expint; see the header. Arrays are (n_dof, batch)."""')
    c("import numpy as np")
    c("import numba as nb")
    c("")
    c(f"FT = np.{options.precision}")
    c(f"ARGS = {tuple(run_args(feat, options))!r}")
    c(f"STAGES = {tab.stages}")
    c(f"MAX_BLOCK = {MAX_BLOCK}")
    c("")
    codegen._emit_accel(c, feat)
    c("")
    _emit_blocks(c)
    c("")
    _emit_run(c, feat, options, tab)
    body = c.text()
    header = [
        "# springc generated kernel: do not edit (regenerated from the netlist)",
        f"# netlist: {rest.file}",
        f"# title: {rest.title}",
        f"# options: {options}",
        f"# integrator: {scheme.name} ({scheme.description}; inner {tab.name})",
        f"# dofs: {rest.n}; elements of the Runge-Kutta part: {rest.element_counts()}",
        f"# body-hash: {codegen.source_hash(body)}",
        "",
    ]
    return "\n".join(header) + body


def _emit_blocks(c: _Code) -> None:
    c('@nb.njit(cache=True, error_model="numpy", nogil=True)')
    c("def blocks(x, v, zt, zn, ua, ub, bk_ptr, bk_node, bk_eoff, bk_e, bk_fptr, bk_fchan, "
      "bk_poff, bk_p0, bk_p1):")
    c.indent()
    c('"""Exact partial step of every block: z <- E z + P0 ua + P1 ub (z = [x; v] of it)."""')
    c("nb_ = x.shape[1]")
    c("for q in range(bk_ptr.shape[0] - 1):")
    c.indent()
    c("lo = bk_ptr[q]")
    c("m = bk_ptr[q + 1] - lo")
    c("m2 = 2 * m")
    c("for r in range(m):")
    c("    xr = x[bk_node[lo + r]]")
    c("    vr = v[bk_node[lo + r]]")
    c("    for b in range(nb_):")
    c("        zt[r, b] = xr[b]")
    c("        zt[m + r, b] = vr[b]")
    c("eo = bk_eoff[q]")
    c("for r in range(m2):")
    c("    zr = zn[r]")
    c("    for b in range(nb_):")
    c("        zr[b] = 0.0")
    c("    for k in range(m2):")
    c("        e = bk_e[eo + r * m2 + k]")
    c("        zk = zt[k]")
    c("        for b in range(nb_):")
    c("            zr[b] += e * zk[b]")
    c("for f in range(bk_fptr[q], bk_fptr[q + 1]):")
    c("    ch = bk_fchan[f]")
    c("    po = bk_poff[f]")
    c("    for r in range(m2):")
    c("        p0 = bk_p0[po + r]")
    c("        p1 = bk_p1[po + r]")
    c("        zr = zn[r]")
    c("        for b in range(nb_):")
    c("            zr[b] += p0 * ua[ch, b] + p1 * ub[ch, b]")
    c("for r in range(m):")
    c("    xr = x[bk_node[lo + r]]")
    c("    vr = v[bk_node[lo + r]]")
    c("    for b in range(nb_):")
    c("        xr[b] = zn[r, b]")
    c("        vr[b] = zn[m + r, b]")
    c.dedent(2)


def _emit_interp(c: _Code, target: str, pos: str) -> None:
    """Linear interpolation of the input samples at input-grid position k0 + `pos`."""
    c(f"pos = {pos}")
    c("kk = k0 + int(pos)")
    c("fr = FT(pos - int(pos))")
    c("for ch in range(nch):")
    c("    for b in range(nb_):")
    c(f"        {target}[ch, b] = (FT(1.0) - fr) * u[lo_ + b, ch, kk] "
      "+ fr * u[lo_ + b, ch, kk + 1]")


def _emit_run(c: _Code, feat: codegen.Features, opts: KernelOptions, tab: Tableau) -> None:
    scheme = SCHEMES[opts.method]
    acc_args = ", ".join(codegen.accel_args(feat))
    bk_args = ", ".join(BLOCK_ARGS[1:])
    c('@nb.njit(parallel=True, cache=True, error_model="numpy")')
    c(f"def run({', '.join(run_args(feat, opts))}):")
    c.indent()
    c('"""Integrate every run (columns of x0) for nsteps split steps of h."""')
    c("n, runs = x0.shape")
    c("nch = u.shape[1]")
    c("nchunks = (runs + chunk - 1) // chunk")
    codegen._emit_coefficients(c, tab)
    c("for ci in nb.prange(nchunks):")
    c.indent()
    c("lo_ = ci * chunk")
    c("nb_ = min(runs, lo_ + chunk) - lo_")
    for name in ["x", "v", "xs"] + [f"kv{s}" for s in range(tab.stages)] + \
            [f"vs{s}" for s in range(1, tab.stages)]:
        c(f"{name} = np.empty((n, nb_), FT)")
    c("zt = np.empty((2 * MAX_BLOCK, nb_), FT)")
    c("zn = np.empty((2 * MAX_BLOCK, nb_), FT)")
    for name in ("uc", "ua", "um", "ub"):
        c(f"{name} = np.zeros((max(nch, 1), nb_), FT)")
    c("for i in range(n):")
    c("    for b in range(nb_):")
    c("        x[i, b] = x0[i, lo_ + b]")
    c("        v[i, b] = v0[i, lo_ + b]")
    codegen._emit_reduction_init(c, opts)
    if opts.record:
        c("for p in range(rec_node.shape[0]):")
        c("    for b in range(nb_):")
        c("        rec[p, lo_ + b, 0] = v[rec_node[p], b] if rec_isv[p] else x[rec_node[p], b]")
    c("for step in range(nsteps):")
    c.indent()
    c("sub = step % substeps")
    c("k0 = step // substeps")
    _emit_interp(c, "ua", "sub / substeps")
    _emit_interp(c, "um", f"(sub + {scheme.half!r}) / substeps")
    _emit_interp(c, "ub", "(sub + 1.0) / substeps")
    c(f"blocks(x, v, zt, zn, ua, um, {bk_args})")
    for s in range(tab.stages):
        _emit_stage(c, feat, tab, s, acc_args)
    _emit_combine(c, tab)
    c(f"blocks(x, v, zt, zn, um, ub, {bk_args})")
    codegen._emit_step_end(c, opts)
    c.dedent()
    c("for i in range(n):")
    c("    for b in range(nb_):")
    c("        xf[i, lo_ + b] = x[i, b]")
    c("        vf[i, lo_ + b] = v[i, b]")
    codegen._emit_reduction_store(c, opts)
    c.dedent(2)


def _emit_stage(c: _Code, feat: codegen.Features, tab: Tableau, s: int, acc_args: str) -> None:
    """One Runge-Kutta stage of the rest; block positions stay frozen (their flow is exact)."""
    c(f"# stage {s}: c = {tab.c[s]!r}")
    row = [j for j, a in enumerate(tab.a[s]) if a != 0.0]
    vel = lambda j: "v" if j == 0 else f"vs{j}"  # noqa: E731
    if s == 0:
        xs_name = "x"
    else:
        xs_name = "xs"
        xterm = " + ".join(f"ha{s}_{j} * {vel(j)}[i, b]" for j in row) or "0.0"
        vterm = " + ".join(f"ha{s}_{j} * kv{j}[i, b]" for j in row) or "0.0"
        c("for i in range(n):")
        c("    if frz[i]:")
        c("        for b in range(nb_):")
        c("            xs[i, b] = x[i, b]")
        c("    else:")
        c("        for b in range(nb_):")
        c(f"            xs[i, b] = x[i, b] + {xterm}")
        c("    for b in range(nb_):")
        c(f"        vs{s}[i, b] = v[i, b] + {vterm}")
    if feat.in_forces:
        _emit_interp(c, "uc", f"(sub + {tab.c[s]!r}) / substeps")
    grow = f"g[step, {s}]" if feat.common_forces else "g[0, 0]"
    c(f"accel({xs_name}, {vel(s)}, kv{s}, uc, {grow}, {acc_args})")


def _emit_combine(c: _Code, tab: Tableau) -> None:
    vel = lambda j: "v" if j == 0 else f"vs{j}"  # noqa: E731
    xterm = " + ".join(f"hb{s} * {vel(s)}[i, b]" for s, b in enumerate(tab.b) if b != 0.0)
    vterm = " + ".join(f"hb{s} * kv{s}[i, b]" for s, b in enumerate(tab.b) if b != 0.0)
    c("for i in range(n):")
    c("    if not frz[i]:")
    c("        for b in range(nb_):")
    c(f"            x[i, b] += {xterm}")
    c("    for b in range(nb_):")
    c(f"        v[i, b] += {vterm}")
