"""Register kernels: each run's step with its whole state in local scalars.

The shared kernel (`springc.kernels.codegen`) keeps the state in `(n_dof, lanes)` rows and runs each
stage as passes over rows (`xa`, `va`, `ka`, picked at run time). Here the whole step is
written out, every node's position, velocity and stage force a named scalar, so no stage row
goes through memory:
- chunks of one run keep the state in scalars from step to step. The hard-driven Duffing
  resonator (one mass) took 80 ns a step in the shared kernel, 23-25 ns here (10,000 steps
  in 0.23-0.25 ms against 0.81 ms); one run of the 6-mass two-band feature extractor
  2.6-3.6x faster (1.0-1.4 against 3.5 ms for 0.5 s);
- chunks of many runs loop over the lanes inside each step, the loop body the whole step
  (LLVM vectorises it across lanes); the state rows are read and written once a step. The
  feature extractor, 64 runs of 1 s recording nothing: float32 32.0 -> 25.5 ms, float64
  62.6 -> 45.1 ms against the kernel with its force code written out per node
  (`codegen.emit_nodes`). The loop spills hundreds of vectors a step, so these kernels align
  their stack frame (`springc.kernels.stackalign`: recording 16 probes, float32 42.8 -> 36.2 ms,
  float64 91.4 -> 56.0 ms).
Within round-off of the shared kernel. Such a kernel is compiled per netlist structure, as a
written-out kernel (`codegen.node_terms`); the coefficients stay runtime arguments, read once
per call.

Used where the force code would be written out (`simulate.written_out`: long simulations of
networks of at most `codegen.NODES_MAX` masses) and, for chunks of one run, always up to
`REGISTER_ALWAYS` masses, with only the term kinds written here (`eligible`: no reductions,
no monomials); everything else keeps the shared or the written-out kernel. Records and the
divergence guard read the state rows (a one-run kernel writes its scalars back first).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from springc.kernels.codegen import (Features, KernelOptions, LaneLayout, _Code, emit_chunk_end,
                             emit_chunk_start, emit_record, emit_run_head,
                             emit_step_end, emit_step_start, features, lane_layout, node_terms,
                             nystrom_coefficients, preamble, run_args, source_hash,
                             with_header)
from springc.kernels.integrators import TABLEAUX, Tableau, get_tableau
from springc.lang.ir import FlatNetlist

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
    """Whether a register kernel serves these options: a Runge-Kutta tableau (not a
    splitting scheme), no reductions, no monomial terms."""
    return (opts.method in TABLEAUX and len(net.monomials) == 0
            and not (opts.work or opts.dissipation or opts.msq or opts.gram))


def terms(co: dict, n: int, linear: tuple | None = None) -> tuple[NodeTerms, ...] | None:
    """Every node's terms from the coefficient arrays `co` (`simulate.coefficient_arrays`),
    extending `linear`, their `codegen.node_terms` when the caller has them already; None
    when the network is too large to write out."""
    linear = linear if linear is not None else node_terms(co, n)
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
    return with_header(net, opts, *_body(features(net), opts))


def _needs_velocity(node: NodeTerms) -> bool:
    return node.damped or bool(node.dashpots)


@functools.lru_cache(maxsize=64)
def _body(feat: Features, opts: KernelOptions) -> tuple[str, str]:
    """The kernel body and its hash (kept per process, as `codegen.hashed_body`)."""
    tab = get_tableau(opts.method)
    c = _Code()
    c('"""Generated by springc.kernels.regkernel; see the header. Each run\'s step in scalars."""')
    preamble(c, opts, run_args(feat, opts), tab.stages)
    c("")
    emit_run_head(c, feat, opts, tab)
    _emit_scalars(c, opts.registers)
    if opts.lanes == 1:
        _emit_one_run(c, opts, tab)
    else:
        _emit_lanes(c, feat, opts, tab)
    text = c.text()
    return text, source_hash(text)


