"""The CUDA kernel form against the CPU kernels: the same probes and reductions.

    NUMBA_ENABLE_CUDASIM=1 python scripts/cuda_compare.py tiny     # numba's CUDA simulator
    NUMBA_ENABLE_CUDASIM=1 NUMBA_DISABLE_JIT=1 python scripts/cuda_compare.py tiny
    NUMBA_ENABLE_CUDASIM=1 python scripts/cuda_compare.py rounding
    python scripts/cuda_compare.py bench --json out.json          # a GPU: every bench network
    python scripts/cuda_compare.py bench --no-fma --only "stiff block"   # products unfused

`tiny`: a four-mass network of every term kind (M K D C Q B P F; sine and in() inputs) with
every reduction the CUDA form computes, under RK4 and Heun3 in float64 and RK4 in float32,
each with the force code written out per node and looped over the index arrays, and with
the steps split over many kernel calls (the streamed inputs); its float32 cases and one
Lawson scheme with no product fused into a fused multiply-add (`fma` False: the CUDA form's
products as `mul_rn`). `rounding`: the stiff block with no product fused, the compiled CPU
kernels against the simulated CUDA form (IEEE operations one by one, as NumPy's scalars do
them), float64 and float32: equal to the bit. `bench`: the bench suite's
networks (`springc.bench.networks`, `springc.bench.suite`) on speech-like inputs. Each
comparison is max |cuda - cpu| over max |cpu| per probe or reduction; the tolerance is
1e-12 in float64 and 1e-5 in float32. Prints one line per case and, with --json, writes
every error; exits 1 if any exceeds its tolerance. Under `NUMBA_DISABLE_JIT=1` (as the test
suite runs `tiny`) the CPU kernels run as Python too, uncompiled: the simulated CUDA form then
does the same arithmetic in the same order, and every error is 0.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from springc.bench import suite
from springc.check import check
from springc.kernels import cuda as cudagen
from springc.lang.ir import IRBuilder, Source, Tran
from springc.sim import gpu
from springc.sim import simulate as sm

TOLERANCE = {"float64": 1e-12, "float32": 1e-5}


REDUCE = ["final:x(c)", "final:v(b)", "msq:x(a)", "msq:v(d):0.002:0.006", "work:in",
          "dissipated:all", "energy", "gram:0.005:a,c,d"]


def every_kind(scattered: bool = True):
    """Four masses: a, b damped, c, d undamped; springs; a coupling a-b; quadratic couplings
    a->c, b->c; a Duffing term on d; a dashpot b-d; a monomial a^2 b^2 and one c^4 (P); inputs
    on a (in(0)), b (in(1)), c (in(0), twice); a sine drive on d. Without `scattered`, no
    monomials and no sine drive (the terms the split form adds after its node loop)."""
    w = 2 * np.pi * 80.0
    b = IRBuilder("every term kind", "<cuda_compare.every_kind>")
    for name, node, m, damp in (("1", "a", 1.0, 30.0), ("2", "b", 2.0, 10.0),
                                ("3", "c", 0.5, 0.0), ("4", "d", 1.0, 0.0)):
        b.mass(f"M{name}", node, m, damp)
        b.spring(f"K{name}", node, w**2 * m)
    b.coupling("C1", "a", "b", 0.3 * w**2, a=1.5)
    b.quad("Q1", "a", "c", 2e3, a=0.5)
    b.quad("Q2", "b", "c", 1e3, a=2.0)
    b.duffing("D1", "d", 1e7)
    b.dashpot("B1", "b", "d", 5.0)
    if scattered:
        b.monomial("P1", 1e6, [("a", 2), ("b", 2)])
        b.monomial("P2", 1e7, [("c", 4)])
    b.force("F1", "a", Source("in", channel=0), 1e3)
    b.force("F2", "b", Source("in", channel=1), 2e3)
    b.force("F3", "c", Source("in", channel=0), 5e2)
    b.force("F4", "c", Source("in", channel=0), -2e2)
    if scattered:
        b.force("F5", "d", Source("sin", (50.0, 60.0)))
    for node in "abcd":
        b.probe("x", node)
    b.probe("v", "b")
    b.tran = Tran(1e-4, 0.008, None)
    return b.finish()


def smooth_inputs(runs: int, channels: int, samples: int, seed: int) -> np.ndarray:
    """(runs, channels, samples) sums of three random sines at 1e-4 s a sample."""
    t = np.arange(samples) * 1e-4
    f = np.random.default_rng(seed).uniform(20.0, 120.0, (runs, channels, 3))
    return np.sin(2 * np.pi * f[..., None] * t).sum(axis=2) * 1e-3


def errors(cpu, cuda) -> dict[str, float]:
    """max |cuda - cpu| / max |cpu| of every probe and reduction."""
    out = {}
    for group in ("probes", "reductions"):
        for key, want in getattr(cpu, group).items():
            got = getattr(cuda, group)[key]
            scale = float(np.abs(want).max()) or 1.0
            out[key] = float(np.abs(np.asarray(got) - want).max() / scale)
    return out


PROGRESS: list[dict] = []  # every case so far, written to --json after each one
JSON_PATH: list[str] = []


def compare(name: str, net, inputs, precision: str, reference=None, device: str | None = "cuda",
            **kw) -> dict:
    """One case: the CPU kernels' result and the CUDA form's (`device`; None: that of
    `gpu.default_device`), their errors and times; with a float64 CPU `reference`, each one's
    own error against it too (float32's rounding, which the two devices meet apart). The row
    keeps the CPU result under "result" (not saved)."""
    checked = check(net)
    start = time.perf_counter()
    cpu = sm.simulate(checked, inputs, precision=precision, device="cpu", **kw)
    mid = time.perf_counter()
    cuda = sm.simulate(checked, inputs, precision=precision, device=device, **kw)
    end = time.perf_counter()
    errs = errors(cpu, cuda)
    worst = max(errs.values())
    ok = worst <= TOLERANCE[precision]
    own = ""
    row = {"case": name, "precision": precision, "worst": worst, "ok": ok, "errors": errs,
           "cpu_s": mid - start, "cuda_s": end - mid,
           **cudagen.kernel_shape(cuda.info.get("kernel"))}
    if reference is not None:
        row["cpu_vs_float64"] = max(errors(reference, cpu).values())
        row["cuda_vs_float64"] = max(errors(reference, cuda).values())
        own = (f"; against float64: cpu {row['cpu_vs_float64']:.2e}, "
               f"cuda {row['cuda_vs_float64']:.2e}")
    print(f"{'ok  ' if ok else 'FAIL'} {name:48s} {precision} worst {worst:.2e} "
          f"(cpu {mid - start:.1f} s, cuda {end - mid:.1f} s){own}", flush=True)
    _progress(row)
    return {**row, "result": cpu}


def _progress(row: dict) -> None:
    """Adds one case to PROGRESS and rewrites --json: a run stopped at its time limit keeps
    the cases done."""
    PROGRESS.append(row)
    for path in JSON_PATH:
        with open(path, "w") as fh:
            json.dump(PROGRESS, fh, indent=1)


def tiny() -> list[dict]:
    """The every-kind network in the three force forms (written out, loops, split over 3
    threads a run), two tableaux, both precisions, with its steps streamed over many calls;
    split in float32 with one term of each list in registers (the rest looped); split
    without monomials and shared signals (its combine folded into the last stage) in springc's
    layout, a node a thread, with a register limit in its text; then once
    on the default device (`gpu.default_device`)."""
    net = every_kind()
    u = smooth_inputs(2, 2, 70, seed=0)  # two runs: two blocks of the split form
    out = _three_forms(net, u)
    # split, no term added after the node loop: the combine folded into the last stage's;
    # springc's layout (a node a thread: a warp, most of its threads without a node) and a
    # register limit in the text (which the simulator, taking none, leaves out)
    with gpu.layout(write_out_max=0, split_min=1, split_threads=None, max_registers=64):
        row = compare("unscattered kinds, split, a node a thread, at most 64 registers, rk4 x1",
                      every_kind(False), u, "float64", method="rk4", substeps=1,
                      reductions=REDUCE, outrate=5e3, write_out=False)
    out.append({k: v for k, v in row.items() if k != "result"})
    out += lawson()
    with gpu.default_device("cuda"):  # a simulation that names no device runs there
        row = compare("every kind, the default device", net, u, "float64", device=None,
                      method="rk4", substeps=1, reductions=REDUCE, outrate=5e3,
                      write_out=False)
    out.append({k: v for k, v in row.items() if k != "result"})
    return out


def _three_forms(net, u) -> list[dict]:
    """`tiny`'s first cases: the every-kind network written out, in loops and split over 3
    threads a run, under RK4 and Heun3 in float64 and RK4 in float32, 13 steps a call."""
    out = []
    default = gpu.current_layout()
    for form, write_out, split_min in (("written out", default.write_out_max, 10**9),
                                       ("loops", 0, 10**9), ("split", 0, 1)):
        for method, precision, sub in (("rk4", "float64", 1), ("heun3", "float64", 2),
                                       ("rk4", "float32", 1)):
            # split in float32: one term of each list in registers, the rest looped
            held = 1 if form == "split" and precision == "float32" else default.slot_max
            name = f"every kind, {form}{', one term a list in registers' * (held == 1)}"
            fma = precision == "float64"  # float32: the products rounded alone (mul_rn)
            # 13 steps a call: the inputs and records streamed over many calls
            with gpu.layout(13, write_out_max=write_out, split_min=split_min, split_threads=3,
                            slot_max=held):
                row = compare(f"{name}, {method} x{sub}{', no fma' * (not fma)}", net, u,
                              precision, method=method, substeps=sub, reductions=REDUCE,
                              outrate=5e3, write_out=False, fma=fma)
            out.append({k: v for k, v in row.items() if k != "result"})
    return out


def lawson() -> list[dict]:
    """The Lawson schemes on the feature extractor (eight exact filter pairs, quadratic
    couplings and low-passes in the rest), one run per thread, split over 3 threads and
    split a node a thread (24 nodes: 32 threads); its probes, input work, dissipation and
    energy."""
    net = suite.feature_extractor()
    u = smooth_inputs(3, 1, 50, seed=1) * 30.0
    out = []
    for form, split_min, threads, methods in (
            ("a run a thread", 10**9, 3, ("exp-rk4", "exp-heun3")),
            ("split", 1, 3, ("exp-rk4", "exp-heun3")),
            ("split, a node a thread", 1, None, ("exp-rk4",))):  # springc's layout: a warp
        for method in methods:
            fma = method == "exp-rk4"  # exp-heun3: the products rounded alone (mul_rn)
            with gpu.layout(split_min=split_min, split_threads=threads):
                row = compare(f"feature extractor, {form}, {method} x1{', no fma' * (not fma)}",
                              net, u, "float64", method=method, substeps=1, tstep=1e-4,
                              tstop=0.004 if threads else 0.0015,  # a warp: 10x the threads
                              reductions=["work:in", "dissipated:all", "energy"], fma=fma)
            out.append({k: v for k, v in row.items() if k != "result"})
    return out



def rounding() -> list[dict]:
    """The stiff block (24 masses, written out per node), RK4 x2 for 2 ms, 3 runs, with no
    product fused (`fma` False), float64 and float32: the CPU kernels compiled (run this
    without NUMBA_DISABLE_JIT) against the CUDA form in the simulator."""
    net = suite.stiff_block()
    u = suite.speech_like(0.002, 16000.0, 3, 3)
    out = []
    for precision in ("float64", "float32"):
        row = compare("stiff block, rk4 x2, no fma", net, u, precision, method="rk4",
                      substeps=2, tstep=1 / 16000.0, tstop=0.002, reductions=["energy"],
                      check_step=False, fma=False)
        out.append({k: v for k, v in row.items() if k != "result"})
    return out


def bench(seconds: float, runs: int, only: list[str] | None = None,
          method: str = "rk4", fma: bool = True) -> list[dict]:
    """Every bench network (or those named in `only`), RK4 (or `method`) in float64 and
    float32, its final state and energy too; `fma` False: no product fused with an add on
    either device."""
    out = []
    for name, net, u, tstep in suite.device_cases(seconds, runs):
        if only and name not in only:
            continue
        sub = suite.DEVICE_SUBSTEPS.get(name, 1)
        reference = None
        for precision in ("float64", "float32"):
            if name == "pipeline classifier 8x3" and precision == "float32":
                continue  # its multipliers' cancellation: float32 is not used for it
            row = compare(f"{name}{', no fma' * (not fma)}", net, u, precision, reference,
                          method=method, substeps=sub, tstep=tstep, tstop=seconds,
                          reductions=["energy"], check_step=False, fma=fma)
            reference = row.pop("result")
            out.append(row)
    return out


def _parser() -> argparse.ArgumentParser:
    """The command line: which comparison, and the bench's time, runs, networks and scheme."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("which", choices=["tiny", "rounding", "bench"])
    parser.add_argument("--seconds", type=float, default=0.02, help="bench: simulated time")
    parser.add_argument("--runs", type=int, default=64, help="bench: runs per network")
    parser.add_argument("--json", help="write every case's errors here")
    parser.add_argument("--only", nargs="*", help="bench: network names to run (default: all)")
    parser.add_argument("--method", default="rk4", help="bench: rk4, or a Lawson scheme")
    parser.add_argument("--no-fma", action="store_true",
                        help="bench: no product fused with an add, on either device")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    if args.json:
        JSON_PATH.append(args.json)
    # numba's CUDA simulator runs a block's threads as Python threads that meet at barriers:
    # at the interpreter's default switch interval (5 ms) each barrier waits that long
    sys.setswitchinterval(1e-4)
    with gpu.layout(**gpu.env_layout()):
        cases = (tiny() if args.which == "tiny" else rounding() if args.which == "rounding"
                 else bench(args.seconds, args.runs, args.only, args.method, not args.no_fma))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(cases, fh, indent=1)
    return 0 if all(c["ok"] for c in cases) else 1


if __name__ == "__main__":
    sys.exit(main())
