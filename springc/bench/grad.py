"""The cost of one gradient against one forward simulation of the same network and inputs.

`measure` times `simulate` of a reduction and `springc.grad.gradient` of the same reduction
over every parameter (least of repeated calls, compiles excluded), on networks with every
nonlinear term kind and dashpots, driven by noise inputs; `report` prints its table when
`springc bench` runs the whole suite.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from springc.check import check
from springc.grad import ParamNetlist, coefficient_gradient, gradient
from springc.sim.simulate import simulate

TARGET = 5.0  # the gradient over all parameters should cost at most this many simulations


def chain(nodes: int, seconds: float) -> str:
    """A chain of Duffing masses with leverage couplings, quadratic couplings and dashpots,
    one input at its head, at a 16 kHz step; six parameters."""
    lines = [".param k0=4e6 kc=1e6 l0=1e9 g0=1e5 bd=40 gain=1e6"]
    for i in range(nodes):
        lines += [f"M{i} n{i} m=1 b={{bd}}", f"K{i} n{i} k={{k0*(1+{i}/{nodes})}}",
                  f"D{i} n{i} l={{l0}}"]
        if i:
            lines += [f"C{i} n{i - 1} n{i} k={{kc}} a=1.2", f"Q{i} n{i - 1} n{i} g={{g0}} a=0.8",
                      f"B{i} n{i - 1} n{i} b={{bd}}"]
    lines += ["F0 n0 in(0) gain={gain}", f".tran {{1/16000}} {seconds}"]
    return "\n".join(lines) + "\n"


def _least(calls: dict[str, Callable[[], object]], repeats: int) -> dict[str, float]:
    """The least wall time of each call over `repeats` rounds, the calls in alternation
    within each round (a busy machine slows both sides alike)."""
    best = dict.fromkeys(calls, np.inf)
    for _ in range(repeats):
        for key, call in calls.items():
            start = time.perf_counter()
            call()
            best[key] = min(best[key], time.perf_counter() - start)
    return {k: float(v) for k, v in best.items()}


def measure_case(nodes: int, runs: int, seconds: float, repeats: int = 5) -> dict:
    """Forward and gradient wall seconds on `chain(nodes, seconds)` with `runs` noise inputs."""
    pn = ParamNetlist.from_text(chain(nodes, seconds), "<bench chain>")
    checked = check(pn.netlist())
    rng = np.random.default_rng(0)
    inputs = 0.01 * rng.standard_normal((runs, 1, int(16000 * seconds) + 1))
    spec, wrt = f"msq:x(n{nodes - 1})", list(pn.values)
    fwd = lambda: simulate(checked, inputs, reductions=[spec])  # noqa: E731
    grad = lambda: gradient(pn, spec, wrt, inputs)  # noqa: E731
    sweeps = lambda: coefficient_gradient(checked, [spec], inputs)  # noqa: E731
    for call in (fwd, grad):  # compile (or load from the caches) outside the timing
        call()
    took = _least({"forward_s": fwd, "gradient_s": grad, "sweeps_s": sweeps}, repeats)
    out = {"dofs": nodes, "runs": runs, "steps": int(round(seconds * 16000)),
           "params": len(wrt), **took}
    out["ratio"] = out["gradient_s"] / out["forward_s"]
    out["sweeps_ratio"] = out["sweeps_s"] / out["forward_s"]
    return out


def measure(quick: bool = False) -> list[dict]:
    """The cases: one run of a small chain, and batches on a larger one."""
    if quick:
        return [measure_case(4, 2, 0.01, repeats=1)]
    return [measure_case(4, 1, 0.5), measure_case(16, 8, 0.25), measure_case(16, 64, 0.25)]


def markdown(rows: list[dict]) -> str:
    """The table: wall seconds and the ratio, against the target."""
    lines = ["## gradient: one gradient over all parameters against one simulation", "",
             f"Target: at most {TARGET:g}x. Gradient: `springc.grad.gradient` (elaboration, "
             "exact parameter Jacobian, checks, forward and adjoint sweeps); sweeps: the "
             "adjoint's forward and reverse sweeps alone (`coefficient_gradient`). Least of "
             "5 rounds of the three calls in alternation, compiles excluded.", "",
             "| dofs | runs | steps | params | simulate s | gradient s | ratio | sweeps s | "
             "sweeps ratio |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['dofs']} | {r['runs']} | {r['steps']} | {r['params']} | "
                     f"{r['forward_s']:.4g} | {r['gradient_s']:.4g} | {r['ratio']:.1f} | "
                     f"{r['sweeps_s']:.4g} | {r['sweeps_ratio']:.1f} |")
    return "\n".join(lines) + "\n"


def report(names: list[str] | None, quick: bool, progress: Callable[[str], None]) -> None:
    """Measure and print the table through `progress` when the whole suite runs."""
    if names is None:
        progress("[gradient] cost of a gradient against a simulation\n"
                 + markdown(measure(quick)))
