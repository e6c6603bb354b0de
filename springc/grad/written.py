"""The discrete adjoint written out per network: each step's stages and their transposes as
scalar statements.

`springc.grad.adjoint` loops over each term kind's element arrays at every stage; here the
network's structure (which nodes each element joins, the tableau, the damper rows of the
reductions) is written into the code, as the simulator's register kernels write it
(`springc.kernels.regkernel`), and the coefficients are runtime arguments (`coefficients`),
so a kernel serves every parameter value of one netlist structure. A step's state, stage
values and adjoints are local scalars inside a loop over the chunk's runs (`LANES`, a
constant of the text), which LLVM's vectorisers pack across the runs. The reverse step is
one loop that recomputes the stages into rows and seeds their adjoints, then one loop per
stage: a single loop over the whole step kept too many values live (it ran scalar).

`forward` integrates a chunk, accumulating work and dissipation per step and the mean
squares and Gram sums of each step's state, and keeps the state every `every` steps (and
every step of the last segment). `reverse` recomputes each earlier segment's step states
from its checkpoint, then per step, backwards: the state seeds of the reductions, then the
step's stages recomputed from its start state and propagated back. All the rows the step
code touches live in one flat workspace `W` (`forward_blocks`, `reverse_blocks`). Used
for networks `eligible` says (no monomial terms, at most `NODES_MAX` masses); the text goes
to the kernel cache like the simulator's kernels.
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass

import numpy as np

from springc.grad import render
from springc.grad.model import BLOCKS, Model
from springc.kernels.integrators import Tableau
from springc.kernels.terms import COMMON, ELEMENTS, INPUT_FORCE, Physical
from springc.lang.ir import FlatNetlist

NODES_MAX = 48  # as the written-out simulator kernels (`springc.kernels.terms.NODES_MAX`)
ELEMENTS_MAX = 400  # numba's compile time grows with the text
LANE_CHOICES = (32, 8, 4, 1)  # runs per chunk (each a compile of its own)


def choose_lanes(runs_per_thread: int) -> int:
    """The widest lane count of `LANE_CHOICES` that a thread's share of the runs fills."""
    return next(w for w in LANE_CHOICES if runs_per_thread >= w)


def eligible(net: FlatNetlist) -> bool:
    """Whether the written-out adjoint serves `net`: no monomials, small enough to write out."""
    elements = (len(net.springs) + len(net.duffings) + len(net.couplings) + len(net.quads)
                + len(net.dashpots) + len(net.forces))
    return len(net.monomials) == 0 and net.n <= NODES_MAX and elements <= ELEMENTS_MAX


@dataclass(frozen=True)
class Structure:
    """What the generated text depends on: node indices of every element (`(i, j)` with
    j < 0 for the ground), input channels, damper rows of the reductions, the tableau and
    the lane count."""

    n: int
    # per kind of `terms.ELEMENTS`, each element's (i, other): its second node (< 0: the
    # ground; -1 for one-node kinds) or, for an input force, its channel
    elements: tuple[tuple[tuple[int, int], ...], ...]
    dampers: tuple[tuple[int, int], ...]  # the reductions' damper rows (i, j)
    a: tuple[tuple[float, ...], ...]
    b: tuple[float, ...]
    c: tuple[float, ...]
    lanes: int

    @property
    def inputs(self) -> tuple[tuple[int, int], ...]:
        """The input forces' (node, channel)."""
        return self.elements[ELEMENTS.index(INPUT_FORCE)]

    @property
    def commons(self) -> tuple[int, ...]:
        """The shared forces' nodes."""
        return tuple(i for i, _ in self.elements[ELEMENTS.index(COMMON.physical)])


