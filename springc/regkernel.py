"""Register kernels: one run of a small network with its whole state in local scalars.

The shared kernel (`springc.codegen`) keeps the state in `(n_dof, lanes)` rows and picks each
stage's rows at run time (`xa`, `va`, `ka`). For one run of a few masses those rows are a
chain of stores and loads through memory at every term, and the loops over the runtime index
arrays have more control than arithmetic: the hard-driven Duffing resonator (one mass) took
80 ns a step. Here every stage is written out with every node's position, velocity and force
a named scalar, so LLVM keeps the step in registers: 23-25 ns a step on that resonator (10,000
steps in 0.23-0.25 ms against 0.81 ms), and one run of the 6-mass two-band feature extractor
2.6-3.6x faster (1.0-1.4 against 3.5 ms for 0.5 s), within round-off of the shared kernel. Such a kernel is compiled per netlist
structure (as a written-out kernel, `codegen.node_terms`); the coefficients stay runtime
arguments, read once per call.

Used for chunks of one run (`lanes` 1) with only the term kinds written here (`eligible`), for
networks of up to `REGISTER_ALWAYS` masses always and up to `codegen.NODES_MAX` for long
simulations; everything else keeps the shared (or the written-out) kernel. The state
goes back to its rows only to be recorded and checked by the divergence guard.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from springc.codegen import (Features, KernelOptions, LaneLayout, _Code, _emit_coefficients,
                             decorator, emit_guard, emit_nystrom_coefficients, emit_record,
                             features, node_terms, nystrom_coefficients, options_header, preamble,
                             run_args, source_hash)
from springc.integrators import TABLEAUX, Tableau, get_tableau
from springc.ir import FlatNetlist

# Masses up to which one run always gets a register kernel: compiled in about the time of the
# shared kernel (1-3 s). Larger networks, up to `codegen.NODES_MAX`, get one where a kernel
# with its force code written out would be chosen (`simulate.written_out`: long simulations):
# a single run of the 24-mass feature extractor compiled in 7 s and then ran 2.6x faster.
REGISTER_ALWAYS = 8


@dataclass(frozen=True)
class NodeTerms:
    """One node's force terms, as indices into the kernel's coefficient arrays."""

    damped: bool  # bm != 0: reads its own velocity
    sprung: bool  # km != 0
    row: tuple[tuple[int, int], ...]  # (entry of l_val, column): off-diagonal stiffness
    ins: tuple[tuple[int, int], ...]  # (entry of fi_gm, channel): input forces
    quads: tuple[tuple[int, str, int], ...]  # (quad, end 'i' or 'j', other node)
    duffings: tuple[int, ...]  # Duffing elements on it
    dashpots: tuple[tuple[int, str, int], ...]  # (dashpot, end, other node or -1 for ground)
    common: tuple[int, ...]  # common (shared-signal) force elements on it


def eligible(net: FlatNetlist, opts: KernelOptions) -> bool:
    """Whether a register kernel serves these options: one run per chunk, a Runge-Kutta
    tableau (not a splitting scheme), no reductions, no monomial terms."""
    return (opts.lanes == 1 and opts.method in TABLEAUX and len(net.monomials) == 0
            and not (opts.work or opts.dissipation or opts.msq or opts.gram))


def terms(co: dict, n: int) -> tuple[NodeTerms, ...] | None:
    """Every node's terms from the coefficient arrays `co` (`simulate.coefficient_arrays`);
    None when the network is too large to write out (`codegen.node_terms`)."""
    linear = node_terms(co, n)
    if linear is None:
        return None
    duff: list[list[int]] = [[] for _ in range(n)]
    for e, i in enumerate(co["d_node"].tolist()):
        duff[i].append(e)
    dash: list[list[tuple]] = [[] for _ in range(n)]
    for e, (i, j) in enumerate(zip(co["b_i"].tolist(), co["b_j"].tolist())):
        dash[i].append((e, "i", j))
        if j >= 0:
            dash[j].append((e, "j", i))
    common: list[list[int]] = [[] for _ in range(n)]
    for e, i in enumerate(co["fc_node"].tolist()):
        common[i].append(e)
    return tuple(NodeTerms(damped, sprung, row, ins, quads, tuple(duff[i]), tuple(dash[i]),
                           tuple(common[i]))
                 for i, (damped, sprung, row, ins, quads, _) in enumerate(linear))


def generate(net: FlatNetlist, opts: KernelOptions) -> str:
    """Python source of the register kernel for `net` under `opts` (its terms in
    `opts.registers`)."""
    tab = get_tableau(opts.method)
    body, digest = _body(features(net), opts)
    header = [
        "# springc generated kernel: do not edit (regenerated from the netlist)",
        f"# netlist: {net.file}",
        f"# title: {net.title}",
        *options_header(opts),
        f"# integrator: {tab.name} ({tab.description})",
        f"# dofs: {net.n}; elements: {net.element_counts()}",
        f"# body-hash: {digest}",
        "",
    ]
    return "\n".join(header) + body


def _needs_velocity(node: NodeTerms) -> bool:
    return node.damped or bool(node.dashpots)


@functools.lru_cache(maxsize=64)
def _body(feat: Features, opts: KernelOptions) -> tuple[str, str]:
    """The kernel body and its hash (kept per process, as `codegen.hashed_body`)."""
    tab = get_tableau(opts.method)
    nodes = opts.registers
    c = _Code()
    c('"""Generated by springc.regkernel; see the header. One run per chunk, state in '
      'scalars."""')
    preamble(c, opts, run_args(feat, opts), tab.stages)
    c("")
    c(decorator())
    c(f"def run({', '.join(run_args(feat, opts))}):")
    c.indent()
    c('"""Integrate chunks c0..c1-1 of one run each (columns of x0) for nsteps steps of h."""')
    _emit_coefficients(c, tab)
    emit_nystrom_coefficients(c, tab)
    _emit_scalars(c, nodes)
    c("n = x0.shape[0]")
    c("x = np.zeros((n, 1), FT)  # the state's rows: written back to record and to check")
    c("v = np.zeros((n, 1), FT)")
    c("for ci in range(c0, c1):")
    c.indent()
    c("lo_ = ci")
    c("nv_ = 1")
    for i in range(len(nodes)):
        c(f"X{i} = x0[{i}, lo_]")
        c(f"V{i} = v0[{i}, lo_]")
    if opts.record:
        _emit_record(c, len(nodes), "0")
    c("sub = substeps - 1")
    c("k0 = -1")
    c("rc_ = 0")
    c("rn_ = 0")
    c("cc_ = 0")
    c("for step in range(nsteps):")
    c.indent()
    c("sub += 1")
    c("if sub == substeps:")
    c("    sub = 0")
    c("    k0 += 1")
    for s in range(tab.stages):
        _emit_stage(c, tab, s, nodes)
    _emit_combine(c, tab, len(nodes))
    c("k1 = step + 1")
    if opts.record:
        c("rc_ += 1")
        c("if rc_ == rec_every:")
        c.indent()
        c("rc_ = 0")
        c("rn_ += 1")
        _emit_record(c, len(nodes), "rn_")
        c.dedent()
    emit_guard(c, lambda: _write_back(c, len(nodes)))
    c.dedent()
    for i in range(len(nodes)):
        c(f"xf[{i}, lo_] = X{i}")
        c(f"vf[{i}, lo_] = V{i}")
    c.dedent(2)
    text = c.text()
    return text, source_hash(text)


