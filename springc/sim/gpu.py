"""The CUDA runtime: which device a simulation runs on, and the launches of the CUDA kernel
form (`springc.kernels.cuda`) over the arrays `springc.sim.simulate` prepares for the CPU
kernels (the same names, so that simulate finishes the reductions and checks divergence the
same way).

One run per thread, or per block of threads for the split form (`springc.kernels.cuda`); the
state stays on the device between calls, each call integrating
`STEPS_PER_CALL` steps, so only that range's input samples, shared signals and records are
on the device at a time: a recording of any length fits. numba's CUDA simulator
(`NUMBA_ENABLE_CUDASIM=1`) runs the same kernels on the CPU, for the tests.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING

import numpy as np

from springc.errors import UsageError
from springc.kernels import expint, loader, terms
from springc.kernels.codegen import Features, features
from springc.lang.ir import FlatNetlist
from springc.sim import sources

if TYPE_CHECKING:  # the CUDA form's generator: imported where a GPU run needs it
    from springc.kernels import cuda as cudagen

DEVICES = ("cpu", "cuda", "auto")
STEPS_PER_CALL = 4096  # steps per kernel call: the input, signals and records on the device
_DEFAULT = ["cpu"]  # the device of the innermost `default_device`: what `simulate` uses
_LAYOUT: list[tuple[dict, int]] = []  # the innermost `layout`'s changes and steps a call


@contextmanager
def layout(steps_per_call: int | None = None, **changes) -> Iterator[None]:
    """Within it, the CUDA form lays networks out with `changes` to `cudagen.Layout`'s
    defaults (write_out_max, split_min, split_threads, slot_max, slot_code_max,
    max_registers; on top of an enclosing `layout`'s) and integrates `steps_per_call` steps
    a kernel call: the measuring scripts' sweeps and the simulator's comparison. Outside
    one, every CUDA simulation takes the defaults."""
    outer, steps = _LAYOUT[-1] if _LAYOUT else ({}, STEPS_PER_CALL)
    _LAYOUT.append(({**outer, **changes}, steps_per_call or steps))
    try:
        current_layout()  # an unknown field is a TypeError here
        yield
    finally:
        _LAYOUT.pop()


def split_threads(threads: int | None) -> dict:
    """`layout`'s changes for the CUDA form's threads per run of networks split over a
    block (`cudagen.Layout.split_threads`; 0 or None: springc's choice; 1: none split, one
    run per thread)."""
    if threads == 1:
        return {"split_min": 10**9}
    return {"split_threads": threads or None}


def env_layout() -> dict:
    """`layout`'s changes from SPRINGC_SLOT_MAX and SPRINGC_MAX_REGISTERS where set (the
    measuring scripts' register terms and registers a thread of the split form, which
    scripts/gpu_check.sh sets to the fastest of its sweep)."""
    changes: dict = {}
    if os.environ.get("SPRINGC_SLOT_MAX"):
        changes["slot_max"] = int(os.environ["SPRINGC_SLOT_MAX"])
    if int(os.environ.get("SPRINGC_MAX_REGISTERS") or 0):
        changes["max_registers"] = int(os.environ["SPRINGC_MAX_REGISTERS"])
    return changes


def current_layout() -> cudagen.Layout:
    """The CUDA form's layout here (`layout`)."""
    from springc.kernels import cuda as cudagen

    return cudagen.Layout(**(_LAYOUT[-1][0] if _LAYOUT else {}))


def steps_per_call() -> int:
    """Steps a CUDA kernel call integrates here (`layout`)."""
    return _LAYOUT[-1][1] if _LAYOUT else STEPS_PER_CALL


@contextmanager
def default_device(device: str) -> Iterator[str]:
    """Within it, `simulate` calls that name no device run on `device` ('auto': CUDA where a
    GPU is present; UsageError for 'cuda' where none is), falling back to the CPU for what
    the CUDA form does not run, and data-set simulations (`springc.kws.features.distributed`)
    run in this process, batch after batch, instead of on Dask workers. Yields the device
    resolved ('cpu' or 'cuda')."""
    _DEFAULT.append(resolve(device))
    try:
        yield _DEFAULT[-1]
    finally:
        _DEFAULT.pop()