def structure(md: Model, ds: np.ndarray, tab: Tableau, lanes: int) -> Structure:
    """The structure of the kernel model `md` with damper rows `ds` (i, j, b)."""
    a = tuple(tuple(float(tab.a[s][j]) if j < len(tab.a[s]) else 0.0 for j in range(s))
              for s in range(tab.stages))
    return Structure(
        len(md.minv), tuple(_pairs(md, p) for p in ELEMENTS),
        tuple((int(r[0]), int(r[1])) for r in ds), a, tuple(float(v) for v in tab.b),
        tuple(float(v) for v in tab.c), lanes)


def _pairs(md: Model, p: Physical) -> tuple[tuple[int, int], ...]:
    first = getattr(md, p.node_i)
    other = getattr(md, p.node_j or p.channel or p.node_i)
    if not (p.node_j or p.channel):
        other = np.full(len(first), -1)
    return tuple((int(i), int(j)) for i, j in zip(first, other))


def coefficients(md: Model, ds: np.ndarray) -> np.ndarray:
    """The kernels' coefficient vector: inverse masses, local damping, then each kind's
    coefficients, then the damper rows' coefficients (the order of `_layout`)."""
    parts = [md.minv, md.bn] + [getattr(md, array) for p in ELEMENTS for _, array, _ in p.params]
    parts.append(ds[:, 2] if len(ds) else np.zeros(0))
    return np.ascontiguousarray(np.concatenate(parts), np.float64)


class _Code:
    """Lines of generated text at an indentation depth."""

    def __init__(self) -> None:
        self.lines: list[str] = []
        self.depth = 0

    def __call__(self, text: str) -> None:
        self.lines.append("    " * self.depth + text)

    def block(self, head: str) -> _Code:
        self(head)
        self.depth += 1
        return self

    def end(self, levels: int = 1) -> None:
        self.depth -= levels


def _sum(terms: list[str]) -> str:
    """Terms ('+ a', '- b') as one expression; '0.0' for none."""
    return " ".join(terms).removeprefix("+ ").replace("- ", "-", 1) if terms else "0.0"


@functools.lru_cache(maxsize=32)
def source(st: Structure) -> str:
    """The generated module's text for structure `st`."""
    c = _Code()
    c("# springc.grad.written: the adjoint written out for one network structure; generated")
    c("import numpy as np")
    c("from numba import njit")
    c("")
    c(f"LANES = {st.lanes}")
    c('JIT = dict(cache=True, nogil=True, error_model="numpy", fastmath={"contract"})')
    _emit_helpers(c)
    _emit_forward(c, st)
    _emit_reverse(c, st)
    return "\n".join(c.lines) + "\n"


def _layout(st: Structure) -> dict[str, int]:
    """Offsets of each block in the coefficient vector (inverse masses, local damping, each
    kind's coefficients `{field}_{kind}`, the damper rows') and in the gradient rows (which
    follow `springc.grad.model.BLOCKS` as `g{block}`: m, b, x0, v0 per node, then per
    element)."""
    n = st.n
    sizes = [("minv", n), ("bn", n)]
    sizes += [(f"{f}_{p.name}", len(els)) for p, els in zip(ELEMENTS, st.elements)
              for f, _, _ in p.params]
    sizes.append(("dc", len(st.dampers)))
    out, at = {}, 0
    for name, size in sizes:
        out[name] = at
        at += size
    per_block = {b: len(els) for p, els in zip(ELEMENTS, st.elements) for _, _, b in p.params}
    grads = [(f"g{b}", n) for b in BLOCKS[:4]] + [(f"g{b}", per_block.get(b, 0))
                                                  for b in BLOCKS[4:]]
    at = 2 * n  # the adjoint rows: xb, vb, then the gradient, then the damper rows'
    for name, size in grads:
        out[name] = at
        at += size
    out["gdc"] = at
    return out


def _each(st: Structure):
    """(kind, element, i, other, at the ground) of every element, in `ELEMENTS` order."""
    for p, elements in zip(ELEMENTS, st.elements):
        for e, (i, o) in enumerate(elements):
            yield p, e, i, o, p.ground is not None and o < 0


