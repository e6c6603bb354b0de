"""`springc bench --scaling`: how each stage's time grows with the network.

A chain, a square and a cubic lattice (`springc.bench.lattices`) of 10^3 to 10^6 masses go
through the stages a user's command runs: elaboration of the `.for` text, the checks, the
kernel's compile (from the kernel cache, which a warm-up fills: the cold compile of each
kernel form is reported once) and one simulated second of one run. ngspice runs the exported
chain where it finishes within `NGSPICE_LIMIT`. Then one run of the square lattice on one
thread against the nodes split over every core (`springc.sim.simulate.split_nodes`). Each
measurement runs in its own process, whose peak memory is reported. Writes scaling.md,
scaling.json and scaling.png.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from springc.bench.lattices import TSTEP, lattice_net, lattice_text, side_for

CASES = {"chain": 1, "square": 2, "cubic": 3}  # name -> dimensions
SIZES = (10**3, 10**4, 10**5, 10**6)
STEPS = 1000  # one simulated second at the lattices' 1 ms step
STAGES = ("elaborate", "check", "compile", "simulate")
FIT_FROM = 10**4  # masses: the fits start here (below, fixed costs hide the growth)
NGSPICE_LIMIT = 60.0  # s: ngspice runs a size only if it should finish within this
CHILD_LIMIT = 900.0  # s: a measurement running longer is stopped and its larger sizes skipped
THREAD_SIZES = (10**5, 10**6)  # square lattices run on one thread and split over the cores


def measure_stages(dims: int, side: int, steps: int) -> dict:
    """One case at one size, in this process: each stage's seconds (simulate: per simulated
    second), the kernel form and the peak memory."""
    from springc.check import check
    from springc.lang import load_text
    from springc.sim import execute
    from springc.sim import simulate as sm

    text = lattice_text(dims, side)
    start = time.perf_counter()
    net = load_text(text, f"<{dims}-D lattice>")
    elaborate = time.perf_counter() - start
    start = time.perf_counter()
    checked = check(net)
    checks = time.perf_counter() - start
    first = sm.simulate(checked, tstop=2 * TSTEP)  # compiles, or loads from the cache
    start = time.perf_counter()
    res = sm.simulate(checked, tstop=steps * TSTEP)
    wall = time.perf_counter() - start
    split = sm.split_nodes(net, res.info["settings"], 1, None)
    return {"masses": net.n, "elaborate": elaborate, "check": checks,
            "compile": first.info["compile_s"], "simulate": wall / (steps * TSTEP),
            "steps": steps, "threads": execute.threads() if split else 1, "peak_gb": peak_gb()}


def measure_threads(side: int, steps: int, split: bool) -> dict:
    """One run of the square lattice (built as arrays) for `steps` steps, on one thread or
    its nodes split over `threads()`: wall, CPU seconds of the process and of its busiest
    thread (the wall an idle machine would give), peak memory, and the probes' last values."""
    from springc.check import check
    from springc.sim import execute
    from springc.sim import simulate as sm

    net = lattice_net(2, side)
    checked = check(net)
    sm.simulate(checked, tstop=2 * TSTEP, node_threads=split)  # the kernel, loaded
    before, cpu0 = thread_cpu(), time.process_time()
    start = time.perf_counter()
    res = sm.simulate(checked, tstop=steps * TSTEP, node_threads=split)
    wall = time.perf_counter() - start
    after = thread_cpu()
    busiest = max(after[t] - before.get(t, 0.0) for t in after)
    return {"masses": net.n, "steps": steps, "split": split,
            "threads": execute.threads() if split else 1, "wall": wall,
            "cpu": time.process_time() - cpu0, "busiest": busiest, "peak_gb": peak_gb(),
            "last": {k: float(v[0, -1]) for k, v in res.probes.items()}}


