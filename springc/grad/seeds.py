"""Reductions for the adjoint: their accumulator rows, their values from the forward
accumulators (as `springc.sim.simulate` finishes them), and their adjoint seeds.

A reduction is a sum over the discrete computation, so its adjoint is exact when it seeds
the same terms: final values seed the last state, mean squares and Gram sums the states of
their steps, work and dissipation the stage velocities with the tableau's weights (the
kernels' quadrature of power), an insertion loss both through its logarithm.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from springc.errors import UsageError
from springc.lang.ir import GROUND, FlatNetlist
from springc.sim import reductions, sources

SUPPORTED = ("final", "msq", "work", "dissipated", "loss", "gram")


@dataclass
class Rows:
    """Accumulator rows of all reductions: damper rows `ds` (i, j, b) with the element each
    belongs to (`ds_elem`: ('M' or 'B', index)), mean-square rows `ms` (node, isv, lo, hi),
    Gram pairs `gp` (i, j, group, weight h) with per-group decay; per reduction, its slices."""

    ds: list = field(default_factory=list)
    ds_elem: list = field(default_factory=list)
    ms: list = field(default_factory=list)
    ms_count: list = field(default_factory=list)
    gp: list = field(default_factory=list)
    gdecay: list = field(default_factory=list)
    where: dict = field(default_factory=dict)

    def arrays(self) -> tuple[np.ndarray, ...]:
        """(ds, ms, gp, gdecay) as the kernels take them."""
        return (np.array(self.ds, np.float64).reshape(-1, 3),
                np.array(self.ms, np.int64).reshape(-1, 4),
                np.array(self.gp, np.float64).reshape(-1, 4),
                np.array(self.gdecay, np.float64))


def parse(specs: list, net: FlatNetlist) -> list[reductions.Reduction]:
    """The reductions of `specs` (as `--reduce` takes them); a malformed one, or one the
    gradient cannot follow, is a `UsageError` naming it."""
    out = []
    for spec in specs:
        try:
            r = reductions.parse(spec, net)
        except UsageError as err:  # name the argument (`--of` of springc grad)
            raise UsageError(f"--of {spec}: {err.message}", hint=err.diagnostic.hint) from None
        if r.kind not in SUPPORTED:
            raise UsageError(f"--of {spec}: no gradient for this reduction",
                             hint=f"gradients follow {', '.join(SUPPORTED)} reductions")
        out.append(r)
    return out


def plan(items: list[reductions.Reduction], net: FlatNetlist, h: float, nsteps: int) -> Rows:
    """Lay out the accumulator rows of `items` for a run of nsteps steps of h."""
    rows = Rows()
    for r in items:
        if r.kind in ("dissipated", "loss"):
            lo = len(rows.ds)
            for row, elem in damper_rows(r.spec.partition(":")[2], net):
                rows.ds.append(row)
                rows.ds_elem.append(elem)
            rows.where[r.spec] = slice(lo, len(rows.ds))
        elif r.kind == "msq":
            lo_k, hi_k, count = reductions.msq_window(r, h, nsteps)
            rows.where[r.spec] = len(rows.ms)
            rows.ms.append((r.node, int(r.isv), lo_k, hi_k))
            rows.ms_count.append(count)
        elif r.kind == "gram":
            g = r.gram
            base, first = len(rows.gdecay), len(rows.gp)
            rows.gp += [(i, j, base + grp, w * h)
                        for i, j, grp, w in zip(g.i, g.j, g.group, g.weight)]
            rows.where[r.spec] = (slice(base, base + g.groups), slice(first, len(rows.gp)))
            rows.gdecay += [math.exp(-h / g.tau)] * g.groups
    return rows


def damper_rows(name: str, net: FlatNetlist) -> list:
    """The dampers `name` names (as `reductions.dampers`), each with its element. Local
    dampers with b = 0 are kept: their dissipation is 0 but its derivative in b is not."""
    m, d = net.masses, net.dashpots
    local = [((int(m.node[e]), GROUND, float(m.b[e])), ("M", e)) for e in range(len(m))]
    pots = [((int(d.i[e]), int(d.j[e]), float(d.b[e])), ("B", e)) for e in range(len(d))]
    if name == "all":
        return local + pots
    if name in m.names:
        return [local[m.names.index(name)]]
    if name in d.names:
        return [pots[d.names.index(name)]]
    node = net.node_index(name)  # reductions.parse has checked that the name is known
    return [row for row in local if row[0][0] == node]


def force_positions(net: FlatNetlist, forces) -> list[int]:
    """Positions of force elements in the kernels' work vector (inputs, then shared)."""
    order = sources.input_forces(net) + sources.common_forces(net)
    return [order.index(e) for e in forces]


@dataclass
class Acc:
    """One batch of runs' forward accumulators (runs first) and end states."""

    work: np.ndarray
    diss: np.ndarray
    msq: np.ndarray
    gram: np.ndarray
    x0: np.ndarray
    xf: np.ndarray
    vf: np.ndarray