def _elem(p: Physical, e: int) -> str:
    """The suffix of element e's own scalars: its coefficients, its per-element values."""
    return f"_{p.name}{e}"


def _lane(p: Physical, s: int, e: int) -> str:
    """The suffix of element e's values at stage s."""
    return f"{s}_{p.name}{e}"


def _state(p: Physical, s: int, e: int, i: int, o: int) -> dict[str, str]:
    """The scalars element e reads at stage s (`render.state_fields`)."""
    out = {"xi": _x(s, i), "vi": _v(s, i)}
    if p.node_j and o >= 0:
        out |= {"xj": _x(s, o), "vj": _v(s, o)}
    if p.channel:
        out["u"] = f"uc{s}_{o}"
    if p.signal:
        out["g"] = f"gv{s}_{e}"
    return out


def _emit_loads(c: _Code, st: Structure, reverse: bool = False) -> None:
    """Every coefficient into a named scalar, the per-element values of the forces and, for
    the reverse sweep, of their derivatives (divisions out of the loops)."""
    lay = _layout(st)
    for name, count in (("minv", st.n), ("bn", st.n), ("dc", len(st.dampers))):
        for e in range(count):
            c(f"{name}{e} = cf[{lay[name] + e}]")
    for p, e, i, o, ground in _each(st):
        for f, _, _ in p.params:
            c(f"{f}{_elem(p, e)} = cf[{lay[f'{f}_{p.name}'] + e}]")
        args = (p, ground, _state(p, 0, e, i, o), _elem(p, e), _lane(p, 0, e))
        for line in render.forward(*args).head:
            c(line)
        if reverse:
            for line in render.backward(*args).head:
                c(line)
    for s in range(len(st.b)):
        c(f"w{s} = h * {st.b[s]!r}")
        for j, a in enumerate(st.a[s]):
            if a != 0.0:
                c(f"ha{s}_{j} = h * {a!r}")
        for e in range(len(st.inputs)):
            c(f"wfi{s}_{e} = w{s} * gain{_elem(INPUT_FORCE, e)}")
        for d in range(len(st.dampers)):
            c(f"wdc{s}_{d} = w{s} * dc{d}")


def _x(s: int, i: int) -> str:
    return f"x{i}" if s == 0 else f"X{s}_{i}"


def _v(s: int, i: int) -> str:
    return f"v{i}" if s == 0 else f"V{s}_{i}"


def _channels(st: Structure) -> list[int]:
    return sorted({ch for _, ch in st.inputs})


def _emit_step_inputs(c: _Code, st: Structure) -> None:
    """Per step, outside the lane loop: every stage's inputs into the local rows US (stage,
    channel, lane; linear between samples as `adjoint._interp`), and the shared sources'
    values and work weights into scalars."""
    channels = _channels(st)
    if channels:
        c("k0 = step // substeps")
    for s, cs in enumerate(st.c):
        if channels:
            c(f"p = (step - k0 * substeps + {cs!r}) / substeps")
            c("ip = int(p)")
            c("fr = p - ip")
            c("ip += k0")
            for q, ch in enumerate(channels):
                c("for b in range(LANES):")
                c(f"    US[{s * len(channels) + q}, b] = (1.0 - fr) * u[{ch}, ip, b] "
                  f"+ fr * u[{ch}, ip + 1, b]")
        for e in range(len(st.commons)):
            c(f"gv{s}_{e} = gtab[step, {s}, {e}]")
            c(f"wg{s}_{e} = w{s} * gain{_elem(COMMON.physical, e)} * gv{s}_{e}")


