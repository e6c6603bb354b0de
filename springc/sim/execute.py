"""The execution of a planned simulation on a device: its records' memory, the kernel calls
batch by batch, each call's chunks of runs on threads (the kernel releases the GIL) or on
the GPU, and each batch's reductions finished (`springc.sim.finish`)."""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import TYPE_CHECKING

import numpy as np

from springc.errors import UsageError
from springc.kernels import codegen, expint, loader
from springc.sim import finish, gpu, reductions, sources
from springc.sim.marshal import Lanes, damper_coefficients

if TYPE_CHECKING:
    from springc.sim.timegrid import Settings

CHECK_EVERY = 256  # steps between divergence checks


def threads() -> int:
    """Cores this process may use: the threads a kernel call spreads its chunks over."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def run_batches(net, kernel, st: Settings, coeffs, signals, names, plist, rplan, batch, task,
                 progress, rec: np.ndarray, lanes: Lanes | None = None,
                 first_run: int = 0) -> tuple[np.ndarray, dict, dict]:
    """The kernel calls, batch by batch, all recording into `rec` (one record for all the
    calls, each writing its own runs' rows: no copy at the end, a recording at every step is
    hundreds of MB). With `lanes`, run r reads input r % reps. Run r draws the noise streams
    of run `first_run` + r. Returns the time axis, the probes (views of `rec`) and the
    reductions."""
    runs = len(names)
    dtype = np.dtype(st.precision)
    tab = expint.stage_tableau(st.method)
    g = sources.common_table(net, st.nsteps, st.h, st.tstep, tab).astype(dtype)
    records = st.nsteps // st.rec_every + 1
    chunks = []
    bar = _progress(runs, progress)
    for lo in range(0, runs, batch):
        hi = min(runs, lo + batch)
        part = None if signals is None else _batch_inputs(signals, lo, hi)
        chunks.append(_run_one_batch(net, kernel, st, part, hi - lo, coeffs, g, plist, rec, lo,
                                     rplan, task, names[lo:hi], lanes, first_run))
        if bar is not None:
            bar.update(hi - lo)
    if bar is not None:
        bar.close()
    t = np.arange(records) * st.rec_every * st.h
    probes = {p.label: rec[k, :, :records] for k, p in enumerate(plist)}
    join = (lambda parts: parts[0]) if len(chunks) == 1 else np.concatenate
    reds = {k: join([c[k] for c in chunks]) for k in chunks[0]}
    return t, probes, reds


def _batch_inputs(signals: np.ndarray, lo: int, hi: int) -> np.ndarray:
    """The inputs of runs lo..hi-1, run r reading input r % len(signals) (the members of
    `simulate_lanes` share the inputs)."""
    if hi <= len(signals):
        return signals[lo:hi]
    return signals[np.arange(lo, hi) % len(signals)]


def _progress(runs: int, enabled: bool):
    if not enabled or runs <= 1:
        return None
    from tqdm import tqdm

    return tqdm(total=runs, unit="run", desc="simulating")


def _run_one_batch(net, kernel, st, signals, runs, coeffs, g, plist, rec, col, rplan, task,
                   names, lanes: Lanes | None = None, first_run: int = 0):
    """Simulate `runs` runs in one kernel call (their probes into rows col.. of `rec`);
    returns the reductions. With `lanes`, runs col.. of its per-run arrays."""
    dtype = np.dtype(st.precision)
    if lanes is None:
        x0, v0 = (np.repeat(s[:, None], runs, 1) for s in net.initial_state())
    else:
        x0, v0 = lanes.x0[:, col:col + runs], lanes.v0[:, col:col + runs]
    nch = sources.channels_used(net)
    nsamples = st.nsteps // st.substeps + 1
    args = dict(coeffs)
    args.update(
        x0=np.ascontiguousarray(x0, dtype),
        v0=np.ascontiguousarray(v0, dtype),
        u=sources.kernel_inputs(signals, runs, nch, nsamples, dtype), g=g,
        nsteps=st.nsteps, substeps=st.substeps, h=st.h,
        chunk=kernel.module.LANES,
        check_every=CHECK_EVERY, limit=finish.LIMITS[st.precision],
        xf=np.zeros((net.n, runs), dtype), vf=np.zeros((net.n, runs), dtype),
        status=np.zeros(runs, np.int64), bad_node=np.zeros(runs, np.int64),
        run0=first_run + col,  # the population index of this batch's first run: its noise
    )
    args.update(rec_every=st.rec_every, rec_node=np.array([p.node for p in plist], np.uint64),
                rec_isv=np.array([p.quantity == "v" for p in plist], np.bool_),
                rec=rec, rec_col=col)
    nf = len(net.forces)
    args.update(work_in=np.zeros((len(sources.input_forces(net)), runs)),
                work_c=np.zeros((len(sources.common_forces(net)), runs)))
    rows = rplan.damper_rows
    args.update(ds_i=np.array([r[0] for r in rows], np.int64),
                ds_j=np.array([r[1] for r in rows], np.int64),
                ds_b=damper_coefficients(rplan, st.precision), diss=np.zeros((len(rows), runs)))
    wins = [reductions.msq_window(r, st.h, st.nsteps) for r in rplan.msq]
    args.update(ms_node=np.array([r.node for r in rplan.msq], np.int64),
                ms_isv=np.array([r.isv for r in rplan.msq], np.bool_),
                ms_lo=np.array([w[0] for w in wins], np.int64),
                ms_hi=np.array([w[1] for w in wins], np.int64),
                msq=np.zeros((len(wins), runs)))
    ngram = sum(r.gram.groups for r in rplan.gram)
    args.update(reductions.gram_arrays(rplan, st.h, dtype), gram=np.zeros((ngram, runs)))
    if lanes is not None:  # this call's columns of the per-run arrays
        args.update({k: np.ascontiguousarray(v[:, col:col + runs])
                     for k, v in lanes.per_run.items()})
    run_chunks(kernel, args, runs, task)
    work = np.zeros((nf, runs))
    work[sources.input_forces(net)] = args["work_in"]
    work[sources.common_forces(net)] = args["work_c"]
    with np.errstate(all="ignore"):  # a diverged run's sums are NaN; the others are kept
        out = finish.finish_reductions(net, rplan, args, work, wins, st,
                                 None if lanes is None else lanes.members(col, col + runs),
                                 None if lanes is None else lanes.nets)
    finish.check_divergence(net, st, args, names, out)
    return out


def available_memory() -> int:
    """Bytes of memory available to a new allocation (Linux: MemAvailable)."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_AVPHYS_PAGES")