def values(items, rows: Rows, acc: Acc, net: FlatNetlist, h: float, nsteps: int) -> dict:
    """Each reduction's value per run, as `springc.sim.simulate` finishes it."""
    out = {}
    for r in items:
        match r.kind:
            case "final":
                out[r.spec] = (acc.vf if r.isv else acc.xf)[:, r.node].copy()
            case "msq":
                k = rows.where[r.spec]
                out[r.spec] = acc.msq[:, k] / max(rows.ms_count[k], 1)
            case "work":
                out[r.spec] = acc.work[:, force_positions(net, r.forces)].sum(axis=1)
            case "dissipated":
                out[r.spec] = acc.diss[:, rows.where[r.spec]].sum(axis=1)
            case "loss":
                diss = acc.diss[:, rows.where[r.spec]].sum(axis=1)
                with np.errstate(divide="ignore", invalid="ignore"):
                    out[r.spec] = -10.0 * np.log10(diss / acc.work.sum(axis=1))
            case "gram":
                groups, _ = rows.where[r.spec]
                out[r.spec] = _gram(r, acc.gram[:, groups], acc, h, nsteps)
            case _:
                raise TypeError(f"unhandled reduction kind {r.kind!r}")
    return out


def _gram(r, acc: np.ndarray, a: Acc, h: float, nsteps: int) -> np.ndarray:
    return reductions.gram_finish(r, acc.T, a.x0.T, a.xf.T, h, nsteps * h)


@dataclass
class Seeds:
    """Adjoint seeds per run: final state (fx, fv), per force (ww), damper row (dw),
    mean-square row (msw), Gram pair (gw), and the initial positions' direct part (x0)."""

    fx: np.ndarray
    fv: np.ndarray
    ww: np.ndarray
    dw: np.ndarray
    msw: np.ndarray
    gw: np.ndarray
    x0: np.ndarray


def seeds(items, rows: Rows, acc: Acc, weights: dict, net: FlatNetlist,
          h: float, nsteps: int) -> Seeds:
    """The seeds of sum over reductions of weights[spec] * value (weights per run, and per
    group for a Gram reduction)."""
    runs, n = acc.xf.shape
    s = Seeds(np.zeros((runs, n)), np.zeros((runs, n)), np.zeros(acc.work.shape),
              np.zeros(acc.diss.shape), np.zeros(acc.msq.shape),
              np.zeros((runs, len(rows.gp))), np.zeros((runs, n)))
    for r in items:
        w = weights[r.spec]
        match r.kind:
            case "final":
                (s.fv if r.isv else s.fx)[:, r.node] += w
            case "msq":
                k = rows.where[r.spec]
                s.msw[:, k] += w / max(rows.ms_count[k], 1)
            case "work":
                s.ww[:, force_positions(net, r.forces)] += w[:, None]
            case "dissipated":
                s.dw[:, rows.where[r.spec]] += w[:, None]
            case "loss":  # -10 log10(D / W): dD -> -10/(ln10 D), dW -> 10/(ln10 W)
                diss = acc.diss[:, rows.where[r.spec]].sum(axis=1)
                scale = 10.0 / math.log(10.0)
                s.dw[:, rows.where[r.spec]] += (-scale * w / diss)[:, None]
                s.ww += (scale * w / acc.work.sum(axis=1))[:, None]
            case "gram":
                _gram_seeds(r, rows, acc, w, s, h, nsteps)
            case _:
                raise TypeError(f"unhandled reduction kind {r.kind!r}")
    return s


def _gram_seeds(r, rows: Rows, acc: Acc, w: np.ndarray, s: Seeds, h: float,
                nsteps: int) -> None:
    """Seeds of a Gram reduction (w: (runs, groups)): every step's product through the
    kernels' rectangle sums, less the trapezoid's half end terms (`gram_finish`)."""
    g = r.gram
    _, pairs = rows.where[r.spec]
    end0 = math.exp(-nsteps * h / g.tau)
    for p, (i, j, grp, wt) in enumerate(zip(g.i, g.j, g.group, g.weight)):
        wg = w[:, grp]
        s.gw[:, pairs.start + p] += wg
        half = 0.5 * h * wt * wg
        s.fx[:, i] -= half * acc.xf[:, j]
        s.fx[:, j] -= half * acc.xf[:, i]
        s.x0[:, i] -= half * end0 * acc.x0[:, j]
        s.x0[:, j] -= half * end0 * acc.x0[:, i]


def weights_for(items, given: Mapping | None, runs: int) -> dict:
    """Per-run (and per-group) weight arrays of each reduction: given ones broadcast to the
    value's shape, (runs,) or (runs, groups), else 1."""
    given = dict(given or {})
    unknown = set(given) - {r.spec for r in items}
    if unknown:
        raise UsageError(f"weights for reductions not asked for: {', '.join(sorted(unknown))}")
    out = {}
    for r in items:
        shape = (runs, r.gram.groups) if r.kind == "gram" else (runs,)
        try:
            w = np.broadcast_to(np.asarray(given.get(r.spec, 1.0), np.float64), shape)
        except ValueError:
            raise UsageError(f"weights for {r.spec} do not fit its shape {shape}") from None
        out[r.spec] = w.copy()
    return out
