"""Time the .spr front end on a generated netlist of about 10,000 elements.

    python scripts/bench_frontend.py [--elements 10000] [--repeat 3]

The netlist is a long chain (mass, spring and coupling per site, values as expressions) plus
a dense all-to-all block of couplings; parse, elaborate and check (the physics checks of
`springc build`: signs, massless nodes, whole potential, time step) are timed separately (best of
`--repeat` runs) and printed with the element count: wall-clock time and the process's CPU
time (the machine is shared, so CPU time is the steadier figure when others are busy).
"""

from __future__ import annotations

import argparse
import math
import time

from springc.check.checks import check
from springc.lang import elaborate, parse


def generate(elements: int) -> str:
    """Netlist text: about half the elements in a chain, half in an all-to-all block."""
    block = int((1 + math.sqrt(1 + 4 * elements)) / 2)  # block*(block-1)/2 + block ~ n/2
    sites = (elements - block * (block - 1) // 2 - block) // 3
    lines = [".title front-end benchmark", ".param m0=1m kc=10 kl={1e-6*kc}"]
    for i in range(sites):
        lines.append(f"M{i} n{i} m={{m0}} b=0.01")
        lines.append(f"K{i} n{i} k={{kl}}")
        lines.append(f"C{i} n{i} n{i + 1} k={{kc*(1 + {i % 7}/10)}}")
    lines.append(f"M{sites} n{sites} m=m0")
    for i in range(block):
        lines.append(f"Mb{i} b{i} m=1 b=0.1")
    for i in range(block):
        for j in range(i + 1, block):
            lines.append(f"Cb{i}_{j} b{i} b{j} k=0.5 a=1")
    lines.append("Cjoin n0 b0 k=1")
    lines.append(".probe x(n0) x(b0)")
    lines.append(".tran 10u 1")
    return "\n".join(lines) + "\n"


def main() -> None:
    """Generate, then time parse, elaborate and check."""
    cli = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    cli.add_argument("--elements", type=int, default=10_000)
    cli.add_argument("--repeat", type=int, default=3)
    args = cli.parse_args()
    text = generate(args.elements)
    best = {stage: [math.inf, math.inf] for stage in ("parse", "elaborate", "check")}
    for _ in range(args.repeat):
        tree, wall, cpu = _timed(parse, text, "<bench>")
        best["parse"] = [min(best["parse"][0], wall), min(best["parse"][1], cpu)]
        net, wall, cpu = _timed(elaborate, tree)
        best["elaborate"] = [min(best["elaborate"][0], wall), min(best["elaborate"][1], cpu)]
        _, wall, cpu = _timed(check, net)
        best["check"] = [min(best["check"][0], wall), min(best["check"][1], cpu)]
    count = sum(net.element_counts().values())
    print(f"elements {count}, nodes {net.n}, lines {text.count(chr(10))}, bytes {len(text)}")
    print(f"{'':10s} {'wall ms':>9s} {'cpu ms':>9s}   (best of {args.repeat})")
    for stage, (wall, cpu) in best.items():
        print(f"{stage:10s} {wall * 1e3:9.1f} {cpu * 1e3:9.1f}")
    total = [sum(v[i] for v in best.values()) * 1e3 for i in (0, 1)]
    print(f"{'total':10s} {total[0]:9.1f} {total[1]:9.1f}")


def _timed(fn, *args):
    """fn(*args), its wall-clock and its CPU time in seconds."""
    w0, c0 = time.perf_counter(), time.process_time()
    out = fn(*args)
    return out, time.perf_counter() - w0, time.process_time() - c0


if __name__ == "__main__":
    main()
