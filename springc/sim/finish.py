"""The finishing of a simulation: each reduction from the sums a kernel call left, and the
diagnosis of a run that diverged (`DivergedRuns`, with the likely cause)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from springc.errors import DivergedRuns
from springc.kernels import expint
from springc.kernels.integrators import max_stable_step
from springc.lang import physics
from springc.lang.ir import FlatNetlist
from springc.sim import reductions

if TYPE_CHECKING:
    from springc.sim.timegrid import Settings

LIMITS = {"float64": 1e30, "float32": 1e15}  # |x| or |v| beyond this counts as divergence


def finish_reductions(net, rplan, args, work, wins, st, members=None,
                       nets=None) -> dict[str, np.ndarray]:
    xf, vf = args["xf"].astype(np.float64), args["vf"].astype(np.float64)
    out: dict[str, np.ndarray] = {}
    msq_rows = {r.spec: k for k, r in enumerate(rplan.msq)}
    for r in rplan.items:
        match r.kind:
            case "final":
                out[r.spec] = (vf if r.isv else xf)[r.node].copy()
            case "msq":
                k = msq_rows[r.spec]
                out[r.spec] = args["msq"][k] / max(wins[k][2], 1)
            case "work":
                out[r.spec] = work[list(r.forces)].sum(axis=0)
            case "dissipated":
                out[r.spec] = dissipated(args, rplan, r.spec, xf.shape[-1])
            case "loss":
                diss = dissipated(args, rplan, r.spec, xf.shape[-1])
                with np.errstate(divide="ignore", invalid="ignore"):
                    out[r.spec] = -10.0 * np.log10(diss / work.sum(axis=0))
            case "energy" if members is not None:  # each run's own netlist
                out[r.spec] = np.empty(xf.shape[-1])
                for m in np.unique(members):
                    cols = members == m
                    out[r.spec][cols] = physics.energy(nets[m], xf[:, cols], vf[:, cols])
            case "energy":
                out[r.spec] = physics.energy(net, xf, vf)
            case "gram":
                acc = args["gram"][rplan.gram_slices[r.spec]]
                out[r.spec] = reductions.gram_finish(r, acc, args["x0"].astype(np.float64), xf,
                                                     st.h, st.nsteps * st.h)
            case _:
                raise TypeError(f"unhandled reduction kind {r.kind!r}")
    return out


def dissipated(args, rplan, spec: str, runs: int) -> np.ndarray:
    """Energy dissipated per run in the dampers of `spec` (none in the network: nothing)."""
    rows = rplan.damper_slices.get(spec)
    return np.zeros(runs) if rows is None else args["diss"][rows].sum(axis=0)


def check_divergence(net, st: Settings, args, names, reductions: dict) -> None:
    status = args["status"]
    if not status.any():
        return
    bad = np.flatnonzero(status)
    r = int(bad[0])
    when = status[r] * st.h
    node = net.nodes[int(args["bad_node"][r])]
    more = f" (and {len(bad) - 1} more run(s))" if len(bad) > 1 else ""
    raise DivergedRuns(
        f"run {names[r]} diverged by t = {when:.6g} s: node {node} is NaN, infinite or beyond "
        f"{LIMITS[st.precision]:g}{more}", bad, reductions, hint=likely_cause(net, st))


def likely_cause(net: FlatNetlist, st: Settings) -> str:
    """Why a run may have diverged: the step against the linear stability limit when the
    linearisation is small enough to diagonalise, and the other causes otherwise."""
    others = ("a potential unbounded below (P elements), or an input too large for the "
              "nonlinear elements (their stiffness grows with amplitude)")
    if net.n > 3000:
        return f"a step too large for the integrator, {others}"
    if expint.is_split(st.method):  # the blocks are exact: the split's own limit
        from springc.check.checks import step_limit

        hmax = step_limit(net, st.method).dt
    else:
        hmax, _ = max_stable_step(expint.stage_tableau(st.method), linear_eigenvalues(net))
    if st.h > hmax:
        return (f"unstable step: h = {st.h:.4g} s exceeds the largest stable step "
                f"{hmax:.4g} s of {st.method} for the linearised network; raise --substeps "
                f"to at least {math.ceil(st.tstep / hmax)}")
    return f"h = {st.h:.4g} s is linearly stable (limit {hmax:.4g} s), so likely {others}"


def linear_eigenvalues(net: FlatNetlist) -> np.ndarray:
    """Eigenvalues of the first-order linearisation at rest."""
    minv = 1.0 / net.mass()
    n = net.n
    a = np.zeros((2 * n, 2 * n))
    a[:n, n:] = np.eye(n)
    a[n:, :n] = -minv[:, None] * physics.stiffness_matrix(net)
    a[n:, n:] = -minv[:, None] * physics.damping_matrix(net)
    return np.linalg.eigvals(a)
