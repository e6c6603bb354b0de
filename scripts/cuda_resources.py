"""Registers, spills and compile time of the CUDA form's kernels, offline: no GPU, only
numba-cuda and NVIDIA's compiler wheel (`pip install -e .[cuda-offline]`).

    python scripts/cuda_resources.py --only "pipeline features 8x3" --threads 256 512 \\
        --slot-max 0 8 --max-registers 0 64 --fma 1 0 --json regs.json

A child process under numba's CUDA simulator generates each kernel (the bench network of
`springc.bench.suite.device_cases`, RK4 or `--method` at its `suite.DEVICE_SUBSTEPS`,
float64, recording nothing, as `cpu_reference.py` times it; `--threads 0`, the default: the
threads per run and register lists springc chooses) and records the types of the arguments
its launch passes; this
process compiles each to PTX with numba-cuda (timed: numba's front end and NVVM) and then to
machine code with ptxas (`-v`, for `--arch`; with each `--max-registers`, as numba-cuda's
`max_registers` asks ptxas, and with the kernel's own limit where it sets one), printing the
registers a thread, the spilled bytes and the shared memory a block, and the fused
multiply-adds in the PTX (`--fma 0`: the form whose products round on their own,
`CudaOptions.fma` False, must have none). Which blocks a multiprocessor then holds follows from
these; how fast they run is for a GPU to say (`gpu_check.sh`).
"""

from __future__ import annotations

import argparse
import importlib.util
import itertools
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np



def capture(only: list[str], threads: list[int], slot_max: list[int], fmas: list[int],
            method: str, out: str) -> None:
    """Under the simulator: each kernel's file and its launch's argument types, to `out`."""

    from springc.bench import suite
    from springc.check import check
    from springc.sim import gpu
    from springc.sim import simulate as sm

    specs = []
    gpu.run = _recording(gpu.run, specs)
    code_max = gpu.current_layout().slot_code_max
    for name, net, u, tstep in suite.device_cases(0.0005, 2):
        if name not in only:
            continue
        checked = check(net)
        for t, s, fma in itertools.product(threads, slot_max, fmas):
            # a set thread count measures its register form at every size; 0 as springc chooses
            lay = {**gpu.split_threads(t), "slot_max": s, "slot_code_max": 10**9 if t else code_max}
            specs.append({"network": name, "method": method, "slot_max": s, "fma": bool(fma)})
            with gpu.layout(**lay):
                sm.simulate(checked, u, device="cuda", method=method, tstep=tstep,
                            tstop=0.0005, substeps=suite.DEVICE_SUBSTEPS.get(name, 1), probes=[],
                            reductions=["energy"], check_step=False, fma=bool(fma))
    Path(out).write_text(json.dumps(specs, indent=1))


def _recording(plain_run, specs: list[dict]):
    """`gpu.run` that launches nothing: it records the kernel's file, layout and the launch's
    argument types in `specs[-1]`."""

    def recording_run(kernel, args, runs):
        module = kernel.module

        class Launch:  # stands for the kernel: records the argument types, runs nothing
            def __getitem__(self, config):
                def launch(*values):
                    specs[-1]["args"] = [_arg_type(v) for v in values]
                return launch

        real, module.run = module.run, Launch()
        try:
            plain_run(kernel, args, runs)
        finally:
            module.run = real
        specs[-1].update(path=str(kernel.path), threads=module.T, held=bool(module.SLOTS),
                         kernel_limit=module.MAX_REGISTERS)

    return recording_run


def _arg_type(value) -> tuple[str, int]:
    """(dtype, ndim) of a launch argument (ndim 0: a scalar)."""
    if hasattr(value, "dtype") and hasattr(value, "ndim"):
        return str(value.dtype), int(value.ndim)
    return ("float64" if isinstance(value, float) else "int64"), 0


def compile_one(spec: dict, arch: str, registers: list[int], ptxas: str) -> dict:
    """PTX of one captured kernel (timed), then ptxas's report for each register limit."""
    from numba import cuda, types
    from numba.np.numpy_support import from_dtype

    loaded = importlib.util.spec_from_file_location(f"kernel_{id(spec)}", spec["path"])
    module = importlib.util.module_from_spec(loaded)
    loaded.loader.exec_module(module)
    sig = tuple(from_dtype(np.dtype(dt)) if nd == 0 else
                types.Array(from_dtype(np.dtype(dt)), nd, "C") for dt, nd in spec["args"])
    start = time.perf_counter()
    ptx, _ = cuda.compile_ptx(module.run.py_func, sig, cc=(int(arch[3]), int(arch[4:])))
    row = {**{k: spec[k] for k in ("network", "method", "threads", "slot_max", "held", "fma",
                                   "kernel_limit")},
           "ptx_s": time.perf_counter() - start, "ptx_lines": ptx.count("\n"),
           "fma_instructions": len(re.findall(r"\bfma\.rn\.f(?:32|64)\b", ptx)),
           "rounded_products": len(re.findall(r"\bmul\.rn\.f(?:32|64)\b", ptx))}
    with tempfile.NamedTemporaryFile("w", suffix=".ptx", delete=False) as fh:
        fh.write(ptx)
    try:
        for limit in dict.fromkeys([*registers, spec["kernel_limit"] or 0]):
            row[f"ptxas_{limit or 'free'}"] = _ptxas_report(ptxas, arch, limit, fh.name)
    finally:
        os.unlink(fh.name)
    return row


