"""Gradients of reductions: `coefficient_gradient` (a checked netlist in, d reduction /
d every element coefficient out) and `gradient` (a netlist file's `.param` values in,
d reduction / d each named parameter out), both batched over runs like `simulate`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from springc.check import check
from springc.check.checks import CheckedNetlist, require_checked
from springc.check.points import at_point
from springc.errors import CheckError, UsageError
from springc.grad import lanes, model, seeds, written
from springc.grad.params import ParamNetlist
from springc.kernels import expint
from springc.kernels.integrators import get_tableau
from springc.lang.draws import Sample
from springc.lang.ir import FlatNetlist
from springc.lang.variation import PointSet
from springc.sim import execute
from springc.sim import simulate as sim
from springc.sim import sources


@dataclass
class CoefficientGradient:
    """Reductions and the gradient of their weighted sum per run: `values[spec]` (runs,) or
    (runs, groups); `coefficients[(table, field)]` (runs, elements), keyed as
    `springc.grad.params.COEFFICIENTS`; `info`: settings, checkpoint interval, timings."""

    values: dict[str, np.ndarray]
    coefficients: dict[tuple[str, str], np.ndarray]
    runs: list[str]
    info: dict = field(default_factory=dict)


@dataclass
class GradResult:
    """`values[spec]` per run; `grad[run, k]` = d(sum of weighted reductions)/d wrt[k]."""

    of: list[str]
    wrt: list[str]
    values: dict[str, np.ndarray]
    grad: np.ndarray
    runs: list[str]
    params: dict[str, float]
    info: dict = field(default_factory=dict)
    points: tuple | None = None  # with .step/.mc: each point (`at_points`)


def gradient(source: ParamNetlist | str | Path, of: str | Sequence[str], wrt: Sequence[str],
             inputs=None, input_rate: float | None = None, *,
             values: Mapping[str, float] | None = None, weights: Mapping | None = None,
             sample: Sample | None = None, **settings) -> GradResult:
    """d/d(param) of the reductions `of` (specs as `springc sim --reduce`; several: their
    sum, each times `weights[spec]`, per run) for every top-level `.param` of `wrt`, at the
    parameter `values` (others as the file sets them), in Monte Carlo `sample` if given (every
    draw's unit deviate held fixed, so d gauss(nom, rvar) / d nom = draw / nom). The netlist at
    those values must pass
    the checks (`CheckError` otherwise). `inputs`, `input_rate` and the settings (tstep,
    tstop, substeps, method, channel, every) as `coefficient_gradient`."""
    pn = source if isinstance(source, ParamNetlist) else ParamNetlist.load(source)
    specs = [of] if isinstance(of, str) else list(of)
    pn.require(list(wrt))
    t0 = time.perf_counter()
    net = pn.netlist(values, sample)
    jac = pn.jacobian(values, wrt, sample)
    # the adjoint integrates at the configured step (it chooses none): judged always
    checked = check(net, settings.get("method"), tstep=settings.get("tstep"),
                    substeps=settings.get("substeps"), judge_step=True)
    t1 = time.perf_counter()
    cg = coefficient_gradient(checked, specs, inputs, input_rate, weights=weights, **settings)
    grad = np.stack([_chain(cg.coefficients, jac[name]) for name in wrt], axis=1)
    params = {**pn.values, **dict(values or {})}
    info = dict(cg.info, elaborate_s=t1 - t0)
    return GradResult(specs, list(wrt), cg.values, grad, cg.runs, params, info)


def at_points(source: ParamNetlist, points: PointSet, of: str | Sequence[str],
              wrt: Sequence[str], inputs=None, input_rate: float | None = None,
              **settings) -> GradResult:
    """`gradient` at every point of a `.step` netlist (each point's step values set, the
    other parameters as the file sets them): `values[spec]` (points, runs), `grad[point,
    run, k]`, `points` the points. An error at one point names it. At a Monte Carlo sample
    each draw's unit deviate is held fixed (`gradient`'s `sample`): the derivative of that
    fabricated device."""
    results = []
    for point in points.points:
        sample = None if point.sample is None else Sample(point.sample, point.seed)
        try:
            results.append(gradient(source, of, wrt, inputs, input_rate,
                                    values=dict(point.steps), sample=sample, **settings))
        except CheckError as err:
            raise at_point(err, point, len(points)) from None
        except UsageError as err:
            raise UsageError(f"{err.message} at {point.describe(len(points))}", err.loc,
                             err.diagnostic.hint) from None
    first = results[0]
    values = {k: np.stack([r.values[k] for r in results]) for k in first.values}
    grad = np.stack([r.grad for r in results])
    info = dict(first.info, points=[r.info for r in results])
    return GradResult(first.of, first.wrt, values, grad, first.runs, dict(source.values), info,
                      points.points)


def _chain(dcoef: dict, dparam: dict) -> np.ndarray:
    """sum over coefficients of d reduction / d coefficient * d coefficient / d param."""
    return sum(dcoef[key] @ dparam[key] for key in dcoef)


def coefficient_gradient(checked: CheckedNetlist, of: Sequence[str], inputs=None,
                         input_rate: float | None = None, *, weights: Mapping | None = None,
                         tstep=None, tstop=None, substeps=None, method=None,
                         channel: int | None = None, every: int | None = None,
                         check_step: bool = True) -> CoefficientGradient:
    """Values of the reductions `of` and the gradient of sum(weights[spec] * value) with
    respect to every element coefficient, per run, for the float64 computation `simulate`
    does with the same arguments (Runge-Kutta methods; inputs as `simulate` takes them).
    `every`: steps between checkpoints (default: all steps in one segment when its stages
    fit in `MEMORY`, else about sqrt(steps)). `check_step`: refuse a step above the
    stability limit, as `simulate` does."""
    net = require_checked(checked, "coefficient_gradient").net
    tstep0 = tstep or (net.tran.tstep if net.tran else None)
    # the simulator's own gathering of inputs: the same resampling, run names and stop time
    signals, names, seconds = sim._gather_inputs(net, inputs, input_rate, tstep0, channel)
    st = sim.settings(net, tstep, tstop, substeps, method, "float64", None, seconds)
    if expint.is_split(st.method):
        raise UsageError(f"no gradient through the split scheme {st.method}",
                         hint="use a Runge-Kutta method (rk4, rk38, ...)")
    if check_step:
        checked.require_stable(st.method, st.h, st.substeps)
    items = seeds.parse(list(of), net)
    w = seeds.weights_for(items, weights, len(names))
    job = _Job(net, st, items, signals, len(names), every)
    start = time.perf_counter()
    vals, coefs = job.run(w)
    _require_finite(vals, names)
    info = dict(settings=st, every=job.every, lanes=job.lanes, written=job.written,
                wall_s=time.perf_counter() - start)
    return CoefficientGradient(vals, coefs, names, info)


def _require_finite(vals: dict, names: list[str]) -> None:
    for spec, v in vals.items():
        bad = ~np.isfinite(v.reshape(len(names), -1)).all(axis=1)
        if bad.any():
            raise UsageError(f"{spec} is not finite for run {names[int(np.flatnonzero(bad)[0])]}"
                             " (a diverged run, or a logarithm of zero work or dissipation)")


MEMORY = 2**22  # bytes of stage buffers per chunk below which nothing is recomputed (more
# is slower to write and read back than the recomputation, which stays in the caches)


class _Job:
    """One gradient computation: its arrays, and each chunk's forward and reverse sweeps."""

    def __init__(self, net: FlatNetlist, st: sim.Settings, items, signals, runs: int,
                 every: int | None) -> None:
        self.net, self.st, self.items, self.runs = net, st, items, runs
        self.md = model.build(net)
        tab = get_tableau(st.method)
        s = tab.stages
        self.ta = np.zeros((s, s))
        for i, row in enumerate(tab.a):
            self.ta[i, :len(row)] = row
        self.tb, self.tc = np.array(tab.b, np.float64), np.array(tab.c, np.float64)
        g = sources.common_table(net, st.nsteps, st.h, st.tstep, tab)
        self.gtab = np.ascontiguousarray(g if g.shape[2] else np.zeros((st.nsteps, s, 0)))
        self.nch = sources.channels_used(net)
        self.u = sources.kernel_inputs(signals, runs, self.nch, st.nsteps // st.substeps + 1,
                                       np.float64)
        self.rows = seeds.plan(items, net, st.h, st.nsteps)
        self.ds, self.ms, self.gp, self.gdecay = self.rows.arrays()
        # as wide as the runs allow while every core gets a chunk
        per_thread = -(-runs // execute.threads())
        self.written = written.eligible(net)
        if self.written:
            self.lanes = written.choose_lanes(per_thread)
            self.shape = written.structure(self.md, self.ds, tab, self.lanes)
            self.kernels = lanes.load_source(written.source(self.shape), "springc_grad_written")
            self.cf = written.coefficients(self.md, self.ds)
            per_step = 2 * net.n * self.lanes * 8
        else:
            self.lanes = lanes.choose(per_thread)
            self.kernels = lanes.module(self.lanes)
            per_step = s * (3 * net.n + max(self.nch, 1)) * self.lanes * 8
        whole = st.nsteps * per_step <= MEMORY
        self.every = int(every or (st.nsteps if whole else max(1, math.isqrt(st.nsteps))))

    def run(self, weights: dict) -> tuple[dict, dict]:
        """Values (runs, ...) and coefficient gradients (runs, elements) of every chunk."""
        bounds = list(range(0, self.runs, self.lanes))
        parts = [None] * len(bounds)

        def one(c: int) -> None:
            lo = bounds[c]
            parts[c] = self.chunk(lo, min(self.runs, lo + self.lanes), weights)

        execute.on_threads(len(bounds), one)
        vals = {k: np.concatenate([p[0][k] for p in parts]) for k in parts[0][0]}
        coefs = {k: np.concatenate([p[1][k] for p in parts]) for k in parts[0][1]}
        return vals, coefs

    def chunk(self, lo: int, hi: int, weights: dict) -> tuple[dict, dict]:
        """Runs lo..hi-1 (padded to the lanes with copies of the last): forward, seeds,
        reverse; their values and coefficient gradients."""
        take = np.minimum(np.arange(lo, lo + self.lanes), hi - 1)
        acc, buffers = self.forward(take)
        st, keep = self.st, hi - lo
        vals = seeds.values(self.items, self.rows, acc, self.net, st.h, st.nsteps)
        w = {k: np.where(_lane_mask(take, v.ndim), v[take], 0.0) for k, v in weights.items()}
        sd = seeds.seeds(self.items, self.rows, acc, w, self.net, st.h, st.nsteps)
        coefs = self.reverse(take, acc, sd, buffers)
        return ({k: v[:keep] for k, v in vals.items()}, {k: v[:keep] for k, v in coefs.items()})

    def forward(self, take: np.ndarray) -> tuple[seeds.Acc, tuple]:
        """The forward sweep of one chunk (lanes = runs `take`): accumulators (run first),
        and the checkpoints and stage buffers its reverse sweep reads."""
        if self.written:
            return self.forward_written(take)
        n, nl, st, S = self.net.n, self.lanes, self.st, len(self.tc)
        x0, v0 = self.net.initial_state()
        x, v = np.repeat(x0[:, None], nl, 1), np.repeat(v0[:, None], nl, 1)
        u = np.ascontiguousarray(self.u[take].transpose(1, 2, 0))
        nf = len(self.md.fi_node) + len(self.md.fc_node)
        work, diss = np.zeros((nf, nl)), np.zeros((len(self.ds), nl))
        msq, gram = np.zeros((len(self.ms), nl)), np.zeros((len(self.gdecay), nl))
        cps = np.zeros(((st.nsteps - 1) // self.every + 1, 2, n, nl))
        X, V, KV = (np.zeros((self.every, S, n, nl)) for _ in range(3))
        UC = np.zeros((self.every, S, max(self.nch, 1), nl))
        lanes.call(self.kernels, "forward", self.md, self.ta, self.tb, self.tc, st.h,
                   st.nsteps, st.substeps, x, v, u, self.gtab, self.every, cps, X, V, KV, UC,
                   self.ds, self.ms, self.gp, self.gdecay, work, diss, msq, gram)
        acc = seeds.Acc(work.T.copy(), diss.T.copy(), msq.T.copy(), gram.T.copy(),
                        np.tile(x0, (nl, 1)), x.T.copy(), v.T.copy())
        return acc, (u, cps, X, V, KV, UC)

    def reverse(self, take: np.ndarray, acc: seeds.Acc, sd: seeds.Seeds, buffers: tuple
                ) -> dict:
        """The adjoint sweep of one chunk; the gradient per element coefficient (lane, ...)."""
        if self.written:
            return self.reverse_written(acc, sd, buffers)
        st, nl = self.st, self.lanes
        u, cps, X, V, KV, UC = buffers
        gr = np.zeros((int(self.md.off[-1]), nl))
        dgr = np.zeros((len(self.ds), nl))
        lane = lambda a: np.ascontiguousarray(a.T)  # noqa: E731  (run, row) -> (row, lane)
        xb, vb = lane(sd.fx), lane(sd.fv)
        lanes.call(self.kernels, "reverse", self.md, self.ta, self.tb, self.tc, st.h,
                   st.nsteps, st.substeps, u, self.gtab, self.every, cps, X, V, KV, UC,
                   lane(acc.xf), lane(acc.vf), self.ds, self.ms, self.gp, self.gdecay,
                   lane(sd.ww), lane(sd.dw), lane(sd.msw), lane(sd.gw), xb, vb, gr, dgr)
        return self.coefficients(gr.T, dgr, sd.x0)

    def forward_written(self, take: np.ndarray) -> tuple[seeds.Acc, tuple]:
        """`forward` with the written-out kernels (`springc.grad.written`)."""
        n, nl, st = self.net.n, self.lanes, self.st
        nf = len(self.md.fi_node) + len(self.md.fc_node)
        x0, v0 = self.net.initial_state()
        W = np.zeros((written.rows(written.forward_blocks(self.shape)), nl))
        W[:n], W[n:2 * n] = x0[:, None], v0[:, None]
        u = np.ascontiguousarray(self.u[take].transpose(1, 2, 0))
        msq, gram = np.zeros((len(self.ms), nl)), np.zeros((len(self.gdecay), nl))
        cps = np.zeros(((st.nsteps - 1) // self.every + 1, 2 * n, nl))
        SS = np.zeros((self.every + 1, 2 * n, nl))
        lanes.call(self.kernels, "forward", self.cf, st.h, st.nsteps, st.substeps, W.reshape(-1), u,
                   self.gtab, self.every, cps, SS, self.ms, msq, self.gp, self.gdecay, gram)
        end = 2 * n + nf + len(self.ds)
        acc = seeds.Acc(W[2 * n:2 * n + nf].T.copy(), W[2 * n + nf:end].T.copy(), msq.T.copy(),
                        gram.T.copy(), np.tile(x0, (nl, 1)), W[:n].T.copy(),
                        W[n:2 * n].T.copy())
        return acc, (u, cps, SS)

    def reverse_written(self, acc: seeds.Acc, sd: seeds.Seeds, buffers: tuple) -> dict:
        """`reverse` with the written-out kernels."""
        n, st, off = self.net.n, self.st, self.md.off
        u, cps, SS = buffers
        lane = lambda a: np.ascontiguousarray(a.T)  # noqa: E731  (run, row) -> (row, lane)
        wrow, drow, _ = written.adjoint_rows(self.shape)
        A = np.zeros((written.rows(written.reverse_blocks(self.shape)), self.lanes))
        A[:n], A[n:2 * n] = lane(sd.fx), lane(sd.fv)
        A[wrow:drow], A[drow:drow + len(self.ds)] = lane(sd.ww), lane(sd.dw)
        lanes.call(self.kernels, "reverse", self.cf, st.h, st.nsteps, st.substeps, u,
                   self.gtab, self.every, cps, SS, A.reshape(-1), self.ms, lane(sd.msw), self.gp,
                   lane(sd.gw), self.gdecay, np.ones(len(self.gp)))
        gr = A[2 * n:2 * n + int(off[-1])]
        gr[off[model.X0]:off[model.X0 + 1]] += A[:n]
        gr[off[model.V0]:off[model.V0 + 1]] += A[n:2 * n]
        return self.coefficients(gr.T, A[2 * n + int(off[-1]):wrow], sd.x0)

    def coefficients(self, gr: np.ndarray, dgr: np.ndarray, x0: np.ndarray) -> dict:
        """The kernels' gradient rows (lane, row), damper rows (row, lane) and the initial
        positions' direct seeds (lane, node) per element coefficient (lane, element)."""
        gr = np.array(gr)
        gr[:, self.md.off[model.X0]:self.md.off[model.X0 + 1]] += x0
        coefs = model.to_elements(self.net, self.md, gr)
        for row, (letter, e) in enumerate(self.rows.ds_elem):
            key = ("masses", "b") if letter == "M" else ("dashpots", "b")
            coefs[key] = coefs[key].copy()
            coefs[key][:, e] += dgr[row]
        return coefs


def _lane_mask(take: np.ndarray, ndim: int) -> np.ndarray:
    """True for the lanes that hold a run of their own (padding lanes get zero weight)."""
    first = np.r_[True, take[1:] != take[:-1]]
    return first.reshape((-1,) + (1,) * (ndim - 1))


