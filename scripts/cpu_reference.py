"""Runs per second of the bench networks and the keyword-spotting pipeline's 8x3 feature and
classifier networks, on the CPU kernels (the reference) or the CUDA form.

    python scripts/cpu_reference.py --json cpu.json                     # this machine's cores
    python scripts/cpu_reference.py --device cuda --runs 10000 --json gpu.json

For the CUDA form's split runs (networks split over a block), `--threads` sets the threads
per run (`springc.kernels.cuda.SPLIT_THREADS`; 0: springc's choice, one node a thread where
the register form fits; 1: one run per thread), `--slot-max` the terms of each list a node
holds in registers (`SLOT_MAX`; 0: every term read in a loop) and `--max-registers` the
registers a thread (`MAX_REGISTERS`; 0: ptxas's choice, capped where a block would not fit);
each combination is a row, which reports the layout the kernel took.

Each network runs RK4 (or `--method`; the substeps of `springc.bench.suite.DEVICE_SUBSTEPS`) for
`--seconds` of speech-like input (`springc.bench.suite.speech_like`), recording nothing and
summing the final energy, in float64 and float32 (the classifier float64 only). A first call
compiles the kernel and is not timed; the best of `--repeat` timed calls gives runs per second.
The CPU uses every core this process may use (`springc.sim.execute.threads`).
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np  # noqa: E402

from springc.bench import suite  # noqa: E402
from springc.check import check  # noqa: E402
from springc.kernels import cuda as cudagen  # noqa: E402
from springc.sim import gpu  # noqa: E402
from springc.sim import execute  # noqa: E402
from springc.sim import simulate as sm  # noqa: E402


def measure(name: str, net, inputs, tstep: float, seconds: float, precision: str,
            device: str, repeat: int, method: str = "rk4") -> dict:
    """Runs per second of one network (best of `repeat` calls after a compiling one)."""
    checked = check(net)
    kw = dict(method=method, substeps=suite.DEVICE_SUBSTEPS.get(name, 1), tstep=tstep,
              tstop=seconds, precision=precision, probes=[], reductions=["energy"],
              device=device, check_step=False)
    runs = len(inputs)
    best, res = _best_wall(checked, inputs, kw, device, repeat)
    row = {"network": name, "dofs": net.n, "precision": precision, "device": device,
           "method": method, "threads_per_run": None, "slot_max": None, "max_registers": None,
           "runs": runs, "seconds": seconds, "substeps": kw["substeps"], "wall_s": best,
           "runs_per_s": runs / best, "run_seconds_per_s": runs * seconds / best}
    shown = _cuda_layout(row, res) if device == "cuda" else device
    if row.get("kernel"):
        shown += f" ({row['kernel'].get('regs_per_thread', '?')} registers a thread)"
    print(f"{name:28s} {precision} {method} {shown}: {runs} runs of {seconds} s in {best:.3f} s = "
          f"{runs / best:,.0f} runs/s", flush=True)
    return row


def _best_wall(checked, inputs, kw: dict, device: str, repeat: int) -> tuple[float, object]:
    """The best wall time of `repeat` simulate calls after an untimed compiling one, and the
    last call's result."""
    # compile: the CPU kernel's lanes follow the runs per thread, so its warm-up call is a
    # whole one; the CUDA kernel is the same for any number of runs
    sm.simulate(checked, inputs if device == "cpu" else inputs[:2], **kw)
    best, res = float("inf"), None
    for _ in range(repeat):
        start = time.perf_counter()
        res = sm.simulate(checked, inputs, **kw)
        best = min(best, time.perf_counter() - start)
    return best, res


def _cuda_layout(row: dict, res) -> str:
    """Adds the layout the CUDA kernel took (its text's constants) to `row`; the device as
    shown in the printed line."""
    shape = cudagen.kernel_shape(res.info["kernel"])
    held = shape["registers_held"]
    slot_max = gpu.current_layout().slot_max
    row.update(shape, slot_max=slot_max if shape["threads_per_run"] > 1 else None,
               kernel=kernel_resources(res.info["kernel"]))
    return (f"cuda T={shape['threads_per_run']} S={slot_max if held else 0} "
            f"R={shape['max_registers']}")


