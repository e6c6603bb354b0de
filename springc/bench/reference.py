"""Peers of the generated kernels: plain numpy RK4 on `springc.lang.physics`, and scipy `solve_ivp`.

Both use the runtime's forcing conventions (`springc.sim.sources`): input signals sampled at
1/tstep, interpolated linearly in time and 0 after their end; analytic sources exact. They are
slow and obviously correct; tests and `springc bench` compare the kernels against them.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.integrate import solve_ivp

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


def _accel(net: FlatNetlist, minv: np.ndarray, x, v, fext) -> np.ndarray:
    return minv[:, None] * (physics.internal_force(net, x) + physics.damping_force(net, v) + fext)


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
    minv = 1.0 / net.mass()
    x0, v0 = net.initial_state()
    runs = 1 if inputs is None else inputs.shape[0]
    x, v = np.repeat(x0[:, None], runs, 1), np.repeat(v0[:, None], runs, 1)
    recs = [_pick(x, v, probes)]
    for step in range(nsteps):
        x, v = _rk_step(net, tab, minv, force, x, v, step * h, h)
        if (step + 1) % rec_every == 0:
            recs.append(_pick(x, v, probes))
    rec = np.stack(recs, axis=-1)  # (probes, runs, T)
    t = np.arange(rec.shape[-1]) * rec_every * h
    return t, {p.label: rec[k] for k, p in enumerate(probes)}, (x, v)


def _rk_step(net, tab, minv, force, x, v, t, h):
    kx, kv = [], []
    for s in range(tab.stages):
        xs = x + h * sum((a * kx[j] for j, a in enumerate(tab.a[s])), np.zeros_like(x))
        vs = v + h * sum((a * kv[j] for j, a in enumerate(tab.a[s])), np.zeros_like(v))
        kx.append(vs)
        kv.append(_accel(net, minv, xs, vs, force(t + tab.c[s] * h)))
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
    minv = 1.0 / net.mass()
    n = net.n

    def rhs(t, y):
        x, v = y[:n, None], y[n:, None]
        return np.concatenate([y[n:], _accel(net, minv, x, v, force(t))[:, 0]])

    x0, v0 = net.initial_state()
    sol = solve_ivp(rhs, (0.0, t_eval[-1]), np.concatenate([x0, v0]), method=method,
                    t_eval=t_eval, rtol=rtol, atol=atol, max_step=max_step or tstep / 8)
    if not sol.success:
        raise RuntimeError(f"solve_ivp failed: {sol.message}")
    out = {p.label: sol.y[p.node + (n if p.quantity == "v" else 0)][None, :] for p in probes}
    return sol.t, out, sol