MEMORY_SHARE = 0.8  # of the available memory that the records may take


def require_memory(probes: int, records: int, runs: int, precision: str,
                   reuse: np.ndarray | None) -> None:
    """Refuse, before anything runs, records that would not fit in memory, naming their size
    and what reduces it (the time axis counts too: it is there with no probe)."""
    dtype = np.dtype(precision)
    need = records * np.dtype(np.float64).itemsize
    if reuse is None and probes:
        need += math.prod(record_shape(probes, records, runs, dtype)) * dtype.itemsize
    have = available_memory()
    if need > MEMORY_SHARE * have:
        raise UsageError(
            f"the records would take {need / 2**30:.3g} GiB ({probes} probe(s) x {runs} run(s)"
            f" x {records} samples, and the time axis), more than the {have / 2**30:.3g} GiB "
            "of memory available",
            hint="record fewer samples (--outrate), fewer probes, shorter runs (--tstop), or "
                 "stream what you need with --reduce and no probes")


def record_buffer(probes: int, records: int, runs: int, dtype) -> np.ndarray:
    """Zeros (probe, run, record) for the kernel's recording: each run's trajectory
    contiguous, each row padded to, and the whole aligned on, `codegen.RECORD_ALIGN` bytes,
    which the kernel's aligned streaming stores of whole lines need (a misaligned one would
    fault). One buffer holds all the runs of a simulation, each kernel call writing its own
    rows, and each probe is handed out as a (run, record) view of it."""
    dtype = np.dtype(dtype)
    shape = record_shape(probes, records, runs, dtype)
    size = math.prod(shape)
    raw = np.zeros(size + codegen.record_block(dtype), dtype)
    skip = (-raw.ctypes.data % codegen.RECORD_ALIGN) // dtype.itemsize
    return raw[skip:skip + size].reshape(shape)


def record_shape(probes: int, records: int, runs: int, dtype) -> tuple[int, int, int]:
    """(probe, run, record) of `record_buffer`: each row padded to whole lines of
    `codegen.RECORD_ALIGN` bytes."""
    per_line = codegen.record_block(dtype)
    return probes, runs, -(-records // per_line) * per_line


def records_buffer(probes: int, records: int, runs: int, dtype, reuse: np.ndarray | None
             ) -> np.ndarray:
    """The record buffer: `reuse` when given (checked against what this call records), else
    a fresh `record_buffer`."""
    if reuse is None:
        return record_buffer(probes, records, runs, dtype)
    shape = record_shape(probes, records, runs, dtype)
    misaligned = reuse.size and (not reuse.flags.c_contiguous
                                 or reuse.ctypes.data % codegen.RECORD_ALIGN)
    if reuse.shape != shape or reuse.dtype != dtype or misaligned:
        raise UsageError(f"record_into is a {reuse.dtype} buffer of shape {reuse.shape}; this "
                         f"call records into {dtype} {shape}, aligned on "
                         f"{codegen.RECORD_ALIGN} bytes (pass an earlier call's "
                         "info['records'] with the same probes, runs and steps)")
    return reuse




def run_chunks(kernel, args: dict, runs: int, task: int) -> None:
    """Run the kernel's chunks (of `LANES` runs) as tasks of about `task` runs, each a
    contiguous range of chunks, on up to `threads()` threads (the kernel releases the GIL and
    each chunk writes only its own columns). A kernel without CHUNK_RANGE (a numba prange
    kernel) runs all its chunks in one call, and one with NODE_THREADS does so on
    `threads()` of numba's threads. A CUDA kernel runs them on the GPU (`gpu.run`)."""
    if getattr(kernel.module, "CUDA", False):
        gpu.run(kernel, args, runs)
        return
    nchunks = -(-runs // kernel.module.LANES)
    fixed = {k: args[k] for k in kernel.args if k not in ("c0", "c1")}
    if getattr(kernel.module, "NODE_THREADS", False):
        with loader.numba_threads(threads()):
            kernel.run(**fixed, c0=0, c1=nchunks)
        return
    ntasks = min(nchunks, -(-runs // max(task, 1)))
    if not getattr(kernel.module, "CHUNK_RANGE", False):
        ntasks = 1
    bounds = [nchunks * t // ntasks for t in range(ntasks + 1)]

    def call(t: int) -> None:
        kernel.run(**fixed, c0=bounds[t], c1=bounds[t + 1])

    on_threads(ntasks, call)


def on_threads(count: int, call: Callable[[int], None]) -> None:
    """call(k) for every k < count, on up to one thread per core (the kernels release the
    GIL); in this thread when one would do."""
    workers = min(count, threads())
    if workers <= 1:
        for k in range(count):
            call(k)
        return
    with ThreadPoolExecutor(workers) as pool:
        list(pool.map(call, range(count)))