def _emit_stages(c: _Code, st: Structure) -> None:
    """Every stage's state, inputs, element temporaries and accelerations K, in scalars,
    from the step's start state x{i}, v{i} (`adjoint._stages`)."""
    for s in range(len(st.b)):
        if s:
            for i in range(st.n):
                xs = [f"+ ha{s}_{j} * {_v(j, i)}" for j, a in enumerate(st.a[s]) if a != 0.0]
                ks = [f"+ ha{s}_{j} * K{j}_{i}" for j, a in enumerate(st.a[s]) if a != 0.0]
                c(f"X{s}_{i} = x{i} {' '.join(xs)}")
                c(f"V{s}_{i} = v{i} {' '.join(ks)}")
        _emit_temps(c, st, s)
        forces: list[list[str]] = [[f"- bn{i} * {_v(s, i)}"] for i in range(st.n)]
        for p, e, i, o, ground in _each(st):
            code = render.forward(p, ground, _state(p, s, e, i, o), _elem(p, e), _lane(p, s, e))
            for end, term in code.force.items():
                forces[i if end == "i" else o].append(term)
        for i in range(st.n):
            c(f"K{s}_{i} = ({_sum(forces[i])}) * minv{i}")


def _emit_temps(c: _Code, st: Structure, s: int) -> None:
    """Stage s's inputs and the elements' shared subexpressions, from its state scalars."""
    channels = _channels(st)
    for q, ch in enumerate(channels):
        c(f"uc{s}_{ch} = US[{s * len(channels) + q}, b]")
    for p, e, i, o, ground in _each(st):
        for line in render.forward(p, ground, _state(p, s, e, i, o), _elem(p, e),
                                   _lane(p, s, e)).lane:
            c(line)


def _damper_dv(st: Structure, s: int, d: int) -> str:
    i, j = st.dampers[d]
    return f"({_v(s, i)} - {_v(s, j)})" if j >= 0 else _v(s, i)


def _emit_helpers(c: _Code) -> None:
    """The reductions of each step's state, outside the lane loop (`adjoint._state_sums`,
    `adjoint._state_seeds`), over rows of the state array (x: rows 0..n-1, v: n..2n-1)."""
    c("")
    c("")
    c('@njit(**JIT, inline="always")')
    c("def state_sums(k, n, S, ms, msq, gp, gdecay, gram):")
    c("    for r in range(ms.shape[0]):")
    c("        if ms[r, 2] <= k <= ms[r, 3]:")
    c("            row = ms[r, 0] + (n if ms[r, 1] else 0)")
    c("            for b in range(LANES):")
    c("                msq[r, b] += S[row, b] * S[row, b]")
    c("    if k > 0:")
    c("        for g in range(gram.shape[0]):")
    c("            for b in range(LANES):")
    c("                gram[g, b] *= gdecay[g]")
    c("    for p in range(gp.shape[0]):")
    c("        i, j, g, w = int(gp[p, 0]), int(gp[p, 1]), int(gp[p, 2]), gp[p, 3]")
    c("        for b in range(LANES):")
    c("            gram[g, b] += w * S[i, b] * S[j, b]")
    c("")
    c("")
    c('@njit(**JIT, inline="always")')
    c("def state_seeds(k, n, S, A, ms, msw, gp, gw, fac, gdecay):")
    c("    for r in range(ms.shape[0]):")
    c("        if ms[r, 2] <= k <= ms[r, 3]:")
    c("            row = ms[r, 0] + (n if ms[r, 1] else 0)")
    c("            for b in range(LANES):")
    c("                A[row, b] += 2.0 * msw[r, b] * S[row, b]")
    c("    for p in range(gp.shape[0]):")
    c("        i, j = int(gp[p, 0]), int(gp[p, 1])")
    c("        for b in range(LANES):")
    c("            w = gw[p, b] * gp[p, 3] * fac[p]")
    c("            A[i, b] += w * S[j, b]")
    c("            A[j, b] += w * S[i, b]")
    c("        fac[p] *= gdecay[int(gp[p, 2])]")