def kernel_resources(path: str) -> dict:
    """The compiled CUDA kernel's registers a thread, shared and local memory (what bounds the
    blocks a multiprocessor holds); empty under the simulator or where numba-cuda lacks them."""
    from springc.kernels import loader

    out = {}
    for kernel in loader._LOADED.values():
        if str(kernel.path) != str(path):
            continue
        for name in ("regs_per_thread", "shared_mem_per_block", "local_mem_per_thread",
                     "max_threads_per_block"):
            try:
                out[name] = int(getattr(kernel.module.run, f"get_{name}")())
            except Exception:  # noqa: BLE001  (a report, not a measurement)
                pass
    return out


def info(device: str, rows: list[dict]) -> dict:
    """The rows with the machine they ran on."""
    return {"machine": platform.processor() or platform.machine(), "cores": execute.threads(),
            "cpu_count": os.cpu_count(), "device": device, "rows": rows}


def _parser() -> argparse.ArgumentParser:
    """The command line: device, runs, networks, precisions and the CUDA layouts to try."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", choices=["cpu", "cuda"], default="cpu")
    parser.add_argument("--runs", type=int, default=None,
                        help="runs per network (default: 8 per core on cpu, 10000 on cuda)")
    parser.add_argument("--seconds", type=float, default=0.05, help="simulated time per run")
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--only", nargs="*", help="network names to run (default: all)")
    parser.add_argument("--precision", nargs="*", default=["float64", "float32"])
    parser.add_argument("--method", default="rk4", help="rk4, or a Lawson scheme (exp-rk4)")
    parser.add_argument("--threads", nargs="*", type=int, default=[0],
                        help="cuda: threads per run of the split form (0: springc's choice; "
                             "1: one run a thread)")
    parser.add_argument("--slot-max", nargs="*", type=int, default=[cudagen.SLOT_MAX],
                        help="cuda: a split node's terms of each list in registers (0: none)")
    parser.add_argument("--max-registers", nargs="*", type=int, default=[0],
                        help="cuda: a split run's registers a thread (0: ptxas's choice, "
                             "capped where a block would not fit)")
    parser.add_argument("--json", help="write the rows here")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    runs = args.runs or (10000 if args.device == "cuda" else 8 * execute.threads())
    rows = []
    for name, net, u, tstep in suite.device_cases(args.seconds, runs):
        if args.only and name not in args.only:
            continue
        if u is None:  # the Duffing resonator's drive is its own: runs of no input
            u = np.zeros((runs, 1, int(round(args.seconds / tstep)) + 1))
        for precision in args.precision:
            if name == "pipeline classifier 8x3" and precision == "float32":
                continue
            _measure_layouts(args, name, net, u, tstep, precision, rows)
    return 0 if all("error" not in r for r in rows) else 1


def _measure_layouts(args: argparse.Namespace, name: str, net, u, tstep: float,
                     precision: str, rows: list[dict]) -> None:
    """Appends one row to `rows` per CUDA layout the options name (one on the CPU), a failed
    one as an error row, and rewrites the JSON after each."""
    for threads, slot_max, regs in itertools.product(args.threads, args.slot_max,
                                                     args.max_registers):
        lay = {**gpu.split_threads(threads), "slot_max": slot_max,
               "max_registers": regs or None}
        try:
            with gpu.layout(**lay):
                rows.append(measure(name, net, u, tstep, args.seconds, precision,
                                    args.device, args.repeat, args.method))
        except Exception as err:  # report and go on: one must not stop the rest
            print(f"{name} {precision}: FAILED {type(err).__name__}: {err}", flush=True)
            rows.append({"network": name, "precision": precision, "error": str(err)})
        if args.json:  # after every row: a stage stopped at its limit keeps them
            Path(args.json).write_text(json.dumps(info(args.device, rows), indent=1))


if __name__ == "__main__":
    sys.exit(main())