def current() -> str:
    """The device of the innermost `default_device` ('cpu' outside any)."""
    return _DEFAULT[-1]


def device_name() -> str:
    """What the innermost `default_device` is, in words: 'cpu', or the GPU's name."""
    if current() == "cpu":
        return "cpu"
    from numba import config, cuda

    if config.ENABLE_CUDASIM:
        return "numba's CUDA simulator"
    name = cuda.get_current_device().name
    return name.decode() if isinstance(name, bytes) else str(name)


def _numpy_compat() -> None:
    """numba-cuda 0.30 registers an overload of `np.row_stack`, which numpy 2.4 removed: its
    first kernel compile fails with AttributeError there unless the old name (an alias of
    `np.vstack`) exists."""
    if not hasattr(np, "row_stack"):
        np.row_stack = np.vstack


_numpy_compat()


def cuda_present(simulator: bool = True) -> bool:
    """Whether numba can launch CUDA kernels here (`simulator`: numba's CUDA simulator
    counts)."""
    try:
        from numba import config, cuda
    except ImportError:
        return False
    if config.ENABLE_CUDASIM:
        return simulator
    try:
        return bool(cuda.is_available())
    except Exception:  # a broken driver reads as no GPU
        return False


def resolve(device: str) -> str:
    """'cpu' or 'cuda' for `device` ('auto': CUDA where a GPU is present, not the
    simulator); UsageError for 'cuda' where none is."""
    match device:
        case "cpu":
            return "cpu"
        case "auto":
            return "cuda" if cuda_present(simulator=False) else "cpu"
        case "cuda":
            if not cuda_present():
                raise UsageError("--device cuda: no CUDA GPU is available here (numba.cuda "
                                 "found none, or numba-cuda is not installed)",
                                 hint="install springc[cuda] on a machine with an NVIDIA "
                                      "GPU, or use --device cpu")
            return "cuda"
        case _:
            raise UsageError(f"unknown device {device!r}", hint="cpu, cuda or auto")


def _strang(method: str) -> bool:
    return expint.is_split(method) and expint.SCHEMES[method].kind != "lawson"


def serves(net: FlatNetlist, method: str) -> bool:
    """Whether the CUDA form runs `method` with `net`'s options (`require`'s refusals)."""
    return not _strang(method) and float(net.options.get("temp", 0.0)) == 0


def require(net: FlatNetlist, method: str) -> None:
    """Refuse what the CUDA form does not run: Strang splitting and thermal noise."""
    if _strang(method):
        raise UsageError(f"--device cuda runs Runge-Kutta tableaux and the Lawson schemes, not "
                         f"{method}", hint="use --method exp-rk4, rk4 (or another tableau) or "
                                           "--device cpu")
    if float(net.options.get("temp", 0.0)) > 0:
        raise UsageError("--device cuda does not simulate thermal noise (.options temp=)",
                         hint="use --device cpu")


def vneed(net: FlatNetlist, coeffs: dict, work: bool) -> tuple[bool, ...]:
    """Whether anything reads each node's stage velocity (`codegen.velocity_needed`)."""
    out = coeffs["bm"] != 0.0
    feat = features(net)
    for kind in terms.KINDS:
        if getattr(feat, kind.feature) and kind.reads_velocity():
            for index in (kind.node_i, kind.node_j):
                if index:
                    nodes = coeffs[index].astype(np.int64)
                    out[nodes[nodes >= 0]] = True
    if work:
        for index in ("fi_node", "fc_node"):
            if index in coeffs and getattr(feat, {"fi_node": "in_forces",
                                                  "fc_node": "common_forces"}[index]):
                out[coeffs[index].astype(np.int64)] = True
    return tuple(bool(b) for b in out)


