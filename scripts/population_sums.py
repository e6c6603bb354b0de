"""Wall of one `simulate` of a Monte Carlo population with work and dissipation sums.

    python scripts/population_sums.py [--samples 64] [--masses 100] [--temp K] [--filters]

A chain of masses (every mass, damper and spring drawn, the couplings one global draw), an
input at the first mass, 0.5 s at 16 kHz (RK4), reductions `work:in`, `dissipated:all` and a
final position; no probes recorded; with --temp, the dampers' thermal noise at K kelvin.
With --filters, a bank of masses/2 driven two-mass filters instead (every coefficient
drawn), integrated by `exp-rk4`: its exact blocks differ between the samples.
Prints the kernel calls and the least wall of three calls after a warm-up (compile
excluded), and the first samples' input work. Run it with `PYTHONPATH=<another tree>` to
compare trees (docs/performance.md).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import springc


def population(masses: int, samples: int, temp: float = 0.0) -> str:
    lines = [".param kc={gauss(1e4, 0.01)}"]
    for i in range(masses):
        lines += [f"M{i} n{i} m={{gauss(1e-3, 0.01)}} b={{gauss(0.01, 0.05)}}",
                  f"K{i} n{i} k={{gauss(4e4, 0.01)}}"]
        if i:
            lines.append(f"C{i} n{i - 1} n{i} k={{kc}}")
    lines += ["F0 n0 in gain=1", ".tran {1/16000} 0.5", f".mc {samples} seed=1"]
    if temp:
        lines.append(f".options temp={temp!r}")
    return "\n".join(lines) + "\n"


def filters(masses: int, samples: int) -> str:
    lines = []
    for i in range(masses // 2):
        k = 4e4 * (1 + i)
        lines += [f"Ma{i} a{i} m={{gauss(1e-3, 0.01)}} b={{gauss(0.01, 0.05)}}",
                  f"Mb{i} n{i} m={{gauss(1e-3, 0.01)}} b={{gauss(0.01, 0.05)}}",
                  f"Ka{i} a{i} k={{gauss({k!r}, 0.01)}}", f"Kb{i} n{i} k={{gauss({k!r}, 0.01)}}",
                  f"C{i} a{i} n{i} k={{gauss(1e3, 0.01)}}", f"F{i} a{i} in gain=1"]
    lines += [".tran {1/16000} 0.5", f".mc {samples} seed=1"]
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=64)
    ap.add_argument("--masses", type=int, default=100)
    ap.add_argument("--temp", type=float, default=0.0)
    ap.add_argument("--filters", action="store_true")
    args = ap.parse_args()
    if args.filters:
        net = springc.load(filters(args.masses, args.samples))
        last, method = f"n{args.masses // 2 - 1}", "exp-rk4"
    else:
        net = springc.load(population(args.masses, args.samples, args.temp))
        last, method = f"n{args.masses - 1}", None
    sig = np.random.default_rng(0).normal(0, 1, (1, 1, 8000))
    reduce = ["work:in", "dissipated:all", f"final:x({last})"]
    walls = []
    for _ in range(4):  # the first compiles or loads the kernel
        start = time.perf_counter()
        res = net.simulate(sig, input_rate=16000, reduce=reduce, probes=[], method=method)
        walls.append(time.perf_counter() - start)
    print(f"calls {res.info['calls']}, wall {min(walls[1:]):.3f} s (least of 3, warm); "
          f"work:in of samples 0-2: {res['work:in'][:3, 0]}")


if __name__ == "__main__":
    main()
