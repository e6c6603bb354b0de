"""Generic GPU ODE peers of the CUDA form, on the same network, the same inputs and the same
scheme: JAX (jit + vmap + lax.scan of classic RK4) and diffrax (diffeqsolve with the RK4
tableau at the same constant step), built from the kernel netlist's element tables
(`springc.sim.marshal.coefficient_arrays`), the input interpolated linearly between
samples as the kernels do. Equal error: each peer's final positions against springc's (the
same scheme and step, so they agree to round-off where the peer is right).

    python scripts/gpu_peers.py --network "pipeline features 8x3" --runs 10000 --json p.json

Prints runs per second of springc's CUDA form, JAX and diffrax (float64; float32 with
--precision), each after a compiling call, and the peers' largest final-position
difference from springc's over the largest final position.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from springc.bench import suite  # noqa: E402
from springc.check import check  # noqa: E402
from springc.kernels import cuda as cudagen  # noqa: E402
from springc.kernels.lower import kernel_netlist  # noqa: E402
from springc.sim import gpu, marshal, sources  # noqa: E402
from springc.sim import simulate as sm  # noqa: E402


def accel_fn(net, dtype):
    """a(x, v, u, t) for one run from the kernel netlist's tables, in jax.numpy: the own
    terms, stiffness rows, inputs, quadratic couplings, Duffing terms, dashpots and `sin`
    drives (the bench networks' kinds; monomials and other shared signals are refused)."""
    import jax.numpy as jnp

    knet = kernel_netlist(net)
    co = marshal.coefficient_arrays(knet, dtype)
    if len(knet.monomials):
        raise ValueError("monomials: not in the bench networks, not rendered here")
    j = {k: jnp.asarray(v) for k, v in co.items()}
    rows = np.repeat(np.arange(knet.n), np.diff(co["l_ptr"].astype(np.int64)))
    fi_node = np.asarray(co["fi_node"], np.int64)
    drives = _sin_drives(knet)
    b_j = np.asarray(co["b_j"], np.int64)
    ground = b_j < 0

    def accel(x, v, u, t):
        a = -(j["bm"] * v + j["km"] * x)
        if len(rows):
            a = a.at[rows].add(j["l_val"] * x[np.asarray(co["l_col"], np.int64)])
        if len(fi_node):
            a = a.at[fi_node].add(j["fi_gm"] * u[np.asarray(co["fi_chan"], np.int64)])
        a = _nonlinear_terms(a, x, v, j, co, b_j, ground)
        for node, amp, w, phase in drives:
            a = a.at[node].add(amp * jnp.sin(w * t + phase))
        return a

    return accel, knet


def _sin_drives(knet) -> list[tuple]:
    """(node, amplitude over mass, angular frequency, phase) of each `sin` drive among the
    shared signals; any other shared signal is refused."""
    drives = []
    for e in sources.common_forces(knet):
        src = knet.forces.source[e]
        if src.kind != "sin":
            raise ValueError(f"shared signal {src.kind}: not rendered here")
        phase = src.args[2] if len(src.args) > 2 else 0.0
        gm = float(knet.forces.gain[e] / knet.mass()[knet.forces.node[e]])
        drives.append((int(knet.forces.node[e]), gm * src.args[0], 2 * np.pi * src.args[1],
                       phase))
    return drives


def _nonlinear_terms(a, x, v, j: dict, co: dict, b_j: np.ndarray, ground: np.ndarray):
    """`a` plus the quadratic couplings, Duffing terms and dashpots (`b_j` < 0: to ground)."""
    import jax.numpy as jnp

    if len(co["q_i"]):
        qi, qj = (np.asarray(co[k], np.int64) for k in ("q_i", "q_j"))
        s = x[qi] * x[qi] - j["q_a"] * x[qj]
        a = a.at[qi].add(-j["q_gi"] * x[qi] * s).at[qj].add(j["q_gj"] * s)
    if len(co["d_node"]):
        dn = np.asarray(co["d_node"], np.int64)
        a = a.at[dn].add(-j["d_lm"] * x[dn] ** 3)
    if len(b_j):
        bi = np.asarray(co["b_i"], np.int64)
        other = jnp.where(ground, 0.0, v[np.where(ground, 0, b_j)])
        r = v[bi] - other
        a = a.at[bi].add(-j["b_bi"] * r).at[np.where(ground, 0, b_j)].add(
            jnp.where(ground, 0.0, j["b_bj"] * r))
    return a


def input_at(u, k0, frac):
    """Linear interpolation of one run's samples u (channels, samples) at k0 + frac."""
    return (1 - frac) * u[:, k0] + frac * u[:, k0 + 1]


def jax_rk4(net, tstep, substeps, nsteps, dtype):
    """A jitted (runs' inputs) -> final positions: lax.scan of RK4 steps, vmap over runs."""
    import jax
    import jax.numpy as jnp

    accel, knet = accel_fn(net, dtype)
    h = tstep / substeps
    x0, v0 = (jnp.asarray(a, dtype) for a in knet.initial_state())

    def one(u):
        def f(x, v, k, frac):
            t = (k * substeps + frac * substeps) * h
            return accel(x, v, input_at(u, k, frac), t)

        def step(state, i):
            x, v = state
            k = i // substeps
            c0 = (i % substeps) / substeps
            dc = 1.0 / substeps
            return _rk4_step(f, x, v, h, k, c0, dc), None

        (x, _), _ = jax.lax.scan(step, (x0, v0), jnp.arange(nsteps))
        return x

    return jax.jit(jax.vmap(one))


def _rk4_step(f, x, v, h: float, k, c0, dc: float) -> tuple:
    """One classic RK4 step of x'' = f(x, v, sample k, fraction c) from fraction c0 of sample
    k, a fraction dc of it long: the new (x, v)."""
    k1 = f(x, v, k, c0)
    x2, v2 = x + 0.5 * h * v, v + 0.5 * h * k1
    k2 = f(x2, v2, k, c0 + 0.5 * dc)
    x3, v3 = x + 0.5 * h * v2, v + 0.5 * h * k2
    k3 = f(x3, v3, k, c0 + 0.5 * dc)
    x4, v4 = x + h * v3, v + h * k3
    k4 = f(x4, v4, k, c0 + dc)
    xn = x + h / 6 * (v + 2 * v2 + 2 * v3 + v4)
    vn = v + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return xn, vn


def diffrax_rk4(net, tstep, substeps, nsteps, dtype):
    """The same with diffrax.diffeqsolve: an RK4 Butcher tableau, constant step h."""
    import diffrax
    import jax
    import jax.numpy as jnp

    accel, knet = accel_fn(net, dtype)
    h = tstep / substeps
    n = knet.n
    y0 = jnp.concatenate([jnp.asarray(a, dtype) for a in knet.initial_state()])

    def one(u):
        def f(t, y, args):
            pos = t / tstep
            k = jnp.floor(pos).astype(jnp.int32)
            uu = input_at(u, k, pos - k)
            return jnp.concatenate([y[n:], accel(y[:n], y[n:], uu, t)])

        sol = diffrax.diffeqsolve(diffrax.ODETerm(f), _rk4_solver(), 0.0, nsteps * h, h, y0,
                                  stepsize_controller=diffrax.ConstantStepSize(),
                                  saveat=diffrax.SaveAt(t1=True), max_steps=nsteps + 1)
        return sol.ys[0, :n]

    return jax.jit(jax.vmap(one))


def _rk4_solver():
    """A diffrax solver of the classic RK4 Butcher tableau (no error estimate: constant
    steps)."""
    import diffrax

    class RK4(diffrax.AbstractERK):
        tableau = diffrax.ButcherTableau(
            c=np.array([0.5, 0.5, 1.0]), b_sol=np.array([1 / 6, 1 / 3, 1 / 3, 1 / 6]),
            b_error=np.zeros(4),
            a_lower=(np.array([0.5]), np.array([0.0, 0.5]), np.array([0.0, 0.0, 1.0])))
        interpolation_cls = diffrax.ThirdOrderHermitePolynomialInterpolation.from_k

        def order(self, terms):
            return 4

    return RK4()


def timed(call, *args) -> tuple[float, object]:
    """Wall time of a call after a compiling one (its result ready)."""
    import jax

    jax.block_until_ready(call(*args))
    start = time.perf_counter()
    out = jax.block_until_ready(call(*args))
    return time.perf_counter() - start, out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--network", default="pipeline features 8x3")
    parser.add_argument("--runs", type=int, default=10000)
    parser.add_argument("--seconds", type=float, default=0.05)
    parser.add_argument("--precision", default="float64")
    parser.add_argument("--threads", type=int, default=None,
                        help="springc's threads per run where a run is split over a block")
    parser.add_argument("--json")
    args = parser.parse_args(argv)
    with gpu.layout(**gpu.env_layout(), **gpu.split_threads(args.threads)):
        return _measure(args)


def _measure(args: argparse.Namespace) -> int:
    """springc's CUDA form and the peers on the chosen network (`main`'s arguments)."""
    import jax

    jax.config.update("jax_enable_x64", args.precision == "float64")
    name, net, u, tstep = next(c for c in suite.device_cases(args.seconds, args.runs)
                               if c[0] == args.network)
    sub = suite.DEVICE_SUBSTEPS.get(name, 1)
    nsteps = int(round(args.seconds / (tstep / sub)))
    kw = dict(method="rk4", substeps=sub, tstep=tstep, tstop=args.seconds,
              precision=args.precision, probes=[], reductions=["energy"], device="cuda",
              check_step=False)
    checked = check(net)
    sm.simulate(checked, u[:2], **kw)
    start = time.perf_counter()
    res = sm.simulate(checked, u, **kw)
    wall = time.perf_counter() - start
    shape = cudagen.kernel_shape(res.info["kernel"])  # threads per run, register limit
    result = {"network": name, "dofs": net.n, "runs": len(u), "seconds": args.seconds,
              "substeps": sub, "precision": args.precision,
              "springc_cuda": {"wall_s": wall, "runs_per_s": len(u) / wall, **shape}}
    print(f"springc cuda {shape}: {len(u) / wall:,.0f} runs/s", flush=True)
    save(args.json, result)
    _peers(args, net, checked, u, tstep, sub, nsteps, kw, result)
    return 0


def _peers(args: argparse.Namespace, net, checked, u, tstep: float, sub: int, nsteps: int,
           kw: dict, result: dict) -> None:
    """JAX's and diffrax's runs per second on springc's inputs and their final positions
    against springc's (the first 64 runs), into `result`; a failed peer as its error."""
    import jax

    dtype = np.dtype(args.precision)
    uk = sources.kernel_inputs(u, len(u), max(sources.channels_used(net), 1),
                               nsteps // sub + 1, dtype)
    final = sm.simulate(checked, u[:64], **{**kw, "reductions": [
        f"final:x({node})" for node in net.nodes]})
    want = np.stack([final.reductions[f"final:x({node})"] for node in net.nodes], axis=1)
    for peer, build in (("jax", jax_rk4), ("diffrax", diffrax_rk4)):
        try:
            fn = build(net, tstep, sub, nsteps, dtype)
            wall, got = timed(fn, jax.numpy.asarray(uk))
            got = np.asarray(got)[:64]
            err = float(np.abs(got - want).max() / np.abs(want).max())
            result[peer] = {"wall_s": wall, "runs_per_s": len(u) / wall,
                            "final_x_difference": err}
            print(f"{peer}: {len(u) / wall:,.0f} runs/s, final positions within {err:.2e} "
                  "of springc's", flush=True)
        except Exception as exc:  # a peer that fails is reported, the others still run
            result[peer] = {"error": f"{type(exc).__name__}: {exc}"}
            print(f"{peer}: FAILED {type(exc).__name__}: {exc}", flush=True)
        save(args.json, result)


def save(path: str | None, result: dict) -> None:
    """Write what is measured so far (a run stopped at its time limit keeps it)."""
    if path:
        Path(path).write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    sys.exit(main())
