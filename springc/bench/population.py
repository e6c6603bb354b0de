"""`springc bench --population`: what a Monte Carlo population costs against the nominal
design.

A chain of 500 masses (damped, sprung, coupled to its neighbours, a Duffing term at its far
end), driven at its first mass by one input signal, with 1% local mismatch on every mass,
spring and coupling (`.mc 256`): its 256 samples run in the lanes of one kernel call per
batch (`springc.sim.points`, per-run coefficients), against 256 runs of the nominal network
whose runs share their coefficients, same input, same settings, same kernel form, timed in
`PAIRS` alternating pairs (the ratio per pair, its median and range). Compile
time is excluded from both (a warm-up call compiles or loads each kernel) and reported;
elaborating and checking the 256 samples is reported apart. Then scipy's `solve_ivp` (RK45,
rtol 1e-6) on the same equations for a few of the samples, one after the other: its time per
sample against springc's. Writes bench-population.md and bench/population.json.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

MASSES = 500
SAMPLES = 256
TSTEP = 1e-3
TSTOP = 1.0
SCIPY_SAMPLES = 3
PAIRS = 5  # nominal and population walls measured alternately, the ratio per pair
COMMAND = "springc bench --population --out docs"


def population_text(masses: int = MASSES, samples: int = SAMPLES) -> str:
    """The chain's `.spr` text with 1% local mismatch and `.mc samples`."""
    return "\n".join([
        f".title population: chain of {masses} masses, 1% mismatch",
        f".param n={masses}",
        ".for i 0 {n-1}",
        "M{i} n{i} m={gauss(1, 0.01)} b=0.5",
        "K{i} n{i} k={gauss(4000, 0.01)}",
        ".endfor",
        ".for i 0 {n-2}",
        "C{i} n{i} n{i+1} k={gauss(20000, 0.01)}",
        ".endfor",
        "D1 n{n-1} l=1e6",
        "F1 n0 in gain=100",
        ".probe x(n0) x(n{n-1})",
        f".mc {samples} seed=1",
        f".tran {TSTEP!r} {TSTOP!r}",
        ".options method=rk4 substeps=1",
    ]) + "\n"


def _input(seconds: float = TSTOP) -> np.ndarray:
    """One input channel: a chirp from 1 to 40 Hz, (1, 1, samples) at 1/TSTEP."""
    t = np.arange(int(round(seconds / TSTEP)) + 2) * TSTEP
    return np.sin(2 * np.pi * (1 + 19.5 * t / seconds) * t)[None, None, :]


def run_population(masses: int = MASSES, samples: int = SAMPLES, tstop: float = TSTOP,
                   scipy_samples: int = SCIPY_SAMPLES,
                   progress: Callable[[str], None] = lambda m: None) -> dict:
    """Measure (see the module docstring); returns the numbers as a dict."""
    import springc
    from springc.bench.reference import solve_ivp_reference
    from springc.bench.suite import machine_info
    from springc.check.points import check_points
    from springc.sim import execute
    from springc.sim import simulate as sm
    from springc.sim.points import simulate_points

    machine = machine_info()
    out: dict = {"masses": masses, "samples": samples, "tstop": tstop, "tstep": TSTEP,
                 "threads": execute.threads(), "load": machine["load"], "when": machine["when"],
                 "cpu": machine["cpu"]}
    start = time.perf_counter()
    net = springc.load(population_text(masses, samples))
    loaded = time.perf_counter()
    pointset = net.variation.point_set()
    elaborated = time.perf_counter()
    pointset = check_points(pointset, net.checked.method, **net.check_options)
    out["elaborate_s"] = elaborated - loaded
    out["check_s"] = time.perf_counter() - elaborated
    out["elaborate_check_s"] = time.perf_counter() - start
    progress(f"elaborated {len(pointset)} samples in {out['elaborate_s']:.1f} s, checked "
             f"them in {out['check_s']:.1f} s")
    one = _input(tstop)
    nominal = net.checked
    same = dict(tstop=tstop, reductions=["final:x(n0)"])
    warm = sm.simulate(nominal, np.repeat(one, samples, 0), **{**same, "tstop": 2 * TSTEP})
    out["compile_nominal_s"] = float(warm.info["compile_s"] or 0.0)
    warm = simulate_points(pointset, one, **{**same, "tstop": 2 * TSTEP})
    out["compile_population_s"] = float(warm.info["compile_s"][0] or 0.0)
    progress("kernels compiled or loaded")
    walls: dict[str, list[float]] = {"nominal": [], "population": []}
    for _ in range(PAIRS):  # alternating, so that a drift of the machine's speed meets both
        start = time.perf_counter()
        base = sm.simulate(nominal, np.repeat(one, samples, 0), **same)
        walls["nominal"].append(time.perf_counter() - start)
        start = time.perf_counter()
        pop = simulate_points(pointset, one, **same)
        walls["population"].append(time.perf_counter() - start)
    ratios = np.divide(walls["population"], walls["nominal"])
    out["nominal_s"] = float(np.median(walls["nominal"]))
    out["population_s"] = float(np.median(walls["population"]))
    out["walls"] = walls
    out["calls"] = pop.info["calls"]
    out["ratio"] = float(np.median(ratios))
    out["ratio_range"] = [float(ratios.min()), float(ratios.max())]
    out["spread_final"] = float(np.std(pop.reductions["final:x(n0)"][:, 0]))
    out["nominal_final"] = float(base.reductions["final:x(n0)"][0])
    progress(f"nominal {out['nominal_s']:.2f} s, population {out['population_s']:.2f} s")
    scipy_s, errors = [], []
    for p in range(scipy_samples):
        start = time.perf_counter()
        _, probes, _ = solve_ivp_reference(pointset.nets[p], one, tstep=TSTEP, tstop=tstop,
                                           method="RK45", rtol=1e-6, atol=1e-12)
        scipy_s.append(time.perf_counter() - start)
        ref = probes["x(n0)"][0]
        errors.append(float(np.abs(pop.probes["x(n0)"][p, 0] - ref).max()
                            / np.abs(ref).max()))
        progress(f"scipy sample {p}: {scipy_s[-1]:.1f} s")
    out["scipy_s"] = scipy_s
    out["scipy_vs_springc_rel"] = errors
    out["springc_per_sample_s"] = out["population_s"] / samples
    out["scipy_ratio"] = float(np.mean(scipy_s)) / out["springc_per_sample_s"]
    return out


