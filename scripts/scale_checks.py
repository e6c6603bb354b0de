"""Time the checks of `springc build` on chains and 2-D lattices of 10^4 to 10^6 masses.

    python scripts/scale_checks.py [--sizes 10000 100000 1000000] [--shapes chain lattice]
                                   [--front-end 10000] [--repeat 1]

Each network is a mass per site (m = 1 mg, b = 10 mN s/m), a spring to ground per site
(k = 1 N/m) and a coupling between neighbours (k = 10 N/m): a chain, or a square lattice of
side sqrt(n) coupled to its right and lower neighbours. For every size the flat netlist is made
from arrays (the front end would cost more than the checks at a million masses), then the
stages are timed: `check` (signs, massless nodes, whole potential, modes and step limit) and
the build report (per-mode errors of the configured step). The fitted growth exponent of the
check time over the sizes is printed per shape. `--front-end N` also times the whole `springc
build` path (parse, elaborate with `.for` loops, check, report) on the N-mass netlists,
written as text. Times are wall-clock and process CPU seconds, the best of `--repeat`.
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from pathlib import Path

import numpy as np

from springc.check import checks, compiler
from springc.errors import SourceLoc
from springc.lang import ir

MASS, DAMPING, GROUND_K, COUPLING_K = 1e-3, 0.01, 1.0, 10.0


def edges(shape: str, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Coupled neighbour pairs (i, j) of a chain of n sites or a side x side lattice."""
    if shape == "chain":
        return np.arange(n - 1), np.arange(1, n)
    side = math.isqrt(n)
    grid = np.arange(side * side).reshape(side, side)
    right = (grid[:, :-1].ravel(), grid[:, 1:].ravel())
    down = (grid[:-1, :].ravel(), grid[1:, :].ravel())
    return np.concatenate([right[0], down[0]]), np.concatenate([right[1], down[1]])


def network(shape: str, n: int) -> ir.FlatNetlist:
    """The flat netlist of one network, made from arrays."""
    if shape == "lattice":
        n = math.isqrt(n) ** 2
    i, j = edges(shape, n)
    loc = SourceLoc("<scale>", 1, 1)
    sites = np.arange(n)
    names = [f"n{s}" for s in range(n)]
    ones = np.ones(n)
    masses = ir.Masses([f"M{s}" for s in range(n)], [loc] * n, sites, MASS * ones,
                       DAMPING * ones, 0 * ones, 0 * ones)
    springs = ir.Springs([f"K{s}" for s in range(n)], [loc] * n, sites, GROUND_K * ones)
    couplings = ir.Couplings([f"C{e}" for e in range(len(i))], [loc] * len(i), i, j,
                             np.full(len(i), COUPLING_K), np.ones(len(i)))
    return ir.FlatNetlist(
        f"{shape} of {n} masses", "<scale>", names, [loc] * n, masses, springs,
        ir.Duffings(), couplings, ir.QuadCouplings(), ir.Dashpots(), ir.Monomials(),
        ir.Forces(), [], ir.Tran(1e-5, 1.0, loc), [], {}, {}, [])


def netlist_text(shape: str, n: int) -> str:
    """The same network as `.spr` text with `.for` loops."""
    head = [f".title {shape} of {n} masses", ".tran 10u 1"]
    if shape == "chain":
        return "\n".join(head + [
            f".for i 0 {n - 1}", "M{i} n{i} m=1m b=0.01", "K{i} n{i} k=1", ".endfor",
            f".for i 0 {n - 2}", "C{i} n{i} n{i+1} k=10", ".endfor"]) + "\n"
    side = math.isqrt(n)
    return "\n".join(head + [
        f".for r 0 {side - 1}", f".for c 0 {side - 1}",
        "M{r}_{c} n{r}_{c} m=1m b=0.01", "K{r}_{c} n{r}_{c} k=1", ".endfor", ".endfor",
        f".for r 0 {side - 1}", f".for c 0 {side - 2}",
        "Ch{r}_{c} n{r}_{c} n{r}_{c+1} k=10", ".endfor", ".endfor",
        f".for r 0 {side - 2}", f".for c 0 {side - 1}",
        "Cv{r}_{c} n{r}_{c} n{r+1}_{c} k=10", ".endfor", ".endfor"]) + "\n"


def timed(fn, *args, repeat: int = 1):
    """(result, best wall s, best CPU s) of fn(*args) over `repeat` calls."""
    best = [math.inf, math.inf]
    for _ in range(repeat):
        w0, c0 = time.perf_counter(), time.process_time()
        out = fn(*args)
        best = [min(best[0], time.perf_counter() - w0), min(best[1], time.process_time() - c0)]
    return out, best[0], best[1]


def scale_row(shape: str, n: int, repeat: int) -> dict:
    """Check and report times of one network."""
    net = network(shape, n)
    checked, wall, cpu = timed(checks.check, net, repeat=repeat)
    report, rwall, rcpu = timed(compiler.summarise, checked, repeat=repeat)
    return {"shape": shape, "n": net.n, "check_wall": wall, "check_cpu": cpu,
            "report_wall": rwall, "report_cpu": rcpu, "omega_max": report.omega_max,
            "margin": checked.modes.omega_margin, "dt_max": report.dt_max}


def fitted_exponent(rows: list[dict]) -> float:
    """Least-squares slope of log(check CPU time) against log(n)."""
    if len(rows) < 2:
        return math.nan
    x = np.log([r["n"] for r in rows])
    y = np.log([r["check_cpu"] for r in rows])
    return float(np.polyfit(x, y, 1)[0])


def front_end(shape: str, n: int) -> tuple[float, float]:
    """Wall and CPU seconds of `compiler.build` on the `.for` netlist of n masses."""
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / f"{shape}.spr"
        path.write_text(netlist_text(shape, n))
        _, wall, cpu = timed(compiler.build, path)
    return wall, cpu


def main() -> None:
    """Measure and print one table per shape."""
    cli = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    cli.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000, 1_000_000])
    cli.add_argument("--shapes", nargs="+", default=["chain", "lattice"])
    cli.add_argument("--front-end", type=int, nargs="*", default=[])
    cli.add_argument("--repeat", type=int, default=1)
    args = cli.parse_args()
    for shape in args.shapes:
        rows = []
        print(f"{shape}: {'masses':>9s} {'check s':>9s} {'(cpu)':>8s} {'report s':>9s} "
              f"{'omega_max':>11s} {'margin':>9s} {'dt_max':>11s}")
        for n in args.sizes:
            row = scale_row(shape, n, args.repeat)
            rows.append(row)
            print(f"{'':{len(shape) + 1}s} {row['n']:9d} {row['check_wall']:9.3f} "
                  f"{row['check_cpu']:8.3f} {row['report_wall']:9.3f} {row['omega_max']:11.6g} "
                  f"{row['margin']:9.2e} {row['dt_max']:11.6g}", flush=True)
        print(f"{'':{len(shape) + 1}s} check CPU time grows as n^{fitted_exponent(rows):.2f}")
        for n in args.front_end:
            wall, cpu = front_end(shape, n)
            print(f"{'':{len(shape) + 1}s} springc build of the .for netlist, {n} masses: "
                  f"{wall:.2f} s ({cpu:.2f} s CPU)", flush=True)


if __name__ == "__main__":
    main()