def measure_ngspice(side: int, limit: float) -> dict:
    """ngspice on the exported chain (`springc export --spice`), one simulated second."""
    from springc.check import check
    from springc.export.ngspice import run_ngspice
    from springc.export.spice import export_spice, probe_vectors

    net = lattice_net(1, side)
    checked = check(net)
    start = time.perf_counter()
    text = export_spice(checked)
    export = time.perf_counter() - start
    start = time.perf_counter()
    run_ngspice(text, 1.0, TSTEP, probe_vectors(net), timeout=limit)
    return {"masses": net.n, "export": export, "ngspice": time.perf_counter() - start}


def peak_gb() -> float:
    """Peak resident memory of this process, GiB (Linux: ru_maxrss in KiB)."""
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20


def thread_cpu() -> dict[int, float]:
    """CPU seconds (user + system) of each thread of this process (Linux /proc)."""
    tick = os.sysconf("SC_CLK_TCK")
    out = {}
    for task in Path("/proc/self/task").iterdir():
        try:
            fields = (task / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue  # the thread ended
        out[int(task.name)] = (int(fields[11]) + int(fields[12])) / tick
    return out


def in_child(call: str, limit: float, env: dict | None = None) -> dict:
    """`call` (an expression of this module's functions) in a fresh Python process: its
    result, or {"skipped": reason} when it fails or runs past `limit` seconds."""
    code = f"import json; from springc.bench.scaling import *; print(json.dumps({call}))"
    try:
        proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                              timeout=limit, env=env)
    except subprocess.TimeoutExpired:
        return {"skipped": f"did not finish within {limit:g} s"}
    if proc.returncode != 0:
        tail = (proc.stderr.strip().splitlines() or ["no message"])[-1]
        return {"skipped": f"failed: {tail}"}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def warm_kernels() -> dict:
    """The lattices' kernels compiled, one thread and nodes split (a 64-mass chain: the same
    element kinds as every size), and their compile seconds."""
    from springc.check import check
    from springc.sim import simulate as sm

    checked = check(lattice_net(1, 64))
    out = {}
    for name, split in (("one thread", False), ("split", True)):
        res = sm.simulate(checked, tstop=2 * TSTEP, write_out=False, node_threads=split)
        out[name] = res.info["compile_s"]
    return out


def fit_exponent(masses: list[float], seconds: list[float]) -> float | None:
    """The least-squares slope of log(seconds) on log(masses) over sizes from `FIT_FROM`
    on (None with fewer than two)."""
    pts = [(m, s) for m, s in zip(masses, seconds) if m >= FIT_FROM and s and s > 0]
    if len(pts) < 2:
        return None
    x, y = np.log([p[0] for p in pts]), np.log([p[1] for p in pts])
    return float(np.polyfit(x, y, 1)[0])


def run_scaling(sizes=SIZES, steps: int = STEPS, ngspice: bool = True,
                thread_sizes=THREAD_SIZES,
                progress: Callable[[str], None] = print) -> dict:
    """Every case at every size, ngspice on the chain, and the thread comparison; the
    results as a JSON-ready dict (`write_report` writes it)."""
    from springc.bench.suite import machine_info

    start = time.perf_counter()
    result = {"machine": machine_info(), "steps": steps, "sizes": list(sizes), "cases": {}}
    with tempfile.TemporaryDirectory(prefix="springc-scaling-") as cache:
        env = dict(os.environ, SPRINGC_CACHE=cache)
        progress("compiling the kernels (cold cache)")
        result["cold_compile"] = in_child("warm_kernels()", CHILD_LIMIT, env)
        for name, dims in CASES.items():
            result["cases"][name] = _ladder(
                sizes, lambda m, d=dims: f"measure_stages({d}, {side_for(m, d)}, {steps})",
                env, progress, name)
        if ngspice:
            result["ngspice"] = _ngspice_ladder(sizes, env, progress)
        result["threads"] = [
            in_child(f"measure_threads({side_for(m, 2)}, {steps}, {split})", CHILD_LIMIT, env)
            for m in thread_sizes for split in (False, True)]
        progress("thread comparison done")
    result["fits"] = {name: {stage: fit_exponent([r["masses"] for r in rows],
                                                 [r[stage] for r in rows])
                             for stage in STAGES}
                      for name, rows in _measured(result).items()}
    result["machine"]["wall_s"] = round(time.perf_counter() - start, 1)
    return result