def force_netlist(net: FlatNetlist, method: str) -> tuple[FlatNetlist, expint.Blocks | None]:
    """The netlist whose forces the kernel computes, and a Lawson scheme's exact blocks: its
    Runge-Kutta part (the blocks' linear terms and inputs split off, `expint.split_netlist`;
    the force table, and so the input channels, kept), else `net` and None."""
    if not expint.is_split(method):
        return net, None
    blocks = expint.find_blocks(net)
    return expint.split_netlist(net, blocks), blocks


def options(net: FlatNetlist, blocks: expint.Blocks | None, method: str, precision: str,
            coeffs: dict, probes: int, rplan, fma: bool = True) -> cudagen.CudaOptions:
    """The CUDA kernel's options for the force netlist `net` and a Lawson scheme's `blocks`
    (`force_netlist`) and a reduction plan (`coeffs`: the kernel arrays,
    `marshal.kernel_arrays`, with their node ends, `terms.node_ends`) and whether a product
    may be fused with an add (`fma`, `CudaOptions.fma`). A Lawson scheme's
    force code is never written out (the CPU kernels' choice too: its block updates
    dominate)."""
    from springc.kernels import cuda as cudagen

    lay = current_layout()
    lawson = blocks is not None
    small = net.n <= lay.write_out_max and not lawson
    nodes = terms.node_terms(coeffs, net.n) if small else None
    feat = features(net)
    gram = sum(r.gram.groups for r in rplan.gram)
    folded = not (feat.monomials or feat.common_forces or lawson)
    split = (nodes is None and net.n >= lay.split_min and cudagen.shared_bytes(
        net.n, precision, method, gram, folded) <= cudagen.SHARED_BYTES)
    threads, held = split_layout(feat, coeffs, net.n) if split else (1, ())
    return cudagen.CudaOptions(
        method, precision, net.n, sources.channels_used(net),
        inputs=len(sources.input_forces(net)) if feat.in_forces else 0,
        common=len(sources.common_forces(net)) if feat.common_forces else 0,
        probes=probes, work=rplan.work, dampers=len(rplan.damper_rows),
        msq=len(rplan.msq), gram=gram,
        vneed=vneed(net, coeffs, rplan.work), nodes=nodes,
        threads=threads, slots=held,
        max_registers=cudagen.register_limit(threads, lay.max_registers) if split else None,
        blocks=tuple(expint.block_sizes(blocks)) if lawson else (),
        block_channels=expint.block_channels(net, blocks) if lawson else 1, fma=fma)


def split_layout(feat: Features, coeffs: dict, n: int) -> tuple[int, tuple]:
    """The split form's threads per run and register lists (`cudagen.CudaOptions.slots`)
    from the kernel arrays with their node ends (`terms.node_ends`). Per list a node holds
    its most terms, at most the layout's `slot_max` (`current_layout`), and notes whether a
    node has more; none with slot_max 0, or where the code written out per thread would
    exceed `slot_code_max` term blocks (every term then read in the loops). Threads: the
    layout's `split_threads` where set; else one node a thread (`cudagen.node_threads`) where
    the register lists' code fits there, else `cudagen.LOOP_THREADS`."""
    from springc.kernels import cuda as cudagen

    lay = current_layout()
    lists = cudagen.slot_lists(feat)
    most = [int(np.diff(coeffs[sl.ptr].astype(np.int64)).max(initial=0)) for sl in lists]
    held = [min(m, lay.slot_max) for m in most]

    def fits(threads: int | None) -> bool:
        return bool(threads and lay.slot_max and cudagen.slot_code(
            lists, held, n, threads) <= lay.slot_code_max)

    threads = lay.split_threads
    if threads is None:
        one = cudagen.node_threads(n)
        threads = one if fits(one) else cudagen.LOOP_THREADS
    if not fits(threads):
        return threads, ()
    return threads, tuple((sl.name, k, m > k) for sl, k, m in zip(lists, held, most))