def _place(lines: list[str], blocks: dict[str, tuple[int, int]]) -> list[str]:
    """Rows of the named blocks (`name[row, b]`, or `name` alone for the whole block) as
    elements of the one flat workspace W (row r, lane b at r * LANES + b). Its lane loops
    then touch a single array at constant distances, so LLVM vectorises them across the
    lanes without runtime checks between rows or arrays."""
    def row(m: re.Match) -> str:
        base, _ = blocks[m.group(1)]
        idx = m.group(2)
        if idx.isdigit():
            return f"W[{base + int(idx)} * LANES + b]"
        return f"W[({base} + {idx}) * LANES + b]"

    def whole(m: re.Match) -> str:
        lo, hi = blocks[m.group(1)]
        return f"W[{lo} * LANES:{hi} * LANES].reshape(({hi - lo}, LANES))"

    names = "|".join(blocks)
    out = []
    for line in lines:
        line = re.sub(rf"\b({names})\[([^,\]]+), b\]", row, line)
        out.append(re.sub(rf"\b({names})\b(?!\[)", whole, line))
    return out


def _emit_copy(c: _Code, dst: str, src: str, rows: int | str) -> None:
    c(f"for r_ in range({rows}):")
    c("    for b in range(LANES):")
    c(f"        {dst}[r_, b] = {src}[r_, b]")


def _stage_input_rows(st: Structure) -> int:
    return len(st.b) * max(len(_channels(st)), 1)


def rows(blocks: dict[str, tuple[int, int]]) -> int:
    """The rows a workspace of these blocks needs."""
    return max(hi for _, hi in blocks.values())


def forward_blocks(st: Structure) -> dict[str, tuple[int, int]]:
    """`forward`'s workspace rows: the state and accumulators (ST), the stage inputs (US)."""
    rows = 2 * st.n + len(st.inputs) + len(st.commons) + len(st.dampers)
    return {"ST": (0, rows), "US": (rows, rows + _stage_input_rows(st))}


def reverse_blocks(st: Structure) -> dict[str, tuple[int, int]]:
    """`reverse`'s workspace rows: the adjoint rows (AD, `adjoint_rows`), a step's start
    state (CUR) and end state (NXT), the stage inputs (US), the stage states and
    accelerations (STG: X, V, K per stage and node) and the stage adjoints (VBR, KBR)."""
    ad, n2, sn = adjoint_rows(st)[2], 2 * st.n, len(st.b) * st.n
    us = ad + 2 * n2 + _stage_input_rows(st)
    return {"AD": (0, ad), "CUR": (ad, ad + n2), "NXT": (ad + n2, ad + 2 * n2),
            "US": (ad + 2 * n2, us), "STG": (us, us + 3 * sn), "VBR": (us + 3 * sn, us + 4 * sn),
            "KBR": (us + 4 * sn, us + 5 * sn)}


def _emit_forward(c: _Code, st: Structure) -> None:
    first = len(c.lines)
    _emit_forward_text(c, st)
    c.lines[first:] = _place(c.lines[first:], forward_blocks(st))


def _emit_reverse(c: _Code, st: Structure) -> None:
    first = len(c.lines)
    _emit_reverse_text(c, st)
    c.lines[first:] = _place(c.lines[first:], reverse_blocks(st))