def _ptxas_report(ptxas: str, arch: str, limit: int, ptx_path: str) -> dict:
    """ptxas -v on one PTX file at one register limit (0: none): its time, registers a
    thread, spilled bytes and shared memory."""
    flags = [f"-maxrregcount={limit}"] if limit else []
    start = time.perf_counter()
    rep = subprocess.run([ptxas, "-v", f"-arch={arch}", *flags, ptx_path, "-o",
                          os.devnull], capture_output=True, text=True, check=True).stderr
    return {"s": time.perf_counter() - start,
            "registers": _number(r"Used (\d+) registers", rep),
            "spill_stores": _number(r"(\d+) bytes spill stores", rep),
            "spill_loads": _number(r"(\d+) bytes spill loads", rep),
            "shared": _number(r"(\d+) bytes smem", rep)}


def _number(pattern: str, text: str) -> int | None:
    found = re.search(pattern, text)
    return int(found.group(1)) if found else None


def _ptxas() -> str:
    """ptxas from PATH or from the nvidia-cuda-nvcc wheel."""
    found = shutil.which("ptxas")
    if found:
        return found
    import nvidia.cuda_nvcc

    return str(Path(list(nvidia.cuda_nvcc.__path__)[0]) / "bin" / "ptxas")


def _parser() -> argparse.ArgumentParser:
    """The command line: the networks, layouts, scheme and register limits to compile."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="+", default=["pipeline features 8x3"])
    parser.add_argument("--threads", nargs="+", type=int, default=[0],
                        help="threads per run of the split form (0: springc's choice)")
    parser.add_argument("--method", default="rk4", help="rk4, or a Lawson scheme (exp-rk4)")
    parser.add_argument("--slot-max", nargs="+", type=int, default=[0, 8])
    parser.add_argument("--max-registers", nargs="+", type=int, default=[0])
    parser.add_argument("--fma", nargs="+", type=int, default=[1],
                        help="1: products may fuse with adds (the default form); 0: not")
    parser.add_argument("--arch", default="sm_90", help="ptxas's target (sm_90: H100, H200)")
    parser.add_argument("--json", help="write the rows here")
    parser.add_argument("--capture", help=argparse.SUPPRESS)  # the child's output file
    return parser


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    if args.capture:
        capture(args.only, args.threads, args.slot_max, args.fma, args.method, args.capture)
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        specs = _captured(args, tmp)
        ptxas, rows = _ptxas(), []
        for spec in specs:
            row = compile_one(spec, args.arch, args.max_registers, ptxas)
            rows.append(row)
            _print_row(row)
    if args.json:
        Path(args.json).write_text(json.dumps({"arch": args.arch, "rows": rows}, indent=1))
    return 0


def _captured(args: argparse.Namespace, tmp: str) -> list[dict]:
    """The kernels' specs, from this script run as a child under numba's CUDA simulator
    (numba reads NUMBA_ENABLE_CUDASIM when it is imported)."""
    specs_path = str(Path(tmp) / "specs.json")
    env = {**os.environ, "NUMBA_ENABLE_CUDASIM": "1",
           "SPRINGC_CACHE": os.environ.get("SPRINGC_CACHE", str(Path(tmp) / "cache"))}
    subprocess.run([sys.executable, __file__, "--capture", specs_path, "--only", *args.only,
                    "--threads", *map(str, args.threads), "--method", args.method,
                    "--slot-max",
                    *map(str, args.slot_max), "--fma", *map(str, args.fma)], env=env,
                   check=True)
    return json.loads(Path(specs_path).read_text())


def _print_row(row: dict) -> None:
    """One kernel's line: its layout, PTX time and instructions, ptxas's report per limit."""
    reports = ", ".join(
        f"limit {k.removeprefix('ptxas_')}: {v['registers']} registers, spills "
        f"{v['spill_stores']}/{v['spill_loads']} B" for k, v in row.items()
        if k.startswith("ptxas_"))
    held = row["slot_max"] if row["held"] else 0
    print(f"{row['network']} {row['method']} T={row['threads']} S={held} "
          f"fma={int(row['fma'])} (kernel's limit {row['kernel_limit']}): PTX in "
          f"{row['ptx_s']:.1f} s, "
          f"{row['fma_instructions']} fma.rn, {row['rounded_products']} mul.rn; "
          f"{reports}", flush=True)


if __name__ == "__main__":
    sys.exit(main())
