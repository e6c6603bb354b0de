"""Streaming reductions: quantities a run accumulates instead of storing a trajectory.

Syntax of a reduction (the result is stored under the string as written):
- `final:x(NODE)`, `final:v(NODE)`: the value at the end of the run.
- `msq:x(NODE)`, `msq:x(NODE):T0:T1`: mean square over the integration steps with
  T0 < t <= T1 (seconds; default the whole run). `v(...)` works too.
- `work:in`: input work, the integral of F v summed over all `F` elements; `work:FNAME` for one.
- `dissipated:all`: energy dissipated in all dampers (local `b` of every `M`, every `B`);
  `dissipated:NAME` for one `M` or `B` element, or for a node (its local damping).
- `energy`: total mechanical energy at the end.
- `loss:NAME`: insertion loss in dB, -10 log10(dissipated:NAME / work:in).
- `gram:TAU:N1,N2,...`: leaky Gram matrix of the listed nodes' displacements,
  G_kl = int_0^T exp(-(T-t)/TAU) x_k x_l dt (trapezoid on the integration grid), one value per
  pair k <= l in row-major order, shape (runs, pairs). `gram_reduction` builds the general form
  in code: node pairs summed with weights into groups (the SVM features Phi of
  springc.kws.features.phi).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from springc.errors import UsageError
from springc.lang.ir import GROUND, FlatNetlist

_QTY = re.compile(r"^(x|v)\((.+)\)$")
KINDS = ("final", "msq", "work", "dissipated", "energy", "loss", "gram")


@dataclass(frozen=True)
class Reduction:
    """A parsed reduction: `kind` from KINDS, and what it applies to."""

    spec: str
    kind: str
    node: int = -1
    isv: bool = False
    t0: float = 0.0
    t1: float = np.inf
    forces: tuple[int, ...] = ()
    dampers: tuple[tuple[int, int, float], ...] = ()
    gram: "GramPairs | None" = None


@dataclass(frozen=True)
class GramPairs:
    """The pairs of a `gram` reduction: node indices i, j, group ids, weights (all (P,)), the
    number of groups and the time constant tau (s)."""

    i: tuple[int, ...]
    j: tuple[int, ...]
    group: tuple[int, ...]
    weight: tuple[float, ...]
    groups: int
    tau: float


def gram_reduction(net: FlatNetlist, tau: float, i, j, group, weight=None,
                   label: str = "gram") -> Reduction:
    """A `gram` reduction given in code: result[g] = sum over pairs p with group[p] = g of
    weight[p] int_0^T exp(-(T-t)/tau) x_i[p] x_j[p] dt. `i`, `j` are node names or indices."""
    idx = lambda nodes: tuple(n if isinstance(n, (int, np.integer)) else _node(n, net)  # noqa
                              for n in nodes)
    ii, jj, gg = idx(i), idx(j), tuple(int(g) for g in group)
    ww = tuple(float(w) for w in (np.ones(len(ii)) if weight is None else weight))
    if not (len(ii) == len(jj) == len(gg) == len(ww)) or not ii:
        raise UsageError(f"{label}: i, j, group and weight need the same nonzero length")
    if not tau > 0 or min(gg) < 0:
        raise UsageError(f"{label}: tau must be positive and group ids non-negative")
    if max(ii + jj) >= net.n or min(ii + jj) < 0:
        raise UsageError(f"{label}: node index out of range 0..{net.n - 1}")
    return Reduction(label, "gram", gram=GramPairs(ii, jj, gg, ww, max(gg) + 1, float(tau)))


def parse_quantity(text: str, net: FlatNetlist) -> tuple[int, bool]:
    """`x(NODE)` or `v(NODE)` -> (node index, is velocity)."""
    m = _QTY.match(text.strip())
    if not m:
        raise UsageError(f"expected x(NODE) or v(NODE), got {text!r}")
    return _node(m.group(2), net), m.group(1) == "v"


def _node(name: str, net: FlatNetlist) -> int:
    try:
        return net.node_index(name)
    except ValueError:
        raise UsageError(f"unknown node {name!r}",
                         hint=f"nodes: {', '.join(net.nodes[:12])}...") from None


def parse(spec: "str | Reduction", net: FlatNetlist) -> Reduction:
    """Parse one reduction string (see the module docstring); UsageError if malformed. A
    `Reduction` built in code (`gram_reduction`) is passed through."""
    if isinstance(spec, Reduction):
        return spec
    kind, _, rest = spec.partition(":")
    match kind:
        case "final":
            node, isv = parse_quantity(rest, net)
            return Reduction(spec, kind, node, isv)
        case "msq":
            return _parse_msq(spec, rest, net)
        case "work":
            return Reduction(spec, kind, forces=_forces(rest, net))
        case "dissipated" | "loss":
            return Reduction(spec, kind, dampers=dampers(rest, net))
        case "energy" if not rest:
            return Reduction(spec, kind)
        case "gram":
            return _parse_gram(spec, rest, net)
        case _:
            raise UsageError(f"bad reduction {spec!r}",
                             hint="use final:x(N), msq:x(N)[:T0:T1], work:in, "
                                  "dissipated:NAME|all, energy, loss:NAME, gram:TAU:N1,N2")


def _parse_msq(spec: str, rest: str, net: FlatNetlist) -> Reduction:
    m = re.match(r"^([xv]\(.+\))(?::([^:]+):([^:]+))?$", rest)
    if not m:
        raise UsageError(f"bad reduction {spec!r}", hint="msq:x(NODE) or msq:x(NODE):T0:T1")
    node, isv = parse_quantity(m.group(1), net)
    try:
        t0, t1 = (float(m.group(2)), float(m.group(3))) if m.group(2) else (0.0, np.inf)
    except ValueError:
        raise UsageError(f"bad window in {spec!r}: times are numbers in seconds") from None
    if t1 <= t0:
        raise UsageError(f"empty window in {spec!r}: T1 must be after T0")
    return Reduction(spec, "msq", node, isv, t0, t1)


def _parse_gram(spec: str, rest: str, net: FlatNetlist) -> Reduction:
    tau, _, names = rest.partition(":")
    nodes = [n.strip() for n in names.split(",") if n.strip()]
    try:
        tau_s = float(tau)
    except ValueError:
        raise UsageError(f"bad reduction {spec!r}", hint="gram:TAU:N1,N2,... (TAU in s)") from None
    if not nodes:
        raise UsageError(f"bad reduction {spec!r}: no nodes", hint="gram:TAU:N1,N2,...")
    pairs = [(a, b) for a in range(len(nodes)) for b in range(a, len(nodes))]
    return gram_reduction(net, tau_s, [nodes[a] for a, _ in pairs],
                          [nodes[b] for _, b in pairs], range(len(pairs)), label=spec)


def _forces(name: str, net: FlatNetlist) -> tuple[int, ...]:
    if name == "in":
        return tuple(range(len(net.forces)))
    if name in net.forces.names:
        return (net.forces.names.index(name),)
    raise UsageError(f"work:{name}: no force element {name!r}", hint="work:in sums all of them")


def dampers(name: str, net: FlatNetlist) -> tuple[tuple[int, int, float], ...]:
    """Dampers (i, j, b) named by `name`: all, an M or B element, or a node's local damping."""
    m, d = net.masses, net.dashpots
    local = [(int(m.node[e]), GROUND, float(m.b[e])) for e in range(len(m)) if m.b[e] != 0]
    pots = [(int(d.i[e]), int(d.j[e]), float(d.b[e])) for e in range(len(d))]
    if name == "all":
        return tuple(local + pots)
    if name in m.names:
        e = m.names.index(name)
        return ((int(m.node[e]), GROUND, float(m.b[e])),)
    if name in d.names:
        return (pots[d.names.index(name)],)
    if name in net.nodes:
        node = net.node_index(name)
        return tuple(row for row in local if row[0] == node)
    raise UsageError(f"no damper, M or B element or node called {name!r}")