def _emit_forward_text(c: _Code, st: Structure) -> None:
    n, nf = st.n, len(st.inputs) + len(st.commons)
    c("")
    c("")
    c("@njit(**JIT)")
    c("def forward(cf, h, nsteps, substeps, W, u, gtab, every, cps, SS, ms, msq, gp, gdecay,")
    c("            gram):")
    c('    """Integrate a chunk from the state rows of W (x, v, then the work and dissipation')
    c("    accumulators, then the stage inputs: rows, lanes), checkpoints in cps, the last")
    c('    segment\'s step states in SS; mean squares and Gram sums in msq, gram."""')
    c.depth += 1
    _emit_loads(c, st)
    c("last = (nsteps - 1) // every")
    c(f"state_sums(0, {n}, ST, ms, msq, gp, gdecay, gram)")
    c.block("for step in range(nsteps):")
    c("seg = step // every")
    c("t = step - seg * every")
    c.block("if t == 0:")
    _emit_copy(c, "cps[seg]", "ST", 2 * n)
    c.end()
    c.block("if seg == last:")
    _emit_copy(c, "SS[t]", "ST", 2 * n)
    c.end()
    _emit_step_inputs(c, st)
    c.block("for b in range(LANES):")
    for i in range(n):
        c(f"x{i} = ST[{i}, b]")
        c(f"v{i} = ST[{n + i}, b]")
    _emit_stages(c, st)
    _emit_stage_sums(c, st, 2 * n, 2 * n + nf)
    _emit_combine(c, st, "ST")
    c.end()
    c(f"state_sums(step + 1, {n}, ST, ms, msq, gp, gdecay, gram)")
    c.end()
    _emit_copy(c, "SS[nsteps - last * every]", "ST", 2 * n)
    c.end()


def _emit_combine(c: _Code, st: Structure, out: str) -> None:
    """The step's new state into rows of `out` (`adjoint._combine`)."""
    n = st.n
    for i in range(n):
        dx = [f"+ w{s} * {_v(s, i)}" for s in range(len(st.b)) if st.b[s] != 0.0]
        dv = [f"+ w{s} * K{s}_{i}" for s in range(len(st.b)) if st.b[s] != 0.0]
        c(f"{out}[{i}, b] = x{i} + ({_sum(dx)})")
        c(f"{out}[{n + i}, b] = v{i} + ({_sum(dv)})")


def _emit_stage_sums(c: _Code, st: Structure, work: int, diss: int) -> None:
    """Work per force and dissipation per damper row over the step's stages
    (`adjoint._stage_sums`)."""
    stages = range(len(st.b))
    for e, (i, ch) in enumerate(st.inputs):
        c(f"ST[{work + e}, b] += " + " + ".join(f"wfi{s}_{e} * uc{s}_{ch} * {_v(s, i)}"
                                               for s in stages))
    for e, i in enumerate(st.commons):
        c(f"ST[{work + len(st.inputs) + e}, b] += "
          + " + ".join(f"wg{s}_{e} * {_v(s, i)}" for s in stages))
    for d in range(len(st.dampers)):
        c(f"ST[{diss + d}, b] += " + " + ".join(
            f"wdc{s}_{d} * {_damper_dv(st, s, d)} * {_damper_dv(st, s, d)}" for s in stages))


def adjoint_rows(st: Structure) -> tuple[int, int, int]:
    """The local adjoint array's rows: xb, vb, the gradient rows and the damper rows
    (`_layout`), then the seeds per force (ww) and per damper row (dw): (ww row, dw row,
    rows)."""
    ww = _layout(st)["gdc"] + len(st.dampers)
    dw = ww + len(st.inputs) + len(st.commons)
    return ww, dw, dw + len(st.dampers)