def max_load(threads: int) -> float:
    """The largest 1-minute load average at which the ratio is recorded, a quarter of the
    cores and half a core (1.0 on 2 cores): more work beside the bench hides the population's
    memory traffic (both walls grow alike; a 2-core machine at load 8.7 gave 1.00x where it
    gives 1.74x quiet)."""
    return 0.25 * threads + 0.5


def ratio_cell(r: dict) -> str:
    """The population's ratio, or why it is not recorded (measured above `max_load`)."""
    limit = max_load(r["threads"])
    if r["load"] is not None and r["load"] > limit:
        return f"not recorded: load average {r['load']:.2f} above {limit:g}"
    spread = (f"median, {r['ratio_range'][0]:.2f}-{r['ratio_range'][1]:.2f} over "
              f"{len(r['walls']['nominal'])} alternating pairs; " if "ratio_range" in r else "")
    return f"**{r['ratio']:.2f}x** ({spread}target at most 1.3x)"


def markdown(r: dict) -> str:
    """The report page for `run_population`'s numbers."""
    load = r["load"]
    return "\n".join([
        "# A Monte Carlo population in the lanes of one kernel call",
        "",
        "| what | wall (s, median) | ratio |",
        "|---|---|---|",
        f"| {r['samples']} runs of the nominal chain (shared coefficients) | "
        f"{r['nominal_s']:.3f} | 1 |",
        f"| {r['samples']} Monte Carlo samples (per-run coefficients, {r['calls']} call(s)) "
        f"| {r['population_s']:.3f} | {ratio_cell(r)} |",
        f"| scipy solve_ivp RK45 rtol 1e-6, per sample (mean of {len(r['scipy_s'])}) | "
        f"{np.mean(r['scipy_s']):.3f} | {r['scipy_ratio']:.0f}x springc's "
        f"{r['springc_per_sample_s'] * 1e3:.2f} ms per sample |",
        "",
        f"Chain of {r['masses']} masses (damped, sprung, neighbour couplings, a Duffing term "
        f"at the far end), input at the first mass, 1% local mismatch on every mass, spring "
        f"and coupling (`springc.bench.population.population_text`); RK4, h = "
        f"{r['tstep']:g} s, {r['tstop']:g} s simulated, the probes recorded at every step "
        "and one final-state reduction, float64, the same input for every run.",
        "",
        "- Compile excluded from both walls (a warm-up call compiles or loads each kernel): "
        f"nominal kernel {r['compile_nominal_s']:.2f} s, population kernel "
        f"{r['compile_population_s']:.2f} s (under a second where loaded from the kernel "
        "cache, which a run with the same lane width fills).",
        f"- Elaborating and checking the {r['samples']} samples (each a netlist of its own, "
        f"checked like one): {r['elaborate_check_s']:.1f} s, not in the walls"
        + (f"; of it {r['elaborate_s']:.2f} s elaborating the samples and {r['check_s']:.2f} s "
           f"checking them ({r['check_s'] / r['samples'] * 1e3:.1f} ms per sample), the rest "
           "loading and checking the nominal netlist." if "check_s" in r else "."),
        "- scipy against springc on the same samples: largest difference of x(n0) "
        f"{max(r['scipy_vs_springc_rel']):.1e} of its peak (RK45's tolerance against "
        "RK4's step error).",
        f"- Machine: {r.get('cpu', 'CPU not recorded')}, {r['threads']} cores; measured "
        f"{r.get('when', '(date not recorded)')}, 1-minute load average "
        f"{load if load is not None else 'unknown'} at the start (a ratio is recorded up to "
        f"{max_load(r['threads']):g}).",
        "",
        f"Regenerate: `{COMMAND}` (writes this page and bench/population.json).",
        "",
    ])


def write_report(result: dict, outdir: Path) -> dict[str, Path]:
    """Write OUT/bench-population.md and OUT/bench/population.json; returns their paths."""
    paths = {"md": outdir / "bench-population.md",
             "json": outdir / "bench" / "population.json"}
    paths["json"].parent.mkdir(parents=True, exist_ok=True)
    paths["md"].write_text(markdown(result))
    paths["json"].write_text(json.dumps(result, indent=1))
    return paths