@dataclass
class Plan:
    """All reductions of a simulation laid out as the kernel's accumulator rows."""

    items: list[Reduction]
    msq: list[Reduction] = field(default_factory=list)
    damper_rows: list[tuple[int, int, float]] = field(default_factory=list)
    damper_slices: dict[str, slice] = field(default_factory=dict)
    gram: list[Reduction] = field(default_factory=list)
    gram_slices: dict[str, slice] = field(default_factory=dict)

    @property
    def work(self) -> bool:
        return any(r.kind in ("work", "loss") for r in self.items)


def plan(specs: list[str], net: FlatNetlist) -> Plan:
    """Parse reduction strings and assign kernel accumulator rows."""
    items = [parse(s, net) for s in specs]
    out = Plan(items, msq=[r for r in items if r.kind == "msq"],
               gram=[r for r in items if r.kind == "gram"])
    rows = 0
    for r in out.gram:
        out.gram_slices[r.spec] = slice(rows, rows + r.gram.groups)
        rows += r.gram.groups
    for r in items:
        if r.dampers and r.spec not in out.damper_slices:
            start = len(out.damper_rows)
            out.damper_rows += list(r.dampers)
            out.damper_slices[r.spec] = slice(start, len(out.damper_rows))
    return out


def msq_window(r: Reduction, h: float, nsteps: int) -> tuple[int, int, int]:
    """Steps k (state after step k, t = k h) with t0 < t <= t1: (first, last, count)."""
    lo = int(np.floor(r.t0 / h + 1e-9)) + 1
    hi = nsteps if not np.isfinite(r.t1) else min(nsteps, int(np.floor(r.t1 / h + 1e-9)))
    return lo, hi, max(hi - lo + 1, 0)


def gram_arrays(p: Plan, h: float, dtype) -> dict[str, np.ndarray]:
    """Kernel arguments of the plan's gram reductions: pairs with group rows offset per
    reduction, weights times h, and the per-row decay exp(-h / tau)."""
    gi, gj, gg, gw, decay = [], [], [], [], []
    for r in p.gram:
        off = p.gram_slices[r.spec].start
        gi += r.gram.i
        gj += r.gram.j
        gg += [g + off for g in r.gram.group]
        gw += [w * h for w in r.gram.weight]
        decay += [np.exp(-h / r.gram.tau)] * r.gram.groups
    return {"gr_i": np.array(gi, np.int64), "gr_j": np.array(gj, np.int64),
            "gr_g": np.array(gg, np.int64), "gr_w": np.array(gw, np.float64),
            "gr_decay": np.array(decay, np.float64)}


def gram_finish(r: Reduction, acc: np.ndarray, x0: np.ndarray, xf: np.ndarray, h: float,
                tstop: float) -> np.ndarray:
    """Result (runs, groups) from the kernel's rectangle sums over steps 0..K (the step-0 term
    decayed to exp(-T/tau)): trapezoid = sum - h/2 (w_0 f_0 + f_K)."""
    g = r.gram
    i, j, w = np.array(g.i), np.array(g.j), np.array(g.weight)
    ends = np.zeros((g.groups, xf.shape[1]))
    f0 = w[:, None] * x0[i] * x0[j] * np.exp(-tstop / g.tau)
    fk = w[:, None] * xf[i] * xf[j]
    np.add.at(ends, np.array(g.group), f0 + fk)
    return (acc - 0.5 * h * ends).T.copy()