def _emit_reverse_text(c: _Code, st: Structure) -> None:
    n = st.n
    wrow, drow, _ = adjoint_rows(st)
    c("")
    c("")
    c("@njit(**JIT)")
    c("def reverse(cf, h, nsteps, substeps, u, gtab, every, cps, SS, W, ms, msw, gp, gw,")
    c("            gdecay, fac):")
    c('    """The adjoint sweep after `forward`. W: the adjoint rows (`adjoint_rows`: the')
    c("    final state's adjoint and the seeds on entry; the initial state's adjoint and the")
    c('    gradient on return), then scratch rows."""')
    c.depth += 1
    _emit_loads(c, st, reverse=True)
    c("last = (nsteps - 1) // every")
    c(f"state_seeds(nsteps, {n}, SS[nsteps - last * every], AD, ms, msw, gp, gw, fac, gdecay)")
    c.block("for seg in range(last, -1, -1):")
    c("start = seg * every")
    c("count = min(nsteps, start + every) - start")
    c.block("if seg != last:")
    _emit_copy(c, "SS[0]", "cps[seg]", 2 * n)
    c.block("for t in range(count - 1):")
    c("step = start + t")
    _emit_copy(c, "CUR", "SS[t]", 2 * n)
    _emit_step_inputs(c, st)
    c.block("for b in range(LANES):")
    for i in range(n):
        c(f"x{i} = CUR[{i}, b]")
        c(f"v{i} = CUR[{n + i}, b]")
    _emit_stages(c, st)
    _emit_combine(c, st, "NXT")
    c.end()
    _emit_copy(c, "SS[t + 1]", "NXT", 2 * n)
    c.end(2)
    c.block("for t in range(count - 1, -1, -1):")
    c("step = start + t")
    _emit_copy(c, "CUR", "SS[t]", 2 * n)
    _emit_step_inputs(c, st)
    _emit_step_vjp(c, st, wrow, drow)
    c(f"state_seeds(step, {n}, CUR, AD, ms, msw, gp, gw, fac, gdecay)")
    c.end(3)


def _stg(st: Structure, kind: int, s: int, i: int) -> str:
    """Row of stage s's position (kind 0), velocity (1) or acceleration (2) of node i."""
    return f"STG[{(kind * len(st.b) + s) * st.n + i}, b]"


def _emit_step_vjp(c: _Code, st: Structure, wrow: int, drow: int) -> None:
    """One step backwards (`adjoint._stage_seeds`, `adjoint._step_vjp`): a lane loop that
    recomputes the stages into rows and seeds their adjoints, then one lane loop per stage,
    last to first (a loop over the whole step keeps too many values live: LLVM spilled
    them, or would not vectorise it)."""
    n, S = st.n, len(st.b)
    c.block("for b in range(LANES):")
    for i in range(n):
        c(f"x{i} = CUR[{i}, b]")
        c(f"v{i} = CUR[{n + i}, b]")
        c(f"xb{i} = AD[{i}, b]")
        c(f"vb{i} = AD[{n + i}, b]")
    _emit_stages(c, st)
    for s in range(S):
        for i in range(n):
            if s:
                c(f"{_stg(st, 0, s, i)} = X{s}_{i}")
                c(f"{_stg(st, 1, s, i)} = V{s}_{i}")
            c(f"{_stg(st, 2, s, i)} = K{s}_{i}")
    grad: dict[int, list[str]] = {}
    add = lambda row, term: grad.setdefault(row, []).append(term)  # noqa: E731
    vb0 = _emit_seeds(c, st, wrow, drow, add)
    for s in range(S):
        for i in range(n):
            c(f"VBR[{s * n + i}, b] = {_sum(vb0[s][i])}")
            c(f"KBR[{s * n + i}, b] = w{s} * vb{i}")
    _emit_grad(c, grad)
    grad.clear()
    c.end()
    for s in range(S - 1, -1, -1):
        c.block("for b in range(LANES):")
        for i in range(n):
            if s:
                c(f"X{s}_{i} = {_stg(st, 0, s, i)}")
                c(f"V{s}_{i} = {_stg(st, 1, s, i)}")
            else:
                c(f"x{i} = CUR[{i}, b]")
                c(f"v{i} = CUR[{n + i}, b]")
            c(f"K{s}_{i} = {_stg(st, 2, s, i)}")
            c(f"KB{s}_{i} = KBR[{s * n + i}, b]")
            c(f"VB{s}_{i} = VBR[{s * n + i}, b]")
        _emit_temps(c, st, s)
        _emit_stage_vjp(c, st, s, add)
        _emit_grad(c, grad)
        grad.clear()
        c.end()


