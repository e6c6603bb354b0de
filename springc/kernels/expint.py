"""Exponential kernels: the input-driven linear blocks of a netlist exactly, the rest with
Runge-Kutta (for high-Q filters that RK4 at the input rate damps and detunes).

A *block* is a connected component of the linear graph (couplings, node-to-node dashpots) of
at most `MAX_BLOCK` nodes with an `in(k)` force and no Duffing or `P` term: a driven linear
filter. Its linear terms and inputs move into an exact propagator (phi functions by Van
Loan's augmented exponential, exact for the linearly interpolated input); everything else,
quadratic couplings into a block included, stays in the Runge-Kutta part. Schemes are data
(`SplitScheme`, `SCHEMES`): `strang-rk4` (Strang splitting: half a block step, an RK4 step of
the rest with block positions frozen, half a block step) and the Lawson schemes `exp-rk4`,
`exp-heun3` (every stage sees the blocks' exact flow to its own time, `lawson_fractions`).
`kernel_source` writes the kernel text (`generate`, `generate_lawson`), reusing
`springc.kernels.codegen`'s force code; `split_netlist` and `scheme_arrays` prepare its
arguments. A netlist without blocks gets plain RK4. Why exp-heun3:
docs/performance.md#why-exp-heun3.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

from springc.kernels import codegen, thermal
from springc.kernels.codegen import KernelOptions, _Code
from springc.errors import UsageError
from springc.kernels.integrators import Tableau, get_tableau
from springc.kernels.lower import kernel_netlist
from springc.kernels.terms import lane_array
from springc.lang.ir import GROUND, FlatNetlist

MAX_BLOCK = 4  # nodes: filter pairs are 2; larger components are chains or blocks, not filters


@dataclass(frozen=True)
class SplitScheme:
    """A scheme treating the blocks exactly and the rest with the explicit Runge-Kutta method
    `inner`. kind 'strang': the blocks' exact flow for `half` of the step before and after one
    step of `inner` on the rest (block positions frozen in it). kind 'lawson': the integrating
    factor form of `inner` (exponential Runge-Kutta of Lawson type): every stage sees the
    blocks' exact driven flow to its stage time, plus their back-action carried by it."""

    name: str
    inner: str
    description: str
    kind: str = "strang"
    half: float = 0.5

    @property
    def tableau(self) -> Tableau:
        return get_tableau(self.inner)


SCHEMES: dict[str, SplitScheme] = {
    s.name: s
    for s in [
        SplitScheme("strang-rk4", "rk4",
                    "Strang split: driven linear blocks exact (matrix exponential), rest RK4"),
        SplitScheme("exp-rk4", "rk4", "Lawson exponential RK4: driven linear blocks exact "
                    "at every stage (matrix exponential), rest RK4", kind="lawson"),
        SplitScheme("exp-heun3", "heun3", "Lawson exponential Heun3: driven linear blocks "
                    "exact at every stage (matrix exponential), rest Heun's third-order "
                    "Runge-Kutta (three stages)", kind="lawson"),
    ]
}


def is_split(method: str) -> bool:
    """Whether `method` names a splitting scheme (not a plain tableau)."""
    return method in SCHEMES