def _emit_scalars(c: _Code, nodes: tuple[NodeTerms, ...]) -> None:
    """Every coefficient the force code reads, into a scalar before the loops."""
    for i, node in enumerate(nodes):
        if node.damped:
            c(f"bm{i} = bm[{i}]")
        if node.sprung:
            c(f"km{i} = km[{i}]")
        for e, _ in node.row:
            c(f"lv{e} = l_val[{e}]")
        for e, _ in node.ins:
            c(f"gm{e} = fi_gm[{e}]")
        for e, end, _ in node.quads:
            if end == "i":
                c(f"qa{e} = q_a[{e}]")
            c(f"q{end}{e} = q_g{end}[{e}]")
        for e in node.duffings:
            c(f"dl{e} = d_lm[{e}]")
        for e, end, _ in node.dashpots:
            c(f"b{end}{e} = b_b{end}[{e}]")
        for e in node.common:
            c(f"fg{e} = fc_gm[{e}]")


def _emit_stage(c: _Code, tab: Tableau, s: int, nodes: tuple[NodeTerms, ...]) -> None:
    """Stage s: its positions XA, velocities VA (where read) and inputs, then forces K{s}_i."""
    c(f"# stage {s} (c = {tab.c[s]!r})")
    _, aa, _, _ = nystrom_coefficients(tab)
    row = [j for j, a in enumerate(tab.a[s]) if a != 0.0]
    sq = [int(k) for k in np.flatnonzero(aa[s])]
    for i, node in enumerate(nodes):
        if s == 0:
            c(f"XA{i} = X{i}")
        else:
            xterm = " + ".join([f"hc{s} * V{i}"] + [f"hh{s}_{k} * K{k}_{i}" for k in sq])
            c(f"XA{i} = X{i} + ({xterm})")
        if _needs_velocity(node):
            vterm = " + ".join(f"ha{s}_{j} * K{j}_{i}" for j in row)
            c(f"VA{i} = V{i}" if s == 0 else f"VA{i} = V{i} + {vterm or 'FT(0.0)'}")
    channels = sorted({ch for node in nodes for _, ch in node.ins})
    if channels and (s == 0 or tab.c[s] != tab.c[s - 1]):
        # linear interpolation of the input samples at the stage time (as the shared kernel)
        c(f"pos = (sub + {tab.c[s]!r}) / substeps")
        c("kk = k0 + int(pos)")
        c("fr = FT(pos - int(pos))")
        c("gr = FT(1.0) - fr")
        for ch in channels:
            c(f"U{ch} = gr * u[lo_, {ch}, kk] + fr * u[lo_, {ch}, kk + 1]")
    for e in sorted({e for node in nodes for e in node.common}):
        c(f"G{e} = g[step, {s}, {e}]")
    for i, node in enumerate(nodes):
        c(f"K{s}_{i} = {_force(i, node)}")