def _emit_seeds(c: _Code, st: Structure, wrow: int, drow: int, add) -> list:
    """The reductions' seeds at the stage velocities (`adjoint._stage_seeds`): each stage's
    velocity adjoint terms per node (returned), and the gain and damper gradient terms
    (through `add`)."""
    n, lay, S = st.n, _layout(st), len(st.b)
    nfi = len(st.inputs)
    vb0: list[list[list[str]]] = [[[f"+ w{s} * xb{i}"] for i in range(n)] for s in range(S)]
    for e, (i, ch) in enumerate(st.inputs):
        c(f"ww{e} = AD[{wrow + e}, b]")
        for s in range(S):
            vb0[s][i].append(f"+ ww{e} * wfi{s}_{e} * uc{s}_{ch}")
            add(lay["gfi"] + e, f"+ ww{e} * w{s} * uc{s}_{ch} * {_v(s, i)}")
    for e, i in enumerate(st.commons):
        c(f"ww{nfi + e} = AD[{wrow + nfi + e}, b]")
        for s in range(S):
            vb0[s][i].append(f"+ ww{nfi + e} * wg{s}_{e}")
            add(lay["gfc"] + e, f"+ ww{nfi + e} * w{s} * gv{s}_{e} * {_v(s, i)}")
    for d, (i, j) in enumerate(st.dampers):
        c(f"dw{d} = AD[{drow + d}, b]")
        for s in range(S):
            dv = _damper_dv(st, s, d)
            vb0[s][i].append(f"+ 2.0 * dw{d} * wdc{s}_{d} * {dv}")
            if j >= 0:
                vb0[s][j].append(f"- 2.0 * dw{d} * wdc{s}_{d} * {dv}")
            add(lay["gdc"] + d, f"+ dw{d} * w{s} * {dv} * {dv}")
    return vb0


def _emit_grad(c: _Code, grad: dict[int, list[str]]) -> None:
    for row, terms in sorted(grad.items()):
        c(f"AD[{row}, b] += {_sum(terms)}")


def _emit_stage_vjp(c: _Code, st: Structure, s: int, add) -> None:
    """Stage s's transposed force Jacobian (`adjoint.forces_vjp`, each kind's part rendered
    by `render.backward`) and the tableau's coefficients back to the earlier stages."""
    n, lay = st.n, _layout(st)
    xb: list[list[str]] = [[] for _ in range(n)]
    vb: list[list[str]] = [[] for _ in range(n)]
    for i in range(n):
        c(f"fb{s}_{i} = KB{s}_{i} * minv{i}")
        add(lay["gm"] + i, f"- KB{s}_{i} * K{s}_{i} * minv{i}")
        vb[i].append(f"- bn{i} * fb{s}_{i}")
        add(lay["gb"] + i, f"- {_v(s, i)} * fb{s}_{i}")
    for p, e, i, o, ground in _each(st):
        fb = {"i": f"fb{s}_{i}", "j": f"fb{s}_{o}"}
        code = render.backward(p, ground, _state(p, s, e, i, o), _elem(p, e), _lane(p, s, e),
                               fb)
        for line in code.lane:
            c(line)
        for f, terms in code.state.items():
            (xb if f[0] == "x" else vb)[i if f[1] == "i" else o].extend(terms)
        blocks = {q: b for q, _, b in p.params}
        for f, terms in code.params.items():
            for term in terms:
                add(lay[f"g{blocks[f]}"] + e, term)
    for i in range(n):
        c(f"XB{i} = {_sum(xb[i])}")
        if vb[i]:
            c(f"VB{s}_{i} = VB{s}_{i} {' '.join(vb[i])}")
        c(f"AD[{i}, b] += XB{i}")
        c(f"AD[{n + i}, b] += VB{s}_{i}")
        for j, a in enumerate(st.a[s]):
            if a != 0.0:
                c(f"VBR[{j * n + i}, b] += ha{s}_{j} * XB{i}")
                c(f"KBR[{j * n + i}, b] += ha{s}_{j} * VB{s}_{i}")