def _ladder(sizes, call: Callable[[int], str], env: dict, progress, name: str) -> list[dict]:
    """The sizes in order until one fails or runs out of time (the larger ones are then
    skipped, saying why)."""
    rows = []
    for m in sizes:
        if rows and "skipped" in rows[-1]:
            rows.append({"target": m, "skipped": f"after {rows[-1]['target']}: "
                         + rows[-1]["skipped"].split(": ", 1)[-1]})
            continue
        progress(f"{name}: {m} masses")
        row = in_child(call(m), CHILD_LIMIT, env)
        rows.append({"target": m, **row})
    return rows


def _ngspice_ladder(sizes, env: dict, progress) -> list[dict]:
    """ngspice on the chain, size by size, while the growth seen so far predicts a run
    within `NGSPICE_LIMIT` (at least linear growth is assumed)."""
    rows: list[dict] = []
    for m in sizes:
        done = [r for r in rows if "ngspice" in r]
        if len(done) < len(rows):
            rows.append({"target": m, "skipped": "a smaller size did not finish"})
            continue
        if done:
            growth = max(1.0, fit_slope(done) if len(done) > 1 else 1.0)
            guess = done[-1]["ngspice"] * (m / done[-1]["masses"]) ** growth
            if guess > NGSPICE_LIMIT:
                rows.append({"target": m, "skipped": f"predicted {guess:.0f} s "
                             f"(> {NGSPICE_LIMIT:g} s) from growth n^{growth:.2f}"})
                continue
        progress(f"ngspice: chain of {m} masses")
        side = side_for(m, 1)
        rows.append({"target": m, **in_child(f"measure_ngspice({side}, {NGSPICE_LIMIT})",
                                             NGSPICE_LIMIT + 120, env)})
    return rows


def fit_slope(rows: list[dict]) -> float:
    """The slope of log ngspice seconds on log masses over `rows`."""
    x = np.log([r["masses"] for r in rows])
    return float(np.polyfit(x, np.log([r["ngspice"] for r in rows]), 1)[0])


def _measured(result: dict) -> dict[str, list[dict]]:
    return {name: [r for r in rows if "skipped" not in r]
            for name, rows in result["cases"].items()}


# -- the report --------------------------------------------------------------------------

def write_report(result: dict, outdir: Path) -> dict[str, Path]:
    """scaling.md, scaling.json and scaling.png into `outdir`."""
    outdir.mkdir(parents=True, exist_ok=True)
    paths = {"md": outdir / "scaling.md", "json": outdir / "scaling.json",
             "png": outdir / "scaling.png"}
    paths["json"].write_text(json.dumps(result, indent=1) + "\n")
    plot(result, paths["png"])
    paths["md"].write_text(markdown(result, paths["png"].name))
    return paths


def markdown(result: dict, png: str = "scaling.png") -> str:
    """The page: the figure, the stage table and fits, ngspice, the threads, how measured."""
    lines = ["# Scaling with the network", "", f"![time against masses, log-log]({png})", ""]
    lines += stage_table(result)
    lines += ngspice_table(result.get("ngspice", []))
    lines += thread_table(result.get("threads", []))
    lines += how_measured(result)
    return "\n".join(lines) + "\n"


def _s(value: float | None) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    return f"{value:.3g}"