def stage_tableau(method: str) -> Tableau:
    """The tableau whose stage times the kernel of `method` evaluates forces at."""
    return SCHEMES[method].tableau if is_split(method) else get_tableau(method)


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
    """The driven linear blocks of `net` (see the module docstring), of its kernel netlist
    (`springc.kernels.lower`: a node whose only nonlinearity is a P x^2 is linear)."""
    net = kernel_netlist(net)
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
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

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
    z(tau) = E z0 + P0 u0 + P1 u1. Returns (E, P0, P1) (Van Loan's augmented exponential;
    B is scaled to unit norm first, as the result is linear in it and its scale, 1e9 for
    the Mel filters, would otherwise set the number of squarings)."""
    n, k = b.shape
    scale = float(np.abs(b).max()) or 1.0
    big = np.zeros((n + 2 * k, n + 2 * k))
    big[:n, :n] = a
    big[:n, n:n + k] = b / scale
    big[n:n + k, n + k:] = np.eye(k)
    full = expm_small(big * tau)
    e, f, g = full[:n, :n], full[:n, n:n + k] * scale, full[:n, n + k:] * scale
    return e, f - g / tau, g / tau


def expm_small(m: np.ndarray) -> np.ndarray:
    """exp(m) for a small dense matrix: scaling and squaring of a degree-20 Taylor series
    (after scaling the 1-norm is at most 1/2, where the series' truncation is below 1e-25).
    Used instead of scipy's Pade code, whose LAPACK calls are slow for these 6x6 to 12x12
    matrices on a busy machine."""
    import scipy.linalg

    # balance first (diagonal similarity): the filters' omega^2 against 1 in [x; v] would
    # otherwise cost ~16 squarings and 1e-12 per step; balanced, omega h needs one or two
    _, (scale, _) = scipy.linalg.matrix_balance(m, permute=False, separate=True)
    m = m / scale[:, None] * scale[None, :]
    norm = float(np.abs(m).sum(axis=0).max())
    squarings = max(0, int(np.ceil(np.log2(norm))) + 1) if norm > 0 else 0
    x = m / 2.0**squarings
    out = np.eye(len(m))
    term = np.eye(len(m))
    for j in range(1, 21):
        term = term @ x / j
        out = out + term
    for _ in range(squarings):
        out = out @ out
    return out * scale[:, None] / scale[None, :]


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

    def f(a):
        return np.ascontiguousarray(np.concatenate(a) if a else np.zeros(0), dtype=dtype)

    def i(a):
        return np.ascontiguousarray(a, dtype=np.int64)

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


def _refuse_work(scheme: SplitScheme, options: KernelOptions) -> None:
    if options.work or options.dissipation:
        raise UsageError(f"{scheme.name} does not accumulate input work or dissipation; "
                         "use a Runge-Kutta method or a Lawson scheme (exp-rk4, exp-heun3) "
                         "for work:/dissipated:/loss: reductions")


def _header(rest: FlatNetlist, options: KernelOptions, scheme: SplitScheme, tab: Tableau,
            body: str, extra: list[str] = ()) -> str:
    header = [
        "# springc generated kernel: do not edit (regenerated from the netlist)",
        f"# netlist: {rest.file}",
        f"# title: {rest.title}",
        *codegen.options_header(options),
        f"# integrator: {scheme.name} ({scheme.description}; inner {tab.name})",
        *extra,
        f"# dofs: {rest.n}; elements of the Runge-Kutta part: {rest.element_counts()}",
        f"# body-hash: {codegen.source_hash(body)}",
        "",
    ]
    return "\n".join(header) + body


def generate(rest: FlatNetlist, options: KernelOptions) -> str:
    """Python source of the split kernel; `rest` is `split_netlist(net, blocks)` and
    `options.method` a scheme of `SCHEMES`. Input work and damper dissipation are not
    available (their forces are split between the two parts)."""
    scheme = SCHEMES[options.method]
    _refuse_work(scheme, options)
    feat = codegen.features(rest)
    tab = scheme.tableau
    c = _Code()
    c('"""Generated by springc.kernels.expint; see the header. Arrays are (n_dof, lanes)."""')
    codegen.preamble(c, options, run_args(feat, options), tab.stages)
    c(f"MAX_BLOCK = {MAX_BLOCK}")
    c("")
    if feat.thermal:
        thermal.emit_helpers(c, codegen.decorator(fma=options.fma))
    _emit_blocks(c, options.fma)
    c("")
    _emit_run(c, feat, options, tab)
    return _header(rest, options, scheme, tab, c.text())


def _emit_blocks(c: _Code, fma: bool) -> None:
    c(codegen.decorator(fma=fma))
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
    c("    xr = bk_node[lo + r]")
    c("    for b in range(nb_):")
    c("        zt[r, b] = x[xr, b]")
    c("        zt[m + r, b] = v[xr, b]")
    c("eo = bk_eoff[q]")
    c("for r in range(m2):")
    c("    for b in range(nb_):")
    c("        zn[r, b] = 0.0")
    c("    for k in range(m2):")
    c("        e = bk_e[eo + r * m2 + k]")
    c("        for b in range(nb_):")
    c("            zn[r, b] += e * zt[k, b]")
    c("for f in range(bk_fptr[q], bk_fptr[q + 1]):")
    c("    ch = bk_fchan[f]")
    c("    po = bk_poff[f]")
    c("    for r in range(m2):")
    c("        p0 = bk_p0[po + r]")
    c("        p1 = bk_p1[po + r]")
    c("        for b in range(nb_):")
    c("            zn[r, b] += p0 * ua[ch, b] + p1 * ub[ch, b]")
    c("for r in range(m):")
    c("    xr = bk_node[lo + r]")
    c("    for b in range(nb_):")
    c("        x[xr, b] = zn[r, b]")
    c("        v[xr, b] = zn[m + r, b]")
    c.dedent(2)


def _emit_run(c: _Code, feat: codegen.Features, opts: KernelOptions, tab: Tableau) -> None:
    scheme = SCHEMES[opts.method]
    ln = codegen.lane_layout(opts)
    bk_args = ", ".join(BLOCK_ARGS[1:])
    codegen.emit_def(c, run_args(feat, opts), "nsteps split steps", fma=opts.fma)
    codegen.emit_coefficients(c, tab)
    codegen.emit_nystrom_coefficients(c, tab)
    codegen.velocity_needed(c, feat, opts)
    c("for ci in range(c0, c1):")
    c.indent()
    codegen.emit_chunk_start(c, opts, ["xs", "vs"] + [f"kv{s}" for s in range(tab.stages)])
    if feat.thermal:
        thermal.emit_chunk_init(c)
    c("zt = np.empty((2 * MAX_BLOCK, LANES), FT)")
    c("zn = np.empty((2 * MAX_BLOCK, LANES), FT)")
    for name in ("ua", "um", "ub"):
        c(f"{name} = np.zeros((max(nch, 1), LANES), FT)")
    c("for step in range(nsteps):")
    c.indent()
    codegen.emit_step_start(c, True)
    if feat.thermal:
        thermal.emit_draw(c, opts.per_run)
    codegen.emit_interp(c, "ua", "sub / substeps", ln)
    codegen.emit_interp(c, "um", f"(sub + {scheme.half!r}) / substeps", ln)
    codegen.emit_interp(c, "ub", "(sub + 1.0) / substeps", ln)
    c(f"blocks(x, v, zt, zn, ua, um, {bk_args})")

    def prelude(s: int | None) -> None:
        # one Runge-Kutta stage of the rest; block positions stay frozen (exact flow)
        if s != 0:
            codegen.nystrom_stage_state(c, tab, s, ln, frozen="hold")
        if feat.in_forces:
            codegen.emit_stage_input(c, tab, s, ln)

    codegen.emit_stage_loop(c, feat, tab, ln, prelude, per_run=opts.per_run)
    codegen.nystrom_combine(c, tab, ln, frozen="hold")
    c(f"blocks(x, v, zt, zn, um, ub, {bk_args})")
    codegen.emit_step_end(c, opts, ln)
    c.dedent()
    codegen.emit_chunk_end(c, opts)
    c.dedent(2)


# --- Lawson (integrating factor) scheme -------------------------------------------------
#
# With E(t) the blocks' exact flow matrix and q(t) their exact response to the input from
# rest over t, stage i and the step of the tableau (a, b, c) read, for the blocks' state z:
#     z_i     = E(c_i h) z_n + q(c_i h) + h sum_j a_ij E((c_i - c_j) h) N_j
#     z_{n+1} = E(h) z_n + q(h) + h sum_j b_j E((1 - c_j) h) N_j
# where N_j is the rest's force on the blocks at stage j (it moves only velocities). The rest
# takes ordinary Runge-Kutta stages. Blocks of equal size share one unrolled loop.


def lawson_fractions(tab: Tableau) -> tuple[list[float], list[float]]:
    """(fractions of h whose E and q the scheme needs, fractions where it reads the input)."""
    need = set(tab.c) | {1.0}
    for i, row in enumerate(tab.a):
        need |= {tab.c[i] - tab.c[j] for j, a in enumerate(row) if a != 0.0}
    need |= {1.0 - tab.c[j] for j, b in enumerate(tab.b) if b != 0.0}
    return sorted(need - {0.0}), sorted(set(tab.c) | {0.0, 1.0})


def lawson_arrays(net: FlatNetlist, blocks: Blocks, h: float, tab: Tableau,
                  dtype) -> dict[str, np.ndarray]:
    """Per block size m: node table (Q, m), E (Q, F, 2m, 2m), P0 and P1 (Q, F, 2m, channels)
    for the fractions F of `lawson_fractions`; and the frozen-row mask `frz`."""
    fracs, _ = lawson_fractions(tab)
    nch = block_channels(net, blocks)
    out: dict[str, np.ndarray] = {}
    for m in block_sizes(blocks):
        idx = [q for q, nodes in enumerate(blocks.nodes) if len(nodes) == m]
        e = np.zeros((len(idx), len(fracs), 2 * m, 2 * m))
        p0 = np.zeros((len(idx), len(fracs), 2 * m, nch))
        p1 = np.zeros_like(p0)
        for row, q in enumerate(idx):
            chans = [net.forces.source[f].channel for f in blocks.forces[q]]
            for k, frac in enumerate(fracs):
                ek, a0, a1 = propagator(blocks.a[q], blocks.b[q], frac * h)
                e[row, k] = ek
                for col, ch in enumerate(chans):  # forces on one channel add
                    p0[row, k, :, ch] += a0[:, col]
                    p1[row, k, :, ch] += a1[:, col]
        out[f"lw{m}_node"] = np.array([blocks.nodes[q] for q in idx], np.uint64).reshape(-1, m)
        out[f"lw{m}_e"], out[f"lw{m}_p0"], out[f"lw{m}_p1"] = (
            np.ascontiguousarray(a, dtype=dtype) for a in (e, p0, p1))
    frz = np.zeros(net.n, np.bool_)
    frz[blocks.node_set()] = True
    out["frz"] = frz
    return out


def block_channels(net: FlatNetlist, blocks: Blocks) -> int:
    """The input channels the blocks' propagators take (their largest channel + 1)."""
    return max(1, max((net.forces.source[e].channel for fs in blocks.forces for e in fs),
                      default=0) + 1)


def block_sizes(blocks: Blocks) -> list[int]:
    """The distinct block sizes (nodes), ascending."""
    return sorted({len(n) for n in blocks.nodes})


def lawson_args(feat: codegen.Features, opts: KernelOptions, sizes: list[int]) -> list[str]:
    names = codegen.run_args(feat, opts)
    at = names.index("xf")
    extra = ["frz"] + [f"lw{m}_{k}" for m in sizes for k in ("node", "e", "p0", "p1")]
    extra += ["fi_w"] if opts.work and feat.in_forces else []
    return names[:at] + extra + names[at:]


def generate_lawson(rest: FlatNetlist, options: KernelOptions, sizes: list[int],
                    nch: int) -> str:
    """Kernel source of a 'lawson' scheme for the Runge-Kutta part `rest` and blocks of the
    given sizes driven by `nch` input channels."""
    scheme = SCHEMES[options.method]
    feat = codegen.features(rest)
    tab = scheme.tableau
    fracs, ufracs = lawson_fractions(tab)
    ln = codegen.lane_layout(options)
    c = _Code()
    c('"""Generated by springc.kernels.expint (Lawson scheme); see the header. Arrays are '
      '(n_dof, lanes)."""')
    codegen.preamble(c, options, lawson_args(feat, options, sizes), tab.stages)
    c("")
    if feat.thermal:
        thermal.emit_helpers(c, codegen.decorator(fma=options.fma))
    lw = _Lawson(tab, fracs, ufracs, sizes, max(nch, 1), ln, frozenset(options.per_run))
    _emit_lawson_run(c, feat, options, tab, lw)
    return _header(rest, options, scheme, tab, c.text(),
                   [f"# blocks of sizes {sizes}; input channels {nch}"])


@dataclass(frozen=True)
class _Term:
    """One stage force in a block's flow: E at `fraction` (an index expression; None: the
    identity, the stage at the same time) times h w (`weight`) times its forces `kv` on the
    block's nodes; `j` names its variables."""

    j: str
    kv: str
    weight: str
    fraction: str | None


@dataclass(frozen=True)
class _BlockStep:
    """A block's flow to a stage from the step's start: the free flow E, P0, P1 at fraction
    index `f0` (an expression), the input at the stage's time (`input`, a row array), the
    stage forces' terms."""

    f0: str
    input: str
    terms: list[_Term]


@dataclass
class _Lawson:
    """Emits the unrolled block updates of a Lawson scheme."""

    tab: Tableau
    fracs: list[float]
    ufracs: list[float]
    sizes: list[int]
    nch: int
    ln: codegen.LaneLayout
    per_run: frozenset[str] = frozenset()  # the propagators read per lane (KernelOptions.per_run)

    def fi(self, frac: float) -> int:
        return self.fracs.index(frac)

    def step(self, stage: int | None) -> _BlockStep:
        """The flow to stage `stage` (None: to the step's end) from the step's start."""
        frac = 1.0 if stage is None else self.tab.c[stage]
        weights = self.tab.b if stage is None else self.tab.a[stage]
        if frac not in self.ufracs:
            raise ValueError(f"tableau stage time {frac} is not an input fraction")
        terms = [_Term(str(j), f"kv{j}", f"FT(hh * {w!r})",
                       str(self.fi(frac - self.tab.c[j])) if frac != self.tab.c[j] else None)
                 for j, w in enumerate(weights) if w != 0.0]
        return _BlockStep(str(self.fi(frac)), f"ut{self.ufracs.index(frac)}", terms)

    def _uniform_terms(self) -> list[tuple[int, int]]:
        """(stage, the one force stage it reads) for every stage after the first, under
        `codegen.uniform_stages`."""
        return [(s, codegen.stage_reads(self.tab, s)[0][0]) for s in range(1, self.tab.stages)]

    def emit_tables(self, c: _Code) -> None:
        """Per stage of `codegen.uniform_stages` (index s_; stage 0's entries unused): its
        free flow's fraction index `lf_`, its input row `lu_`, its term's weight `lw_` and
        the fraction index of the term's E `lg_` (-1: the identity, a term at the stage's own
        time)."""
        f, u, w, g = ["0"], ["0"], ["FT(0.0)"], ["0"]
        for s, j in self._uniform_terms():
            cs = self.tab.c[s]
            f.append(str(self.fi(cs)))
            u.append(str(self.ufracs.index(cs)))
            w.append(f"FT(hh * {self.tab.a[s][j]!r})")
            g.append(str(self.fi(cs - self.tab.c[j])) if cs != self.tab.c[j] else "-1")
        for name, values in (("lf_", f), ("lu_", u), ("lw_", w), ("lg_", g)):
            c(f"{name} = ({', '.join(values)},)")

    def emit_inline(self, c: _Code, stage: int | None, xo: str, vo: str | None) -> None:
        """The blocks' state at this stage (or step end) into their rows of `xo`, `vo` (the
        positions alone when `vo` is None), written in place in the step (a call would pass a
        dozen arrays per stage)."""
        for m in self.sizes:
            self._emit_size(c, self.step(stage), m, xo, vo)

    def emit_uniform(self, c: _Code, xo: str, vo: str | None) -> None:
        """`emit_inline` for the stage s_ of `codegen.uniform_stages` (its tables
        `emit_tables`; its force stage `kvv_`, `codegen.nystrom_stage_state`)."""
        if not self.sizes:  # no blocks: nothing to propagate
            return
        c("ub_ = uts_[lu_[s_]]")
        c("lfs_ = lf_[s_]")  # plain names: an index expression holds no brackets
        c("lgs_ = lg_[s_]")
        identity = {self.tab.c[s] == self.tab.c[j] for s, j in self._uniform_terms()}
        # a term at the stage's own time adds its kick alone: no multiply by E(0) = I
        for k, same in enumerate(sorted(identity, reverse=True)):
            if len(identity) > 1:
                c("if lgs_ < 0:" if k == 0 else "else:")
                c.indent()
            step = _BlockStep("lfs_", "ub_",
                              [_Term("v", "kvv_", "lw_[s_]", None if same else "lgs_")])
            for m in self.sizes:
                self._emit_size(c, step, m, xo, vo)
            if len(identity) > 1:
                c.dedent()

    def _emit_propagators(self, c: _Code, m: int, rows: int, step: _BlockStep
                          ) -> tuple[dict[str, str], list[str]]:
        """Block q's propagator entries for the free flow and each term's E: the name each
        is read by, and the per-lane loads. An entry of an array
        that differs between a population's points (`per_run`) is read per lane from its
        chunk copy (`codegen.emit_lane_coefficients`, named `<entry>_{b}`), the others once
        per block here."""
        name: dict[str, str] = {}
        lane_loads: list[str] = []
        starts: dict[tuple[str, str], str] = {}
        width = self.ln.width

        def load(var: str, array: str, frac: str, r: int, k: int, cols: int) -> None:
            if array not in self.per_run:
                name[var] = var
                c(f"{var} = {array}[q, {frac}, {r}, {k}]")
                return
            # the chunk's copy is flat (`codegen.emit_lane_coefficients`): one index a read,
            # not five (numba types and lowers each index of a subscript apart)
            if (array, frac) not in starts:
                starts[array, frac] = f"ps{len(starts)}_"
                c(f"{starts[array, frac]} = (q * {len(self.fracs)} + {frac}) * "
                  f"{2 * m * cols * width}")
            name[var] = f"{var}_{{b}}"
            entry = (r * cols + k) * width
            lane_loads.append(f"{var}_{{b}} = {lane_array(array)}"
                              f"[{starts[array, frac]} + ({entry} + {{b}})]")

        f0 = step.f0
        for r in range(rows):
            for k in range(2 * m):
                load(f"e{r}_{k}", f"lw{m}_e", f0, r, k, 2 * m)
            for ch in range(self.nch):
                load(f"pa{r}_{ch}", f"lw{m}_p0", f0, r, ch, self.nch)
                load(f"pb{r}_{ch}", f"lw{m}_p1", f0, r, ch, self.nch)
        for t in step.terms:
            c(f"hw{t.j} = {t.weight}")  # FT: a float64 here would promote the lanes
            if t.fraction is not None:
                for r in range(rows):
                    for k in range(m):
                        load(f"g{t.j}_{r}_{k}", f"lw{m}_e", t.fraction, r, m + k, 2 * m)
        return name, lane_loads

    def _emit_size(self, c: _Code, step: _BlockStep, m: int, xo: str, vo: str | None
                   ) -> None:
        terms = step.terms
        n2 = 2 * m
        rows = n2 if vo else m  # output rows: positions, then velocities
        c(f"for q in range(lw{m}_node.shape[0]):")
        c.indent()
        for r in range(m):
            c(f"i{r} = lw{m}_node[q, {r}]")
        name, lane_loads = self._emit_propagators(c, m, rows, step)
        loads = []
        for r in range(m):
            loads += [f"Z{r}_{{b}} = x[i{r}, {{b}}]", f"Z{m + r}_{{b}} = v[i{r}, {{b}}]"]
            loads += [f"N{t.j}_{r}_{{b}} = {t.kv}[i{r}, {{b}}]" for t in terms]
        for ch in range(self.nch):
            loads += [f"UA{ch}_{{b}} = ut0[{ch}, {{b}}]",
                      f"UB{ch}_{{b}} = {step.input}[{ch}, {{b}}]"]
        loads += lane_loads
        arith = [f"S{t.j}_{r}_{{b}} = hw{t.j} * N{t.j}_{r}_{{b}}" for t in terms
                 for r in range(m)]
        for r in range(rows):
            parts = [f"{name[f'e{r}_{k}']} * Z{k}_{{b}}" for k in range(n2)]
            parts += [f"{name[f'pa{r}_{ch}']} * UA{ch}_{{b}} + {name[f'pb{r}_{ch}']} * UB{ch}_{{b}}"
                      for ch in range(self.nch)]
            for t in terms:
                if t.fraction is not None:
                    parts += [f"{name[f'g{t.j}_{r}_{k}']} * S{t.j}_{k}_{{b}}" for k in range(m)]
                elif r >= m:
                    parts.append(f"S{t.j}_{r - m}_{{b}}")
            arith.append(f"O{r}_{{b}} = {' + '.join(parts)}")
        stores = [f"{xo}[i{r}, {{b}}] = O{r}_{{b}}" for r in range(m)]
        stores += [f"{vo}[i{r}, {{b}}] = O{m + r}_{{b}}" for r in range(m) if vo]
        codegen.lanes(c, self.ln, loads, arith, stores, own_arith=True)
        c.dedent()


def _emit_lawson_run(c: _Code, feat: codegen.Features, opts: KernelOptions, tab: Tableau,
                     lw: _Lawson) -> None:
    codegen.emit_def(c, lawson_args(feat, opts, lw.sizes), "nsteps exponential RK steps of h",
                     fma=opts.fma)
    codegen.emit_coefficients(c, tab)
    codegen.emit_nystrom_coefficients(c, tab)
    if opts.work or opts.dissipation:
        codegen.emit_stage_weights(c, tab)
    codegen.velocity_needed(c, feat, opts)
    c("hh = FT(h)")
    uniform = codegen.uniform_stages(tab)
    if uniform:
        lw.emit_tables(c)
    c("for ci in range(c0, c1):")
    c.indent()
    codegen.emit_chunk_start(c, opts, ["xs", "vs", "xn", "vn"]
                             + [f"kv{s}" for s in range(tab.stages)])
    if feat.thermal:
        thermal.emit_chunk_init(c)
    for k in range(len(lw.ufracs)):  # every channel: the rest's forces read them too
        c(f"ut{k} = np.zeros((max(nch, {lw.nch}), LANES), FT)")
    if uniform:
        c(f"uts_ = ({', '.join(f'ut{k}' for k in range(len(lw.ufracs)))},)")
    c("for step in range(nsteps):")
    c.indent()
    codegen.emit_step_start(c, True)
    if feat.thermal:
        thermal.emit_draw(c, opts.per_run)
    for k, frac in enumerate(lw.ufracs):
        codegen.emit_interp(c, f"ut{k}", f"(sub + {frac!r}) / substeps", lw.ln)
    power = opts.work or opts.dissipation
    def prelude(s: int | None) -> None:
        if s is None:  # the stage s_ of the tables
            codegen.nystrom_stage_state(c, tab, None, lw.ln, frozen="skip")
            lw.emit_uniform(c, "xs", "vs" if power else None)
            if feat.in_forces:
                c("uc = uts_[lu_[s_]]")
            return
        if s > 0:
            codegen.nystrom_stage_state(c, tab, s, lw.ln, frozen="skip")
            # the blocks' stage positions: nothing in the rest reads a block node's velocity
            # (`split_netlist` moves their damping and dashpots into the blocks, and the rest's
            # zero damping on them multiplies their rows of vs); the work and dissipation
            # sums read the velocities of the input and damper nodes, in blocks too
            lw.emit_inline(c, s, "xs", "vs" if power else None)
        if feat.in_forces:
            # the input at the stage time: one of the interpolated ut rows
            c(f"uc = ut{lw.ufracs.index(tab.c[s])}")

    def after() -> None:
        codegen.emit_stage_reductions(c, feat, opts, gains="fi_w")

    codegen.emit_stage_loop(c, feat, tab, lw.ln, prelude, after if power else None,
                            per_run=opts.per_run)
    lw.emit_inline(c, None, "xn", "vn")
    codegen.nystrom_combine(c, tab, lw.ln, frozen="exact")
    codegen.emit_step_end(c, opts, lw.ln)
    c.dedent()
    codegen.emit_chunk_end(c, opts)
    c.dedent(2)


def kernel_source(net: FlatNetlist, opts: KernelOptions) -> str:
    """The kernel text of scheme `opts.method` for `net`."""
    blocks = find_blocks(net)
    rest = split_netlist(net, blocks)
    if SCHEMES[opts.method].kind == "lawson":
        return generate_lawson(rest, opts, block_sizes(blocks), block_channels(net, blocks))
    return generate(rest, opts)


def scheme_arrays(net: FlatNetlist, blocks: Blocks, h: float, method: str,
                  dtype) -> dict[str, np.ndarray]:
    """The block arguments of scheme `method`'s kernel for step `h`."""
    scheme = SCHEMES[method]
    if scheme.kind == "lawson":
        return lawson_arrays(net, blocks, h, scheme.tableau, dtype)
    return block_arrays(net, blocks, h, scheme, dtype)
