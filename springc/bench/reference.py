"""Peers of the generated kernels: plain numpy RK4 on `springc.lang.physics`, and scipy `solve_ivp`.

Both use the runtime's forcing conventions (`springc.sim.sources`): input signals sampled at
1/tstep, interpolated linearly in time and 0 after their end; analytic sources exact. They are
slow and obviously correct; tests and `springc bench` compare the kernels against them.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.sparse as sp
from scipy.integrate import solve_ivp

from springc.check import linear
from springc.lang import physics
from springc.sim import sources
from springc.kernels.integrators import get_tableau
from springc.lang.ir import FlatNetlist, Probe


def forcing(net: FlatNetlist, inputs: np.ndarray | None,
            tstep: float) -> Callable[[float], np.ndarray]:
    """f(t) -> external force per node, shape (n, runs); `inputs` is (runs, channels, samples)
    on the input grid 1/tstep (None: one run without input signals)."""
    runs = 1 if inputs is None else inputs.shape[0]
    f = net.forces
    rate = 1.0 / tstep
    wavs = {e: sources.load_audio(s.path, rate, 0) for e, s in enumerate(f.source)
            if s.kind == "wav"}

    def force(t: float) -> np.ndarray:
        out = np.zeros((net.n, runs))
        for e, src in enumerate(f.source):
            if src.kind == "in":
                if inputs is None or src.channel >= inputs.shape[1]:
                    continue
                val = _interp_rows(inputs[:, src.channel], rate, t)
            elif src.kind == "wav":
                val = sources.interpolate(wavs[e], rate, t)
            else:
                val = sources.analytic(src, np.float64(t))
            out[f.node[e]] += f.gain[e] * val
        return out

    return force


def _interp_rows(rows: np.ndarray, rate: float, t: float) -> np.ndarray:
    """Linear interpolation of every row (runs, samples) at one time t; 0 after the end."""
    pos = t * rate
    k = int(np.floor(pos))
    frac = pos - k
    at = lambda i: rows[:, i] if 0 <= i < rows.shape[1] else np.zeros(rows.shape[0])  # noqa
    return (1.0 - frac) * at(k) + frac * at(k + 1)


class Equations:
    """The accelerations of `springc.lang.physics` (internal plus damping plus external force,
    over mass) assembled once for an integrator's many calls: the linear terms (springs,
    couplings, dampers, dashpots) as one stiffness and one damping matrix from the checks'
    entries (`springc.check.linear`), the nonlinear terms gathered into their nodes by
    incidence matrices (sparse above `DENSE_MAX` nodes). The same sums as the physics functions
    up to round-off (tests/test_reference.py); a call on a one-mass network takes a tenth of
    their time (2.8 against 32.5 us, where an `np.add.at` per term kind dominated), on three
    masses with a P element about half (the P elements are still summed term by term)."""

    DENSE_MAX = 100

    def __init__(self, net: FlatNetlist) -> None:
        n = net.n
        self.net, self.minv = net, 1.0 / net.mass()
        self.k = self._matrix(*map(np.concatenate, linear.spring_entries(net)), n)
        self.b = self._matrix(*map(np.concatenate, linear.damping_entries(net)), n)
        d, q = net.duffings, net.quads
        self.at_duffing = self._incidence(d.node, n)
        self.at_qi, self.at_qj = self._incidence(q.i, n), self._incidence(q.j, n)
        # the per-element coefficients as columns against (elements, runs), once
        self.dl, self.qa, self.qg = d.l[:, None], q.a[:, None], q.g[:, None]
        self.qgi = (2 * q.g / q.a)[:, None]

    def __call__(self, x: np.ndarray, v: np.ndarray, fext: np.ndarray) -> np.ndarray:
        """Accelerations for positions and velocities (n, runs) and external forces (n, runs)."""
        net = self.net
        f = fext - self.k @ x - self.b @ v
        d, q, p = net.duffings, net.quads, net.monomials
        if len(d.node):
            f -= self.at_duffing @ (self.dl * x[d.node] ** 3)
        if len(q.i):
            qs = x[q.i] ** 2 - self.qa * x[q.j]
            f -= self.at_qi @ (self.qgi * x[q.i] * qs)
            f += self.at_qj @ (self.qg * qs)
        if len(p):
            f += physics.monomial_force(net, x)
        return self.minv[:, None] * f

    def _matrix(self, rows: np.ndarray, cols: np.ndarray, vals: np.ndarray, n: int,
                width: int | None = None):
        """The (n, width or n) matrix of the summed (row, col, value) entries."""
        shape = (n, n if width is None else width)
        if n <= self.DENSE_MAX:
            out = np.zeros(shape)
            np.add.at(out, (rows, cols), vals)
            return out
        return sp.csr_matrix((vals, (rows, cols)), shape=shape)

    def _incidence(self, nodes: np.ndarray, n: int):
        """(n, elements), 1 where element e acts on its node: per-element forces onto nodes."""
        return self._matrix(nodes, np.arange(len(nodes)), np.ones(len(nodes)), n, len(nodes))


def rk4_numpy(net: FlatNetlist, inputs: np.ndarray | None = None, *, tstep: float,
              tstop: float, substeps: int = 1, method: str = "rk4",
              probes: list[Probe] | None = None, rec_every: int | None = None):
    """Explicit Runge-Kutta (any tableau) in vectorised numpy over runs.

    Returns (t, {label: (runs, T)}, (x_final, v_final)); recording as in `springc.sim.simulate`."""
    tab = get_tableau(method)
    h = tstep / substeps
    nsteps = int(round(tstop / h))
    rec_every = rec_every or substeps
    probes = net.probes if probes is None else probes
    force = forcing(net, inputs, tstep)
    accel = Equations(net)
    x0, v0 = net.initial_state()
    runs = 1 if inputs is None else inputs.shape[0]
    x, v = np.repeat(x0[:, None], runs, 1), np.repeat(v0[:, None], runs, 1)
    recs = [_pick(x, v, probes)]
    for step in range(nsteps):
        x, v = _rk_step(tab, accel, force, x, v, step * h, h)
        if (step + 1) % rec_every == 0:
            recs.append(_pick(x, v, probes))
    rec = np.stack(recs, axis=-1)  # (probes, runs, T)
    t = np.arange(rec.shape[-1]) * rec_every * h
    return t, {p.label: rec[k] for k, p in enumerate(probes)}, (x, v)


def _rk_step(tab, accel: Equations, force, x, v, t, h):
    kx, kv = [], []
    for s in range(tab.stages):
        xs = x + h * sum((a * kx[j] for j, a in enumerate(tab.a[s])), np.zeros_like(x))
        vs = v + h * sum((a * kv[j] for j, a in enumerate(tab.a[s])), np.zeros_like(v))
        kx.append(vs)
        kv.append(accel(xs, vs, force(t + tab.c[s] * h)))
    x = x + h * sum(b * k for b, k in zip(tab.b, kx))
    v = v + h * sum(b * k for b, k in zip(tab.b, kv))
    return x, v


def _pick(x, v, probes) -> np.ndarray:
    return np.stack([(v if p.quantity == "v" else x)[p.node] for p in probes]) if probes \
        else np.zeros((0, x.shape[1]))


def solve_ivp_reference(net: FlatNetlist, inputs: np.ndarray | None = None, *, tstep: float,
                        tstop: float, t_eval: np.ndarray | None = None, method: str = "DOP853",
                        rtol: float = 1e-10, atol: float = 1e-14,
                        probes: list[Probe] | None = None, max_step: float | None = None):
    """scipy `solve_ivp` of the same equations for one run (`inputs` (1, channels, samples)).

    Returns (t, {label: (1, T)}, sol) with the probes at `t_eval` (default every tstep).
    `max_step` defaults to tstep / 8: the linearly interpolated inputs have a kink at every
    sample, which the step-size control alone steps over with a visible error (2e-8 relative
    at rtol 1e-10 with max_step = tstep; 2e-14 with tstep / 10)."""
    probes = net.probes if probes is None else probes
    t_eval = np.arange(int(round(tstop / tstep)) + 1) * tstep if t_eval is None else t_eval
    force = forcing(net, inputs, tstep)
    accel = Equations(net)
    n = net.n

    def rhs(t, y):
        x, v = y[:n, None], y[n:, None]
        return np.concatenate([y[n:], accel(x, v, force(t))[:, 0]])

    x0, v0 = net.initial_state()
    sol = solve_ivp(rhs, (0.0, t_eval[-1]), np.concatenate([x0, v0]), method=method,
                    t_eval=t_eval, rtol=rtol, atol=atol, max_step=max_step or tstep / 8)
    if not sol.success:
        raise RuntimeError(f"solve_ivp failed: {sol.message}")
    out = {p.label: sol.y[p.node + (n if p.quantity == "v" else 0)][None, :] for p in probes}
    return sol.t, out, sol