def _force(i: int, node: NodeTerms) -> str:
    """Node i's acceleration at the stage, summed left to right in the shared kernel's order:
    its own damping and spring, stiffness row, inputs, quadratic couplings (`emit_nodes`),
    then Duffing terms, dashpots and shared signals (`emit_accel_body`)."""
    own = ([f"bm{i} * VA{i}"] if node.damped else []) + ([f"km{i} * XA{i}"] if node.sprung else [])
    terms = [f"- ({' + '.join(own)})"] if own else []
    terms += [f"+ lv{e} * XA{j}" for e, j in node.row]
    terms += [f"+ gm{e} * U{ch}" for e, ch in node.ins]
    for e, end, j in node.quads:
        terms.append(f"- qi{e} * XA{i} * (XA{i} * XA{i} - qa{e} * XA{j})" if end == "i" else
                     f"+ qj{e} * (XA{j} * XA{j} - qa{e} * XA{i})")
    terms += [f"- dl{e} * (XA{i} * XA{i} * XA{i})" for e in node.duffings]
    for e, end, j in node.dashpots:
        if j < 0:
            terms.append(f"- bi{e} * VA{i}")
        elif end == "i":
            terms.append(f"- bi{e} * (VA{i} - VA{j})")
        else:
            terms.append(f"+ bj{e} * (VA{j} - VA{i})")
    terms += [f"+ fg{e} * G{e}" for e in node.common]
    return " ".join(terms).removeprefix("+ ") if terms else "FT(0.0)"


def _emit_combine(c: _Code, tab: Tableau, n: int) -> None:
    """x += h (sum b) v + h^2 sum_k (b A)_k K_k; v += h sum_s b_s K_s (`nystrom_combine`)."""
    _, _, ba, _ = nystrom_coefficients(tab)
    used = [s for s, b in enumerate(tab.b) if b != 0.0]
    sq = [int(k) for k in np.flatnonzero(ba)]
    for i in range(n):
        xterm = " + ".join([f"hbs * V{i}"] + [f"hhb{k} * K{k}_{i}" for k in sq])
        vterm = " + ".join(f"hb{s} * K{s}_{i}" for s in used)
        c(f"X{i} = X{i} + ({xterm})")
        c(f"V{i} = V{i} + ({vterm})")


def _write_back(c: _Code, n: int) -> None:
    for i in range(n):
        c(f"x[{i}, 0] = X{i}")
        c(f"v[{i}, 0] = V{i}")


def _emit_record(c: _Code, n: int, r: str) -> None:
    """The probes of record `r` from the written-back state (`codegen.emit_record`: one run's
    ordinary stores)."""
    _write_back(c, n)
    emit_record(c, r, LaneLayout(1, 1), 1)  # one lane: stored as it comes, no staging
