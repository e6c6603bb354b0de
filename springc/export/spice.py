"""Export a flat netlist to an ngspice circuit through the force-current analogy.

The analogy maps each degree of freedom to an electrical node whose voltage is its velocity:

    mass m        -> capacitor C = m from the velocity node to ground (current m v' = net force)
    spring K k    -> inductor L = 1/k to ground (its current k x is the spring's pull)
    coupling C, a = 1 -> inductor L = 1/k between the two velocity nodes
    damper b      -> resistor R = 1/b to ground; dashpot B -> resistor between the nodes
    force F       -> current injected into the velocity node

Nonlinear terms (D, Q, P) and couplings with leverage a != 1 need positions, not velocities, so
every node they touch also gets a position node: a 1 F capacitor to ground charged by a
voltage-controlled current source equal to the velocity, so its voltage is x. Those forces are
then B-sources (behavioural current sources) written in the position voltages; ngspice
differentiates them symbolically for its Newton iterations.

Signals: `sin` and `gauss` become B-sources in `time`; `step`, `pwl`, `in(k)` and `wav(...)`
become PWL current sources (ngspice places a breakpoint at every PWL corner). Sampled signals
follow the simulator's conventions (`springc.sim.sources`): resampled to the input grid 1/tstep,
linear in between, zero after the end. They are written inline, one PWL point per sample,
which keeps the circuit one self-contained file (XSPICE's `filesource` sets no breakpoints,
so it is less accurate, and was no faster: docs/performance.md#ngspice-as-a-peer).
`in(k)` signals are not part of a netlist: they must be bound at export (`SpiceOptions.inputs`).

Limitation: ngspice finds the current PWL segment by a linear scan at every time step, and
restarts its integrator at every breakpoint (one per sample), so its run time grows faster than
the signal's length. Cross-check on short clips.

Initial conditions x0, v0 go into `.ic` (node voltages) and the inductors' `ic=` currents; the
transient runs with `uic` so ngspice starts from them instead of an operating point.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from springc.sim.audio import load_audio, resample
from springc.check.checks import CheckedNetlist, require_checked
from springc.errors import NetlistError, SourceLoc
from springc.lang.ir import GROUND, FlatNetlist, Source

# ngspice reads long PWL lists fine, but lines are folded for editors and diff tools.
_POINTS_PER_LINE = 8
# ngspice restarts its integration with a first-order step after every breakpoint, i.e. at
# every sample of a sampled signal, and at reltol 1e-6 lets that cost about 1e-3 relative
# error on an audio-driven filter; 1e-9 brings it to about 2e-5, at about 6 times the time.
RELTOL = 1e-6
RELTOL_SAMPLED = 1e-9


@dataclass(frozen=True)
class SpiceOptions:
    """How to export: the transient (defaults: the netlist's `.tran`), solver tolerances and
    the signals bound to `in(k)` channels (channel -> (samples, sample rate); resampled to the
    input grid 1/tstep as the simulator does)."""

    tstop: float | None = None
    tstep: float | None = None
    tmax: float | None = None  # largest internal step; default tstep
    reltol: float | None = None  # default: RELTOL, or RELTOL_SAMPLED with sampled signals
    method: str = "trap"
    inputs: dict[int, tuple[np.ndarray, float]] = field(default_factory=dict)
    control: bool = True  # append a .control block that runs and writes the probes
    data_file: str = "springc_probes.txt"


def velocity_node(idx: int) -> str:
    """ngspice name of the velocity node of degree of freedom `idx`."""
    return f"v{idx}"


def position_node(idx: int) -> str:
    """ngspice name of the position (integrator) node of degree of freedom `idx`."""
    return f"x{idx}"


def probe_vectors(net: FlatNetlist) -> dict[str, str]:
    """ngspice vector of every probe, keyed by the probe label as written (`x(X1.out)`)."""
    node = {"x": position_node, "v": velocity_node}
    return {p.label: f"v({node[p.quantity](p.node)})" for p in net.probes}


def transient(net: FlatNetlist, options: SpiceOptions) -> tuple[float, float, float]:
    """(tstep, tstop, tmax) of the export: options first, then the netlist's `.tran`."""
    tran = net.tran
    tstep = options.tstep if options.tstep is not None else (tran.tstep if tran else None)
    tstop = options.tstop if options.tstop is not None else (tran.tstop if tran else None)
    if tstep is None or tstop is None:
        raise NetlistError(
            f"{net.file}: the netlist has no .tran and no time step or stop time was given",
            hint="add `.tran <tstep> <tstop>` or pass --tstep and --tstop",
        )
    if not (tstep > 0 and tstop > 0):
        raise NetlistError(f"time step and stop time must be positive (got {tstep}, {tstop})")
    tmax = options.tmax if options.tmax is not None else tstep
    return float(tstep), float(tstop), float(tmax)


def reltol(net: FlatNetlist, options: SpiceOptions) -> float:
    """ngspice's relative tolerance: as given, else tighter when sampled signals drive `net`."""
    if options.reltol is not None:
        return options.reltol
    sampled = any(s.kind in ("in", "wav") for s in net.forces.source)
    return RELTOL_SAMPLED if sampled else RELTOL


def export_spice(checked: CheckedNetlist, options: SpiceOptions | None = None) -> str:
    """The ngspice netlist of the checked netlist (text). Raises NetlistError, located at the
    element, for what cannot be exported (an `in(k)` channel without a signal bound to it)."""
    net = require_checked(checked, "export_spice").net
    options = options or SpiceOptions()
    tstep, tstop, tmax = transient(net, options)
    pos = _position_nodes(net)
    lines = _header(net, pos)
    lines += _masses(net)
    lines += _position_integrators(pos)
    lines += _linear_elements(net)
    lines += _nonlinear_elements(net)
    lines += _forces(net, options, 1.0 / tstep)
    lines += _initial_conditions(net, pos)
    lines.append(f".options method={options.method} reltol={_num(reltol(net, options))}")
    lines.append(f".tran {_num(tstep)} {_num(tstop)} 0 {_num(tmax)} uic")
    if options.control:
        lines += control_block(list(probe_vectors(net).values()), options.data_file)
    lines.append(".end")
    return "\n".join(lines) + "\n"


def control_block(vectors: list[str], data_file: str, analysis: str = "run") -> list[str]:
    """A `.control` section that runs the analysis and writes `vectors` with one time column."""
    lines = [".control", "set wr_singlescale", "set wr_vecnames", analysis]
    if vectors:
        lines.append(f"wrdata {data_file} " + " ".join(vectors))
    return lines + ["quit", ".endc"]


def _num(v: float) -> str:
    """A float as ngspice reads it, exactly (shortest round-trip form)."""
    v = float(v)
    if not math.isfinite(v):
        raise NetlistError(f"cannot export the non-finite value {v} to SPICE")
    return repr(v)


def _coef(v: float) -> str:
    """A coefficient inside a B-source expression, parenthesised so signs compose."""
    return f"({_num(v)})"


def _pos(idx: int) -> str:
    return f"V({position_node(idx)})"


def _power(idx: int, e: int) -> str:
    """x^e as a product: ngspice's `^` goes through pow() and is not safe for x < 0."""
    return "*".join([_pos(idx)] * e) if e > 0 else "1"


def _position_nodes(net: FlatNetlist) -> list[int]:
    """Nodes whose position is needed: nonlinear terms, levered couplings, x probes."""
    c, q, p = net.couplings, net.quads, net.monomials
    need = set(net.duffings.node.tolist()) | set(q.i.tolist()) | set(q.j.tolist())
    lever = c.a != 1.0
    need |= set(c.i[lever].tolist()) | set(c.j[lever].tolist()) | set(p.var.tolist())
    need |= {pr.node for pr in net.probes if pr.quantity == "x"}
    return sorted(need)


def _header(net: FlatNetlist, pos: list[int]) -> list[str]:
    lines = [
        f"* {net.title or net.file}: exported by springc (force-current analogy)",
        "* node voltage v<i> = velocity of degree of freedom i, x<i> = its position;",
        "* current = force. Degrees of freedom:",
    ]
    lines += [f"*   {i}: {name}" for i, name in enumerate(net.nodes)]
    if not pos:
        lines.append("* (no position nodes needed)")
    if net.acs:
        lines.append("* note: the netlist's .ac analyses are not exported (transient only)")
    return lines


def _comment(letter: str, name: str, loc: SourceLoc) -> str:
    where = f" ({loc})" if loc.line else ""
    return f"* {letter} {name}{where}"


def _masses(net: FlatNetlist) -> list[str]:
    t, lines = net.masses, ["", "* masses (capacitors) and local dampers (resistors)"]
    for e in range(len(t)):
        node = velocity_node(int(t.node[e]))
        lines.append(_comment("M", t.names[e], t.locs[e]))
        lines.append(f"Cm{e} {node} 0 {_num(t.m[e])}")
        if t.b[e] > 0:
            lines.append(f"Rm{e} {node} 0 {_num(1.0 / t.b[e])}")
    return lines


def _position_integrators(pos: list[int]) -> list[str]:
    if not pos:
        return []
    lines = ["", "* position integrators: 1 F charged by a current equal to the velocity"]
    for i in pos:
        lines.append(f"Gx{i} 0 {position_node(i)} {velocity_node(i)} 0 1")
        lines.append(f"Cx{i} {position_node(i)} 0 1")
    return lines


def _linear_elements(net: FlatNetlist) -> list[str]:
    x0, _ = net.initial_state()
    lines = ["", "* springs and unit-leverage couplings (inductors), dashpots (resistors)"]
    s = net.springs
    for e in np.flatnonzero(s.k != 0):
        i = int(s.node[e])
        lines.append(_comment("K", s.names[e], s.locs[e]))
        lines.append(f"Lk{e} {velocity_node(i)} 0 {_num(1 / s.k[e])} ic={_num(s.k[e] * x0[i])}")
    c = net.couplings
    for e in np.flatnonzero((c.a == 1.0) & (c.k != 0)):
        i, j = int(c.i[e]), int(c.j[e])
        ic = c.k[e] * (x0[i] - x0[j])
        lines.append(_comment("C", c.names[e], c.locs[e]))
        lines.append(
            f"Lc{e} {velocity_node(i)} {velocity_node(j)} {_num(1 / c.k[e])} ic={_num(ic)}"
        )
    d = net.dashpots
    for e in np.flatnonzero(d.b != 0):
        other = "0" if d.j[e] == GROUND else velocity_node(int(d.j[e]))
        lines.append(_comment("B", d.names[e], d.locs[e]))
        lines.append(f"Rd{e} {velocity_node(int(d.i[e]))} {other} {_num(1 / d.b[e])}")
    return lines


def _inject(name: str, node: int, expr: str) -> str:
    """A B-source whose current `expr` flows into velocity node `node` (a force on it)."""
    return f"{name} 0 {velocity_node(node)} I={expr}"


def _nonlinear_elements(net: FlatNetlist) -> list[str]:
    lines = ["", "* nonlinear and levered terms (B-sources in the positions)"]
    return lines + _duffings(net) + _levered_couplings(net) + _quads(net) + _monomials(net)


def _duffings(net: FlatNetlist) -> list[str]:
    d, lines = net.duffings, []
    for e in np.flatnonzero(d.l != 0):
        i = int(d.node[e])
        lines.append(_comment("D", d.names[e], d.locs[e]))
        lines.append(_inject(f"Bd{e}", i, f"-{_coef(d.l[e])}*{_power(i, 3)}"))
    return lines


def _levered_couplings(net: FlatNetlist) -> list[str]:
    """f_i = -(k/a)(x_i - a x_j), f_j = k (x_i - a x_j)."""
    c, lines = net.couplings, []
    for e in np.flatnonzero((c.a != 1.0) & (c.k != 0)):
        i, j, k, a = int(c.i[e]), int(c.j[e]), c.k[e], c.a[e]
        stretch = f"({_pos(i)}-{_coef(a)}*{_pos(j)})"
        lines.append(_comment("C", c.names[e], c.locs[e]))
        lines.append(_inject(f"Bc{e}i", i, f"-{_coef(k / a)}*{stretch}"))
        lines.append(_inject(f"Bc{e}j", j, f"{_coef(k)}*{stretch}"))
    return lines


def _quads(net: FlatNetlist) -> list[str]:
    """f_i = -(2g/a) x_i (x_i^2 - a x_j), f_j = g (x_i^2 - a x_j)."""
    q, lines = net.quads, []
    for e in np.flatnonzero(q.g != 0):
        i, j, g, a = int(q.i[e]), int(q.j[e]), q.g[e], q.a[e]
        qs = f"({_power(i, 2)}-{_coef(a)}*{_pos(j)})"
        lines.append(_comment("Q", q.names[e], q.locs[e]))
        lines.append(_inject(f"Bq{e}i", i, f"-{_coef(2 * g / a)}*{_pos(i)}*{qs}"))
        lines.append(_inject(f"Bq{e}j", j, f"{_coef(g)}*{qs}"))
    return lines


def _monomials(net: FlatNetlist) -> list[str]:
    p, lines = net.monomials, []
    for e in range(len(p)):
        powers: dict[int, int] = {}
        for k in range(p.ptr[e], p.ptr[e + 1]):
            powers[int(p.var[k])] = powers.get(int(p.var[k]), 0) + int(p.exp[k])
        lines.append(_comment("P", p.names[e], p.locs[e]))
        for n, (var, ex) in enumerate(powers.items()):
            if ex == 0 or p.c[e] == 0:
                continue
            others = [_power(v, x) for v, x in powers.items() if v != var and x > 0]
            expr = "*".join([f"-{_coef(p.c[e] * ex)}", _power(var, ex - 1), *others])
            lines.append(_inject(f"Bp{e}_{n}", var, expr))
    return lines


def _forces(net: FlatNetlist, options: SpiceOptions, grid_rate: float) -> list[str]:
    f, lines = net.forces, ["", "* external forces (current sources)"]
    for e in range(len(f)):
        lines.append(_comment("F", f.names[e], f.locs[e]))
        signal = _Signal(f.source[e], f.gain[e], f.locs[e], grid_rate)
        lines += _force(e, int(f.node[e]), signal, options)
    return lines


@dataclass(frozen=True)
class _Signal:
    """One force's source with its gain, location and the input grid rate 1/tstep."""

    src: Source
    gain: float
    loc: SourceLoc
    grid_rate: float


def _force(e: int, node: int, sig: _Signal, options: SpiceOptions) -> list[str]:
    src, gain = sig.src, sig.gain
    match src.kind:
        case "sin" | "gauss":
            return [_inject(f"Bf{e}", node, _analytic_expr(sig))]
        case "step":
            amp, t0 = src.args
            ts, vs = ([0.0], [amp]) if t0 <= 0 else ([0.0, t0, t0], [0.0, 0.0, amp])
            return _pwl_source(e, node, np.array(ts), gain * np.array(vs))
        case "pwl":
            ts, vs = _pwl_from_zero(np.array(src.args[0::2]), np.array(src.args[1::2]))
            return _pwl_source(e, node, ts, gain * vs)
        case "in":
            samples, rate = _bound_input(src.channel, sig.loc, options)
            samples = resample(samples, rate, sig.grid_rate)
            return _pwl_source(e, node, *_sampled(samples, sig.grid_rate, gain))
        case "wav":
            samples = load_audio(src.path, sig.grid_rate, 0)  # channel 0, as the simulator
            return _pwl_source(e, node, *_sampled(samples, sig.grid_rate, gain))
        case _:
            raise TypeError(f"unknown source kind {src.kind!r}")


def _analytic_expr(sig: _Signal) -> str:
    """B-source current of a `sin` or `gauss` force, in ngspice's `time`."""
    a, scale = sig.src.args, _coef(sig.gain * sig.src.args[0])
    if sig.src.kind == "sin":
        phase = a[2] if len(a) > 2 else 0.0
        return f"{scale}*sin({_coef(2 * math.pi * a[1])}*time+{_coef(phase)})"
    t0, sigma = a[1], a[2]
    if not sigma > 0:
        raise NetlistError(f"gauss width must be positive, got {sigma}", sig.loc)
    return f"{scale}*exp(-(time-{_coef(t0)})*(time-{_coef(t0)})*{_coef(0.5 / sigma**2)})"


def _bound_input(channel: int, loc: SourceLoc, options: SpiceOptions) -> tuple[np.ndarray, float]:
    if channel not in options.inputs:
        raise NetlistError(
            f"this force reads input channel {channel}, but no signal is bound to it",
            loc,
            hint="give the signal to the export (springc export --spice ... --input FILE)",
        )
    samples, rate = options.inputs[channel]
    return np.asarray(samples, dtype=np.float64), float(rate)


def _sampled(samples: np.ndarray, rate: float, gain: float) -> tuple[np.ndarray, np.ndarray]:
    """PWL points of a sampled signal; it falls to zero one sample after its end (a sound that
    stops), rather than holding its last value as a bare PWL would."""
    ts = np.arange(len(samples) + 1) / rate
    return ts, gain * np.append(samples, 0.0)


def _pwl_from_zero(ts: np.ndarray, vs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """PWL points starting at t = 0 (ngspice's PWL time axis starts there), same values."""
    v0 = np.interp(0.0, ts, vs)
    keep = ts > 0
    return np.concatenate([[0.0], ts[keep]]), np.concatenate([[v0], vs[keep]])


def _pwl_source(e: int, node: int, ts: np.ndarray, vs: np.ndarray) -> list[str]:
    # 12 significant digits: far below the integrator's error, and a third shorter than repr
    pairs = [f"{t:.12g} {v:.12g}" for t, v in zip(ts.tolist(), vs.tolist())]
    rows = [
        " ".join(pairs[k : k + _POINTS_PER_LINE]) for k in range(0, len(pairs), _POINTS_PER_LINE)
    ]
    head = f"If{e} 0 {velocity_node(node)} PWL({rows[0]}"
    return [head] + [f"+ {row}" for row in rows[1:]] + ["+ )"]


def _initial_conditions(net: FlatNetlist, pos: list[int]) -> list[str]:
    x0, v0 = net.initial_state()
    values = [f"v({velocity_node(i)})={_num(v0[i])}" for i in range(net.n)]
    values += [f"v({position_node(i)})={_num(x0[i])}" for i in pos]
    lines = ["", "* initial velocities and positions (used with uic)"]
    for k in range(0, len(values), _POINTS_PER_LINE):
        lines.append(".ic " + " ".join(values[k : k + _POINTS_PER_LINE]))
    return lines
