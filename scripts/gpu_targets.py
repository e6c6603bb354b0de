"""Issue 41's targets from the JSON a `gpu_check.sh` run leaves, one line each, met or missed.

    python scripts/gpu_targets.py OUT [--cpu docs/bench/gpu/2026-11-27/cpu_2core_128runs.json]

- the same probes as the CPU kernels: 1e-12 in float64, 1e-5 in float32 (`compare*.json`:
  fused, and with no product fused, `compare_no_fma.json`);
- throughput on the 8x3 feature network against the 2-core CPU kernels (`--cpu`, a
  `cpu_reference.py` run on a 2-core machine): at least 50x (the fastest float64 row of
  `split_threads.json`, `cuda_throughput.json` and `peers_features.json`);
- at least 3x JAX's throughput on the same GPU, network and step (`peers_*.json`).

A stage that did not run or left no JSON is said to be missing; nothing is guessed.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
CPU_REFERENCE = HERE.parent / "docs/bench/gpu/2026-11-27/cpu_2core_128runs.json"
FEATURES = "pipeline features 8x3"
TOLERANCE = {"float64": 1e-12, "float32": 1e-5}


def _load(path: Path):
    return json.loads(path.read_text()) if path.exists() else None


def agreement(out: Path) -> list[str]:
    """Per comparison file and precision: the worst case against its tolerance."""
    lines = []
    for name, label in (("compare.json", "fused"), ("compare_no_fma.json", "no fma"),
                        ("compare_lawson.json", "exp-rk4, fused")):
        rows = _load(out / name)
        if rows is None:
            lines.append(f"agreement ({label}): missing ({name})")
            continue
        for precision, tol in TOLERANCE.items():
            mine = [r for r in rows if r["precision"] == precision]
            if not mine:
                continue
            worst = max(mine, key=lambda r: r["worst"])
            ok = worst["worst"] <= tol
            lines.append(f"agreement ({label}, {precision}): {'MET' if ok else 'MISSED'}, "
                         f"worst {worst['worst']:.2e} ({worst['case']}) against {tol:g}, "
                         f"{len(mine)} networks")
    return lines


def speedup(out: Path, cpu: Path) -> str:
    """The fastest float64 row of the 8x3 feature network in the run (the threads sweep, the
    throughput stage, the peers' stage) against the 2-core CPU figure."""
    ref = _load(cpu)
    base = [r["runs_per_s"] for r in (ref or {}).get("rows", [])
            if r["network"] == FEATURES and r["precision"] == "float64"]
    rates = [(r["runs_per_s"], name) for name in ("split_threads.json", "cuda_throughput.json")
             for r in (_load(out / name) or {}).get("rows", [])
             if r.get("network") == FEATURES and r.get("precision") == "float64"
             and "runs_per_s" in r]
    peers = _load(out / "peers_features.json")
    if peers and "springc_cuda" in peers:
        rates.append((peers["springc_cuda"]["runs_per_s"], "peers_features.json"))
    if not base or not rates:
        return "50x the 2-core CPU: missing (no 8x3 feature network row, or no --cpu figure)"
    best, where = max(rates)
    ratio = best / base[0]
    return (f"50x the 2-core CPU: {'MET' if ratio >= 50 else 'MISSED'}, {best:,.0f} ({where}) "
            f"against {base[0]:,.0f} runs/s: {ratio:.1f}x")


def against_jax(out: Path) -> list[str]:
    """springc's runs per second over JAX's, per network the peers ran."""
    lines = []
    for name in ("peers_features.json", "peers_kws.json"):
        peers = _load(out / name)
        if peers is None or "jax" not in peers or "runs_per_s" not in peers["jax"]:
            lines.append(f"3x JAX: missing ({name})")
            continue
        ratio = peers["springc_cuda"]["runs_per_s"] / peers["jax"]["runs_per_s"]
        lines.append(f"3x JAX, {peers['network']}: {'MET' if ratio >= 3 else 'MISSED'}, "
                     f"{ratio:.2f}x (final positions within "
                     f"{peers['jax']['final_x_difference']:.1e})")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", help="the folder gpu_check.sh wrote")
    parser.add_argument("--cpu", default=str(CPU_REFERENCE),
                        help="cpu_reference.py's JSON of the 2-core CPU")
    args = parser.parse_args(argv)
    out = Path(args.out)
    for line in agreement(out) + [speedup(out, Path(args.cpu))] + against_jax(out):
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
