"""`springc bench`: throughput and accuracy of the generated kernels against their peers.

On the 564-dof keyword-spotting-sized network (`networks.kws_network`) driven by noise
at 32 kHz: the kernel in float64 and float32 at batch sizes 1 and 64 (1 s of input per run),
its compile time cold (empty cache) and cached (a fresh import loading numba's cache), and on a
short stretch (scaled to per-second figures) plain numpy RK4 and scipy RK45 and DOP853 at
rtol 1e-6. Errors are relative L2 norms of all probes against a tight reference: the kernel's
RK4 at an 8x smaller step (error ~4000x below RK4's at the benchmark step).
"""

from __future__ import annotations

import json
import os
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from springc.check import CheckedNetlist, check
from springc.kernels import codegen, loader
from springc.bench.networks import KWS_RATE, kws_network
from springc.bench.reference import rk4_numpy, solve_ivp_reference
from springc.sim.simulate import simulate


@dataclass
class Row:
    """One line of the table."""

    solver: str
    runs: int
    simulated_s: float
    wall_s: float
    rel_error: float
    dofs: int
    steps: int

    @property
    def run_s_per_wall_s(self) -> float:
        return self.runs * self.simulated_s / self.wall_s

    @property
    def dof_steps_per_s(self) -> float:
        return self.runs * self.steps * self.dofs / self.wall_s

    def as_dict(self) -> dict:
        return {**asdict(self), "run_s_per_wall_s": self.run_s_per_wall_s,
                "dof_steps_per_s": self.dof_steps_per_s,
                "wall_s_per_run_s": 1 / self.run_s_per_wall_s}


def rel_l2(got: dict, ref: dict, samples: int) -> float:
    """Relative L2 error over all probes (first run, first `samples` samples)."""
    num = sum(np.sum((np.asarray(got[k])[0, :samples] - ref[k][0, :samples]) ** 2) for k in ref)
    den = sum(np.sum(ref[k][0, :samples] ** 2) for k in ref)
    return float(np.sqrt(num / den))


def noise(runs: int, seconds: float, seed: int = 0) -> np.ndarray:
    """Band-unlimited white noise inputs (runs, 1, samples) at the benchmark rate."""
    rng = np.random.default_rng(seed)
    return 0.1 * rng.standard_normal((runs, 1, int(seconds * KWS_RATE) + 1))


def compile_times(checked: CheckedNetlist) -> dict[str, float]:
    """Cold compile (empty cache folder) and cached load (fresh import) of the kernel."""
    saved = os.environ.get("SPRINGC_CACHE")
    with tempfile.TemporaryDirectory() as folder:
        os.environ["SPRINGC_CACHE"] = folder
        try:
            # the options `_first_call` (one run) gets, so that forget() drops that kernel
            opts = codegen.KernelOptions(lanes=codegen.choose_lanes(1))
            source = codegen.generate(checked.net, opts)
            loader.forget(codegen.kernel_hash(source))
            cold = _first_call(checked)
            loader.forget(codegen.kernel_hash(source))
            cached = _first_call(checked)
        finally:
            loader.forget(codegen.kernel_hash(source))
            if saved is None:
                os.environ.pop("SPRINGC_CACHE")
            else:
                os.environ["SPRINGC_CACHE"] = saved
    return {"compile_cold_s": cold, "compile_cached_s": cached}


def _first_call(checked: CheckedNetlist) -> float:
    start = time.perf_counter()
    simulate(checked, noise(1, 0.001), tstop=0.001)
    return time.perf_counter() - start


def run_bench(seconds: float = 1.0, batch: int = 64, stretch: float = 0.02,
              progress=print) -> dict:
    """Measure everything; returns the table rows and compile times as a dict."""
    net = kws_network()
    checked = check(net)
    steps = int(round(seconds * KWS_RATE))
    short = int(round(stretch * KWS_RATE))
    progress("compile times (cold, then cached) ...")
    times = compile_times(checked)
    u = noise(batch, seconds)
    progress("tight reference: RK4 at an 8x smaller step ...")
    ref = simulate(checked, u[:1], tstop=stretch, substeps=8, outrate=KWS_RATE).probes
    rows = []
    for precision in ("float64", "float32"):
        simulate(checked, u[:1], tstop=0.001, precision=precision)  # compile outside the timing
        for runs in (1, batch):
            progress(f"kernel {precision}, batch {runs} ...")
            start = time.perf_counter()
            res = simulate(checked, u[:runs], tstop=seconds, precision=precision)
            wall = time.perf_counter() - start
            rows.append(Row(f"springc kernel rk4 {precision}", runs, seconds, wall,
                            rel_l2(res.probes, ref, short + 1), net.n, steps))
    rows += _peers(net, u[:1], stretch, short, ref, progress)
    return {"network": net.title, "dofs": net.n, "elements": net.element_counts(),
            "rate_hz": KWS_RATE, "threads": len(os.sched_getaffinity(0)),
            **times, "rows": [r.as_dict() for r in rows]}


def _peers(net, u, stretch, short, ref, progress) -> list[Row]:
    tstep = 1.0 / KWS_RATE
    rows = []
    progress("numpy RK4 ...")
    start = time.perf_counter()
    _, probes, _ = rk4_numpy(net, u, tstep=tstep, tstop=stretch)
    rows.append(Row("numpy rk4 float64", 1, stretch, time.perf_counter() - start,
                    rel_l2(probes, ref, short + 1), net.n, short))
    for method in ("RK45", "DOP853"):
        progress(f"scipy {method} rtol 1e-6 ...")
        start = time.perf_counter()
        _, probes, sol = solve_ivp_reference(net, u, tstep=tstep, tstop=stretch, method=method,
                                             rtol=1e-6, atol=1e-12, max_step=np.inf)
        rows.append(Row(f"scipy {method} rtol 1e-6", 1, stretch, time.perf_counter() - start,
                        rel_l2(probes, ref, short + 1), net.n, int(sol.nfev)))
    return rows


def markdown(result: dict) -> str:
    """The table as Markdown."""
    lines = [
        f"Network: {result['network']}, {result['dofs']} dofs {result['elements']}, "
        f"input noise at {result['rate_hz']:.0f} Hz, {result['threads']} threads.",
        f"Kernel compile: cold {result['compile_cold_s']:.1f} s, "
        f"cached {result['compile_cached_s']:.2f} s.",
        "",
        "| solver | runs | simulated s | wall s | wall s per run-second | run-s per wall-s "
        "| dof-steps/s | rel. L2 error |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in result["rows"]:
        lines.append(
            f"| {r['solver']} | {r['runs']} | {r['simulated_s']:g} | {r['wall_s']:.2f} | "
            f"{r['wall_s_per_run_s']:.3g} | {r['run_s_per_wall_s']:.3g} | "
            f"{r['dof_steps_per_s']:.3g} | {r['rel_error']:.2e} |")
    lines.append("")
    lines.append("scipy rows count right-hand-side evaluations as steps. Errors: all probes of "
                 "run 0 over the first stretch, against RK4 at an 8x smaller step.")
    return "\n".join(lines)


def write_json(result: dict, path: str | Path) -> None:
    """Write the result as JSON (through a temporary file)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(result, indent=2))
    os.replace(tmp, path)