def kernel_text(net: FlatNetlist, opts: cudagen.CudaOptions) -> str:
    """The CUDA kernel's text for the force netlist `net` (`force_netlist`) under `opts`
    (`springc.kernels.loader` imports it; numba.cuda compiles it at its first launch)."""
    from springc.kernels import cuda as cudagen

    return cudagen.generate(net, opts)


_STATE = ("x0", "v0")
_CONST = ("vneed", "rec_node", "rec_isv", "ds_i", "ds_j", "ds_b", "ms_node", "ms_isv",
          "ms_lo", "ms_hi", "gr_i", "gr_j", "gr_g", "gr_w", "gr_decay")
_SUMS = ("work_in", "work_c", "diss", "msq", "gram")


def run(kernel: loader.Kernel, args: dict, runs: int) -> None:
    """Integrate `runs` runs of the arrays `simulate` prepared (`args`: the CPU kernels'
    argument names) on the GPU, `steps_per_call()` steps a call, filling args' records
    (`rec`, from column `rec_col`), reductions, final state (`xf`, `vf`) and status as the
    CPU kernels do."""
    from numba import cuda

    mod = kernel.module
    nsteps, sub, every = int(args["nsteps"]), int(args["substeps"]), int(args["rec_every"])
    dtype = args["x0"].dtype
    if "gr_ptr" in mod.ARGS:
        args = {**args, **_pairs_by_group(args)}
    if mod.SLOTS:
        args = {**args, **_slot_tables(args, mod.SLOTS, len(mod.VNEED))}
    if "deal" in mod.ARGS:
        args = {**args, "deal": deal(args, mod.DEAL, len(mod.VNEED))}
    dev = {name: _to_device(args[name]) for name in mod.ARGS if name in args
           and name not in ("u", "g", "rec") and isinstance(args[name], np.ndarray)}
    dev["vneed"] = cuda.to_device(np.array(mod.VNEED, np.bool_))
    dev["xst"], dev["vst"] = (cuda.to_device(np.ascontiguousarray(args[k])) for k in _STATE)
    for name in _SUMS:
        dev[name] = cuda.to_device(_rows(args[name]))
    _record_start(args, runs)
    threads = mod.BLOCK if mod.T > 1 else min(mod.BLOCK, runs)
    blocks = runs if mod.T > 1 else -(-runs // threads)
    per_call = steps_per_call()
    for s0 in range(0, nsteps, per_call):
        s1 = min(nsteps, s0 + per_call)
        a, b = s0 // sub, (s1 - 1) // sub + 3
        call = {**dev, "u": _inputs(args["u"], a, b), "ubase": a, "g": _signals(args["g"], s0, s1),
                "s0": s0, "s1": s1, "rbase": s0 // every + 1}
        count = s1 // every - s0 // every
        call["rec"] = cuda.device_array((max(args["rec"].shape[0], 1), max(count, 1), runs),
                                        dtype)
        for name in ("nsteps", "substeps", "h", "check_every", "limit", "rec_every"):
            call[name] = args[name]
        with warnings.catch_warnings():  # a launch of few runs is not a user's error
            # numba-cuda's warning is its own class, not numba's: matched by its text
            warnings.filterwarnings("ignore", message=".*Grid size")
            mod.run[blocks, threads](*[call[name] for name in mod.ARGS])
        if args["rec"].shape[0] and count:
            col = int(args["rec_col"])
            got = call["rec"].copy_to_host()
            args["rec"][:, col:col + runs, s0 // every + 1:s1 // every + 1] = got.transpose(0, 2, 1)
    cuda.synchronize()
    args["xf"][...] = dev["xst"].copy_to_host()
    args["vf"][...] = dev["vst"].copy_to_host()
    for name in _SUMS:
        rows = args[name].shape[0]
        args[name][...] = dev[name].copy_to_host()[:rows]
    args["status"][...] = dev["status"].copy_to_host()
    args["bad_node"][...] = dev["bad_node"].copy_to_host()


def _pairs_by_group(args: dict) -> dict:
    """The Gram pairs sorted by group, each group's in their order, and each group's range
    (`gr_ptr`): the split form sums a group in one thread."""
    order = np.argsort(args["gr_g"], kind="stable")
    out = {name: np.ascontiguousarray(args[name][order])
           for name in ("gr_i", "gr_j", "gr_g", "gr_w")}
    groups = len(args["gr_decay"])
    out["gr_ptr"] = np.searchsorted(out["gr_g"], np.arange(groups + 1)).astype(np.int64)
    return out


def deal(args: dict, ptrs: tuple[str, ...], n: int) -> np.ndarray:
    """The split form's order of its nodes (thread t takes those at positions t, t + T, ...):
    nodes with the same count of each list (`ptrs`: the CSR ranges of a node's stiffness row,
    inputs and element ends) and the same damping side by side, so that a warp's threads
    mostly run the same terms: a warp runs each term that any of its threads has (a node's
    sum and its order do not depend on the thread that sums it)."""
    keys = [np.diff(args[p][:n + 1].astype(np.int64)) for p in ptrs]
    keys.append((np.asarray(args["bm"][:n]) != 0).astype(np.int64))
    return np.lexsort([np.arange(n)] + keys[::-1]).astype(np.int32)


def _slot_tables(args: dict, spec: tuple, n: int) -> dict:
    """The split form's register lists as tables (the kernel's `SLOTS`): each node's count
    per list (`sl_n`, (lists, n)) and the fields of its first entries per list
    (`sl_{list}_{field}`, (entries, n): neighbouring threads read neighbouring words), indices
    as int32 (half the registers of int64), zeros past a node's count."""
    counts = np.zeros((len(spec), n), np.int32)
    out = {"sl_n": counts}
    for row, (name, k, ptr, elem, fields) in enumerate(spec):
        start = args[ptr][:n].astype(np.int64)
        counts[row] = args[ptr][1:n + 1].astype(np.int64) - start
        for field, array, by_elem in fields:
            src = args[array]
            dtype = src.dtype if src.dtype.kind == "f" else np.dtype(np.int32)
            table = np.zeros((k, n), dtype)
            for q in range(k):
                has = counts[row] > q
                entry = start[has] + q
                at = args[elem][entry].astype(np.int64) if by_elem else entry
                table[q, has] = src[at]
            out[f"sl_{name}_{field}"] = table
    return out


def _to_device(a: np.ndarray):
    """A constant array on the device (an empty one as one zero: no zero-size launches)."""
    from numba import cuda

    a = np.ascontiguousarray(a)
    return cuda.to_device(a if a.size else np.zeros((1,) * max(a.ndim, 1), a.dtype))


def _rows(a: np.ndarray) -> np.ndarray:
    """A (rows, runs) sum array with at least one row."""
    return np.ascontiguousarray(a if a.shape[0] else np.zeros((1, a.shape[1]), a.dtype))


def _record_start(args: dict, runs: int) -> None:
    """Record 0 (the initial state), which the CPU kernels write at their start."""
    rec = args["rec"]
    if not rec.shape[0]:
        return
    col = int(args["rec_col"])
    for p, (q, isv) in enumerate(zip(args["rec_node"], args["rec_isv"])):
        rec[p, col:col + runs, 0] = (args["v0"] if isv else args["x0"])[int(q)]


def _inputs(u: np.ndarray, a: int, b: int):
    """Input samples a..b-1 of every run, laid out (channel, sample, run): neighbouring
    threads read neighbouring words."""
    from numba import cuda

    part = u[:, :, a:min(b, u.shape[2])]
    if not part.size:
        return cuda.to_device(np.zeros((1, 1, 1), u.dtype))
    return cuda.to_device(np.ascontiguousarray(part.transpose(1, 2, 0)))


def _signals(g: np.ndarray, s0: int, s1: int):
    """The shared signals of steps s0..s1-1 (step, stage, force)."""
    from numba import cuda

    part = g[s0:s1] if g.shape[2] else g
    return cuda.to_device(np.ascontiguousarray(part if part.size else np.zeros((1, 1, 1),
                                                                               g.dtype)))