def _emit_one_run(c: _Code, opts: KernelOptions, tab: Tableau) -> None:
    """Chunks of one run: the state stays in scalars from step to step."""
    nodes = opts.registers
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
    _emit_input_positions(c, tab, nodes, "k0")
    _emit_step(c, tab, nodes, "u[lo_, {ch}, {k}]")
    emit_step_end(c, opts, LaneLayout(1, 1), lambda: _write_back(c, len(nodes)))
    c.dedent()
    for i in range(len(nodes)):
        c(f"xf[{i}, lo_] = X{i}")
        c(f"vf[{i}, lo_] = V{i}")
    c.dedent()


def _emit_lanes(c: _Code, feat: Features, opts: KernelOptions, tab: Tableau) -> None:
    """Chunks of LANES runs, as the shared kernel lays them out (`codegen`: state rows, staged
    inputs, staged records, guard), but each step a loop over the lanes whose body is the
    whole step in scalars: no stage rows go through memory, and LLVM vectorises the loop
    across lanes."""
    nodes = opts.registers
    c("for ci in range(c0, c1):")
    c.indent()
    emit_chunk_start(c, opts, [])
    c("for step in range(nsteps):")
    c.indent()
    emit_step_start(c, feat.in_forces)
    _emit_input_positions(c, tab, nodes, "k0 - ubase")
    c(f"for b in range({opts.lanes}):")
    c.indent()
    for i in range(len(nodes)):
        c(f"X{i} = x[{i}, b]")
        c(f"V{i} = v[{i}, b]")
    _emit_step(c, tab, nodes, "ustg[{k}, {ch}, b]")
    for i in range(len(nodes)):
        c(f"x[{i}, b] = X{i}")
        c(f"v[{i}, b] = V{i}")
    c.dedent()
    emit_step_end(c, opts, lane_layout(opts))
    c.dedent()
    emit_chunk_end(c, opts)
    c.dedent()


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


def _input_times(tab: Tableau) -> list[int]:
    """Stages whose time differs from the stage before (each needs its own input values)."""
    return [s for s in range(tab.stages) if s == 0 or tab.c[s] != tab.c[s - 1]]


def _emit_input_positions(c: _Code, tab: Tableau, nodes: tuple[NodeTerms, ...],
                          base: str) -> None:
    """Per distinct stage time: the input sample `kk{s}` before it (`base` + the step's
    sample) and the linear interpolation weights, as the shared kernel (`emit_interp`)."""
    if not any(node.ins for node in nodes):
        return
    for s in _input_times(tab):
        c(f"pos{s} = (sub + {tab.c[s]!r}) / substeps")
        c(f"kk{s} = {base} + int(pos{s})")
        c(f"fr{s} = FT(pos{s} - int(pos{s}))")
        c(f"gr{s} = FT(1.0) - fr{s}")


def _emit_step(c: _Code, tab: Tableau, nodes: tuple[NodeTerms, ...], read: str) -> None:
    """One step from scalars X{i}, V{i} to the new X{i}, V{i}; inputs read as `read`
    formatted with the channel and the sample index."""
    channels = sorted({ch for node in nodes for _, ch in node.ins})
    for s in range(tab.stages):
        _emit_stage(c, tab, s, nodes)
        if channels and s in _input_times(tab):
            for ch in channels:
                a, b = read.format(ch=ch, k=f"kk{s}"), read.format(ch=ch, k=f"kk{s} + 1")
                c(f"U{ch} = gr{s} * {a} + fr{s} * {b}")
        for e in sorted({e for node in nodes for e in node.common}):
            c(f"G{e} = g[step, {s}, {e}]")
        for i, node in enumerate(nodes):
            c(f"K{s}_{i} = {_force(i, node)}")
    _emit_combine(c, tab, len(nodes))


def _emit_stage(c: _Code, tab: Tableau, s: int, nodes: tuple[NodeTerms, ...]) -> None:
    """Stage s's positions XA{i} and velocities VA{i} (where read)."""
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