def stage_table(result: dict) -> list[str]:
    """Seconds per stage, case by case and size by size, then the fitted exponents."""
    lines = ["| case | masses | elaborate s | check s | compile s | simulate s per simulated s "
             "| threads | peak GiB |", "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for name, rows in result["cases"].items():
        for r in rows:
            if "skipped" in r:
                lines.append(f"| {name} | ~{r['target']} | {r['skipped']} | | | | | |")
                continue
            lines.append(f"| {name} | {r['masses']} | "
                         + " | ".join(_s(r[s]) for s in STAGES)
                         + f" | {r['threads']} | {r['peak_gb']:.2f} |")
    lines += ["", f"Fitted growth, seconds ~ masses^p, from {FIT_FROM} masses on:", "",
              "| case | " + " | ".join(STAGES) + " |", "|---|" + "---:|" * len(STAGES)]
    for name, fits in result.get("fits", {}).items():
        lines.append(f"| {name} | " + " | ".join(
            "-" if fits[s] is None else f"{fits[s]:.2f}" for s in STAGES) + " |")
    return lines + [""]


def ngspice_table(rows: list[dict]) -> list[str]:
    """ngspice's seconds for one simulated second of the exported chain."""
    if not rows:
        return []
    lines = ["ngspice on the exported chain (one simulated second):", "",
             "| masses | export s | ngspice s |", "|---:|---:|---:|"]
    for r in rows:
        if "skipped" in r:
            lines.append(f"| ~{r['target']} | skipped: {r['skipped']} | |")
        else:
            lines.append(f"| {r['masses']} | {_s(r['export'])} | {_s(r['ngspice'])} |")
    return lines + [""]


def thread_table(rows: list[dict]) -> list[str]:
    """One run of the square lattice, one thread against the nodes split over the cores."""
    if not rows:
        return []
    lines = ["One run of the square lattice, 1 ms steps:", "",
             "| masses | steps | threads | wall s | CPU s | busiest thread CPU s | peak GiB |",
             "|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        if "skipped" in r:
            lines.append(f"| | | | skipped: {r['skipped']} | | | |")
            continue
        lines.append(f"| {r['masses']} | {r['steps']} | {r['threads']} | {r['wall']:.3g} | "
                     f"{r['cpu']:.3g} | {r['busiest']:.3g} | {r['peak_gb']:.2f} |")
    return lines + [""]


def how_measured(result: dict) -> list[str]:
    """How the numbers were taken."""
    from springc.bench.suite import of_cpu

    m = result["machine"]
    cold = result.get("cold_compile", {})
    cold_text = ", ".join(f"{k} {v:.1f} s" for k, v in cold.items() if isinstance(v, float))
    return [
        "## How it was measured", "",
        f"`springc bench --scaling` on {m.get('cpus')} CPUs{of_cpu(m)}, load average "
        f"{m.get('load')} at the start, {m.get('when')}. Each row is its own process (peak "
        "memory: its maximum resident set). elaborate: `load_text` of the `.for` text "
        "(`springc.bench.lattices.lattice_text`); check: `springc.check.check`; compile: the "
        "first simulation's kernel compile, here a load from the kernel cache that a warm-up "
        f"filled (cold compiles: {cold_text or 'not measured'}); simulate: the next "
        f"simulation, one run of {result['steps']} steps of RK4 at 1 ms (scaled to one "
        "simulated second), the nodes "
        "split over the threads where `split_nodes` chooses it (the threads column). The fits "
        f"are least squares of log seconds on log masses from {FIT_FROM} masses on. "
        f"ngspice runs a size only when the growth so far predicts under {NGSPICE_LIMIT:g} s. "
        "CPU s: the process's CPU time; busiest thread: the CPU time of its busiest thread, "
        "the wall an idle machine would give.", ""]


def plot(result: dict, path: Path) -> None:
    """Seconds against masses, log-log, one panel per case (ngspice on the chain's)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    measured = _measured(result)
    fig, axes = plt.subplots(1, len(measured), figsize=(4.2 * len(measured), 3.6),
                             sharey=True, squeeze=False)
    for ax, (name, rows) in zip(axes[0], measured.items()):
        masses = [r["masses"] for r in rows]
        for stage in STAGES:
            ax.loglog(masses, [r[stage] for r in rows], "o-", label=stage)
        if name == "chain":
            done = [r for r in result.get("ngspice", []) if "ngspice" in r]
            if done:
                ax.loglog([r["masses"] for r in done], [r["ngspice"] for r in done], "k^--",
                          label="ngspice (simulate)")
        ax.set_title(name)
        ax.set_xlabel("masses")
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].set_ylabel("seconds (simulate: per simulated second)")
    axes[0][0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
