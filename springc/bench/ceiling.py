"""The machine's arithmetic ceiling for batched RK4 on a network: how many run-seconds per
wall-second the hardware could reach at best, to report a kernel's throughput as a fraction.

What `measure_ceiling` measures, exactly: a Numba loop with the shape and memory traffic of an
explicit 4-stage Runge-Kutta kernel on an (n_dof, batch) state (batch innermost, contiguous),
parallelised over batch chunks with the time loop inside each thread, as a real batched kernel
is. Per stage and per (dof, lane) it reads the state x, v and the previous stage derivatives
kx, kv, writes the new kx, kv and updates the accumulators ax, av (6 reads, 4 writes); once per
step it adds the accumulators into x, v. In between, the "force" is a fixed chain of `n_pad`
fused multiply-adds in registers, standing for the network's own force arithmetic, so that the
loop executes `flops_per_dof_step(n_pad)` flops per (dof, lane, step): as many as the kernel
being rated, but with no gathers, no branches and no dependence on neighbours. Its arithmetic
is a stable damped oscillator per lane (values stay bounded: no overflow, no subnormals).

Timed after a warm-up (compilation and first touch of the memory), over enough steps to last
about `min_seconds`. From the wall time it reports flop/s and the equivalent throughput
    run-seconds per wall-second = flop/s / (F * n_dof * rate)
for the given flop count F per dof-step at the given sample rate (a "run" is one batch lane
simulated for one second of signal). It is the ceiling of a kernel that moves its state and
stage rows through memory at every stage, as the shared kernel does (`springc.kernels.codegen`): a
kernel with F flops per dof-step of that shape cannot beat it on this machine without doing
less arithmetic. A register kernel (`springc.kernels.regkernel`) keeps its stage values in registers
and can (docs/performance.md#the-ceiling-and-the-fma-peak). Hence `measure_peak`, the
machine's FMA peak for the batch: chains of FMAs held in registers, which no kernel doing F
flops per dof-step can beat at all.

The loop reuses its memory and writes no output. A kernel that records its probes writes them too,
as non-temporal lines (`springc.kernels.streamstore`), into fresh memory, which the OS hands out a
page at a time on first write. `first_touch_seconds` measures the fresh pages alone for a record of
a given size, and `store_seconds` the writing of the record's lines into memory already handed out,
so that a report can tell each from the kernel's own arithmetic.
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager

import numba
import numpy as np

from springc.lang.ir import FlatNetlist
from springc.kernels.streamstore import store_fence, stream_store

STAGES = 4
# Flops of one (dof, lane) in one stage without padding, and per step outside the stages;
# see `_stage` for the count: 2 + 2 (stage state) + 1 + 5 (derivatives) + 4 (accumulate).
STAGE_FLOPS = 14
STEP_FLOPS = 2  # x += ax, v += av
# Coefficients of the per-lane oscillator, in units of the step: stable under RK4.
_W2H2, _GH, _ALPHA, _BETA, _EPS = 0.01, 0.01, 0.5, 1.0, 1e-3
_RK4_C = (0.0, 0.5, 0.5, 1.0)
_RK4_W = (1 / 6, 1 / 3, 1 / 3, 1 / 6)


def flops_per_dof_step(n_pad: int) -> int:
    """Flops the ceiling loop executes per (dof, lane, step) with `n_pad` padding FMAs per
    stage (an FMA counts 2 flops, a lone multiply or add 1)."""
    return STAGES * (STAGE_FLOPS + 2 * n_pad) + STEP_FLOPS


def padding_for(flops: float) -> int:
    """Padding FMAs per stage whose loop comes closest to `flops` per dof-step (at least 0)."""
    return max(0, round((flops - flops_per_dof_step(0)) / (2 * STAGES)))


def bytes_per_dof_step(itemsize: int) -> int:
    """Bytes moved per (dof, lane, step): per stage 6 reads and 4 writes; per step x, v, ax,
    av read and x, v written, ax, av reset (counted as the loop is written, cache or not)."""
    return itemsize * (STAGES * 10 + 8)


def rk4_flops_per_dof_step(net: FlatNetlist) -> float:
    """Flops per (dof, lane, step) of a straightforward RK4 kernel on `net`, counted per element:
    per dof and stage 4 (stage state) + 1 (divide by mass, as a multiply) + 4 (accumulate) and 2
    for a local damper; K 2, D 4, C 6, Q 8, dashpot 4, P (2 + degree) per variable, F 5 (gain
    and input interpolation); plus 2 per dof and step. An estimate for rating a kernel when its
    own count is not known; a kernel reports its own count when it has one."""
    per_stage = 9.0 * net.n + 2.0 * np.count_nonzero(net.local_damping())
    per_stage += 2 * len(net.springs) + 4 * len(net.duffings) + 6 * len(net.couplings)
    per_stage += 8 * len(net.quads) + 4 * len(net.dashpots) + 5 * len(net.forces)
    p = net.monomials
    for e in range(len(p)):
        lo, hi = p.ptr[e], p.ptr[e + 1]
        per_stage += len(set(p.var[lo:hi].tolist())) * (2 + int(p.exp[lo:hi].sum()))
    return (STAGES * per_stage + STEP_FLOPS * net.n) / max(net.n, 1)


def run_seconds_per_wall_second(
    flops_per_second: float, flops_per_step: float, n_dof: int, rate: float
) -> float:
    """Lanes times simulated seconds per wall second that `flops_per_second` sustains for a
    kernel doing `flops_per_step` flops per dof-step on `n_dof` dofs at `rate` steps/s."""
    return flops_per_second / (flops_per_step * n_dof * rate)


def measure_ceiling(
    n_dof: int,
    batch: int,
    precision: str = "float64",
    threads: int = 2,
    flops_per_step: float = 70.0,
    rate: float = 32000.0,
    min_seconds: float = 0.3,
) -> dict:
    """Measure the arithmetic ceiling (see the module docstring) for an (n_dof, batch) state.

    `flops_per_step` is the flop count per dof-step of the kernel to rate (default: an RK4
    chain, see `rk4_flops_per_dof_step`); returns a dict with the measured `seconds`,
    `flops_per_second`, `bytes_per_second`, `dof_steps_per_second` and
    `run_seconds_per_wall_second` at `rate`, and the loop's own `flops_per_dof_step`."""
    dtype = _dtype(precision)
    with _numba_threads(threads) as threads:
        n_pad = padding_for(flops_per_step)
        state = make_state(n_dof, batch, dtype, threads)
        kernel = functools.partial(_kernel(n_pad), *state, *_coefficients(dtype))
        kernel(2)  # warm-up: compile, first touch
        steps, seconds = _timed(kernel, min_seconds)
    return _report(n_dof, batch, precision, threads, n_pad, steps, seconds, flops_per_step, rate)


# The FMA peak: per lane, independent chains of FMAs held in registers, as a register
# kernel's lane loop holds its step
PEAK_CHAINS = 8  # enough to keep both FMA pipes busy through an FMA's latency
PEAK_DEPTH = 32  # FMAs per chain between its load and its store


def measure_peak(batch: int, precision: str = "float64", threads: int = 2,
                 min_seconds: float = 0.3) -> dict:
    """Measure the machine's FMA peak for `batch` lanes (see the module docstring): per lane
    PEAK_CHAINS independent chains of PEAK_DEPTH fused multiply-adds in registers, the lanes
    vectorised as a register kernel's are, one chunk of lanes per thread, a load and a store
    per chain and pass of PEAK_DEPTH. Returns a dict with `passes`, `seconds`, `threads` and
    `flops_per_second` (padding lanes of an uneven split included: the machine did them)."""
    dtype = _dtype(precision)
    with _numba_threads(threads) as threads:
        chunks, width = chunking(batch, threads)
        acc = peak_state(chunks, width, dtype)
        kernel = functools.partial(_peak_kernel(width), acc, np.array([_ALPHA, _BETA], dtype))
        kernel(2)  # warm-up: compile
        passes, seconds = _timed(kernel, min_seconds)
    flops = 2 * PEAK_CHAINS * PEAK_DEPTH * chunks * width * passes
    return {"batch": batch, "precision": precision, "threads": threads, "passes": passes,
            "seconds": seconds, "flops_per_second": flops / seconds}


def peak_state(chunks: int, width: int, dtype: type) -> np.ndarray:
    """The peak loop's chains: (chunk, chain, lane), distinct starting values."""
    start = np.linspace(-1.0, 1.0, chunks * PEAK_CHAINS * width)
    return start.reshape(chunks, PEAK_CHAINS, width).astype(dtype)


@functools.cache
def _peak_kernel(width: int):
    """The peak loop for chunks of `width` lanes: acc <- alpha * acc + beta, PEAK_DEPTH times
    a pass, for `passes` passes. Written out as text, each chain a scalar of the lane loop's
    body: LLVM then keeps the chains in registers and vectorises the lanes (numba compiles
    the function from its code object)."""
    body = [f"A{k} = acc[c, {k}, b]" for k in range(PEAK_CHAINS)]
    body += [f"A{k} = alpha * A{k} + beta" for _ in range(PEAK_DEPTH) for k in range(PEAK_CHAINS)]
    body += [f"acc[c, {k}, b] = A{k}" for k in range(PEAK_CHAINS)]
    source = "\n".join(["def run(acc, coef, passes):",
                        "    alpha, beta = coef[0], coef[1]",
                        "    for c in numba.prange(acc.shape[0]):",
                        "        for _ in range(passes):",
                        f"            for b in range({width}):"]
                       + ["                " + line for line in body])
    scope = {"numba": numba}
    exec(source, scope)  # noqa: S102  (our own text, no input in it)
    return numba.njit(parallel=True, fastmath={"contract"}, error_model="numpy")(scope["run"])


def _dtype(precision: str) -> type:
    if precision not in ("float64", "float32"):
        raise ValueError(f"precision must be float64 or float32, not {precision!r}")
    return np.float64 if precision == "float64" else np.float32


def chunking(batch: int, threads: int) -> tuple[int, int]:
    """(chunks, lanes per chunk) of a batch split over `threads`: min(threads, batch) chunks
    of equal width, the last padded."""
    chunks = max(1, min(threads, batch))
    return chunks, -(-batch // chunks)


@contextmanager
def _numba_threads(threads: int) -> Iterator[int]:
    """numba's thread count set to `threads` (at most what numba has) inside the block, and
    back to the caller's after it; yields the count set."""
    previous = numba.get_num_threads()
    threads = max(1, min(int(threads), numba.config.NUMBA_NUM_THREADS))
    try:
        numba.set_num_threads(threads)
        yield threads
    finally:
        numba.set_num_threads(previous)  # the caller's kernels keep their thread count


def make_state(n_dof: int, batch: int, dtype: type, threads: int) -> tuple[np.ndarray, ...]:
    """x, v, kx, kv, ax, av for an (n_dof, batch) state split into min(threads, batch) chunks
    of equal width (the last padded, as the slowest thread of an uneven split sets the pace),
    each chunk one contiguous row of shape (chunks, n_dof * width). Deterministic start.

    The six arrays start at offsets spread evenly over a 4 KiB page (`staggered`): large
    allocations land at equal page offsets, where each load falsely waits on an earlier store
    to another array at the same offset (4K aliasing), which can halve the loop's speed at
    random between measurements, and the ceiling is the machine's best
    (docs/performance.md#the-ceiling-and-the-fma-peak)."""
    chunks, width = chunking(batch, threads)
    cells = n_dof * width
    x = np.linspace(0.1, 1.0, chunks * cells).reshape(chunks, cells).astype(dtype)
    arrays = (x, *(np.zeros((chunks, cells), dtype) for _ in range(5)))
    return tuple(staggered(a, k * PAGE // len(arrays)) for k, a in enumerate(arrays))


PAGE = 4096  # bytes: the span of address bits a load is matched against earlier stores with
LINE = 64  # bytes


def staggered(a: np.ndarray, offset: int) -> np.ndarray:
    """A copy of `a` whose data starts `offset` bytes (rounded down to a cache line) into a
    4 KiB page."""
    item = a.dtype.itemsize
    raw = np.empty(a.size + 2 * PAGE // item, a.dtype)
    start = (-raw.ctypes.data % PAGE + offset // LINE * LINE) // item
    out = raw[start:start + a.size].reshape(a.shape)
    out[...] = a
    return out


def _timed(kernel: Callable[[int], None], min_seconds: float) -> tuple[int, float]:
    """Steps and wall time of the first run that lasts at least `min_seconds`, growing the
    step count from a short calibration run."""
    steps = 8
    while True:
        t0 = time.perf_counter()
        kernel(steps)
        seconds = time.perf_counter() - t0
        if seconds >= min_seconds:
            return steps, seconds
        steps = int(steps * min(64.0, max(2.0, 1.2 * min_seconds / max(seconds, 1e-6))))


def _report(n_dof, batch, precision, threads, n_pad, steps, seconds, flops_per_step, rate) -> dict:
    loop_flops = flops_per_dof_step(n_pad)
    dof_steps = n_dof * batch * steps
    flops_per_second = loop_flops * dof_steps / seconds
    itemsize = np.dtype(precision).itemsize
    return {
        "n_dof": n_dof,
        "batch": batch,
        "precision": precision,
        "threads": threads,
        "steps": steps,
        "seconds": seconds,
        "n_pad": n_pad,
        "flops_per_dof_step": loop_flops,
        "flops_per_step_rated": float(flops_per_step),
        "flops_per_second": flops_per_second,
        "bytes_per_second": bytes_per_dof_step(itemsize) * dof_steps / seconds,
        "dof_steps_per_second": dof_steps / seconds,
        "rate": rate,
        "run_seconds_per_wall_second": run_seconds_per_wall_second(
            flops_per_second, flops_per_step, n_dof, rate
        ),
    }


def _coefficients(dtype: type) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Loop coefficients as arrays of the state's dtype, so float32 arithmetic stays float32
    (Python float constants would promote it to float64). The step `h` = 1 is data, not a
    constant, so that the multiply by it is not folded away."""
    coef = np.array([_ALPHA, _BETA, _W2H2, _GH, _EPS, 1.0], dtype=dtype)
    return coef, np.array(_RK4_C, dtype=dtype), np.array(_RK4_W, dtype=dtype)


@functools.cache
def _kernel(n_pad: int):
    """The ceiling loop with `n_pad` (a compile-time constant, so the chain is unrolled and the
    lane loop vectorised) padding FMAs per stage. Returns the jitted function."""
    fast = {"contract"}  # FMA contraction only: no reassociation

    # Each chunk's (n_dof, width) block is one contiguous row, swept by one flat loop over its
    # full length: LLVM vectorises that (it does not when Numba indexes 2-D arrays with
    # `range(lo, hi)`, for fear of negative indices), and no per-row overhead is charged.
    @numba.njit(fastmath=fast, error_model="numpy", inline="always")
    def stage(x, v, kx, kv, ax, av, coef, cc, ww):
        alpha, beta, w2h2, gh, eps, h = coef[0], coef[1], coef[2], coef[3], coef[4], coef[5]
        for j in range(x.shape[0]):
            xs = cc * kx[j] + x[j]
            vs = cc * kv[j] + v[j]
            p = xs
            for _r in range(n_pad):
                p = alpha * p + beta
            kxn = h * vs
            kvn = -w2h2 * xs + (-gh * vs + eps * p)
            kx[j] = kxn
            kv[j] = kvn
            ax[j] = ww * kxn + ax[j]
            av[j] = ww * kvn + av[j]

    @numba.njit(fastmath=fast, error_model="numpy", inline="always")
    def update(x, v, ax, av):
        for j in range(x.shape[0]):
            x[j] += ax[j]
            v[j] += av[j]
            ax[j] = 0
            av[j] = 0

    @numba.njit(parallel=True, fastmath=fast, error_model="numpy")
    def run(x, v, kx, kv, ax, av, coef, cs, ws, steps):
        for c in numba.prange(x.shape[0]):
            for _ in range(steps):
                for s in range(4):
                    stage(x[c], v[c], kx[c], kv[c], ax[c], av[c], coef, cs[s], ws[s])
                update(x[c], v[c], ax[c], av[c])

    return run


def run_loop(state: tuple[np.ndarray, ...], n_pad: int, steps: int, threads: int = 1) -> None:
    """Advance `state` (x, v, kx, kv, ax, av from `make_state`) by `steps` steps of the
    ceiling loop, one thread per chunk (at most `threads`)."""
    with _numba_threads(threads):
        _kernel(n_pad)(*state, *_coefficients(state[0].dtype.type), steps)


def reference_steps(state: tuple[np.ndarray, ...], n_pad: int, steps: int) -> None:
    """The ceiling loop's arithmetic in plain numpy (in place), for tests of what it computes."""
    x, v, kx, kv, ax, av = state
    coef, cs, ws = _coefficients(x.dtype.type)
    alpha, beta, w2h2, gh, eps, h = coef
    for _ in range(steps):
        for cc, ww in zip(cs, ws):
            xs, vs = cc * kx + x, cc * kv + v
            p = xs.copy()
            for _r in range(n_pad):
                p = alpha * p + beta
            kx[...] = h * vs
            kv[...] = -w2h2 * xs + (-gh * vs + eps * p)
            ax += ww * kx
            av += ww * kv
        x += ax
        v += av
        ax[...] = 0
        av[...] = 0


def first_touch_seconds(shape: tuple[int, int, int], precision: str, threads: int = 2) -> float:
    """Wall time to allocate a zeroed (probe, run, record) array of `shape`, as a kernel's
    record, and write one value into each of its 4 KiB pages (`touch_record`). The OS hands
    out fresh memory a page at a time on first write (a fault and the zeroing of the page):
    a cost of any method that writes that much output into new memory, which the ceiling
    loop, reusing its memory, does not pay."""
    dtype = _dtype(precision)
    touch_pages(np.zeros(2 * PAGE, dtype), 0, 2 * PAGE, 1)  # compile outside the timing
    start = time.perf_counter()
    flat = np.zeros(math.prod(shape), dtype)  # untouched: the OS maps zero pages lazily
    touch_record(flat, shape, threads)
    return time.perf_counter() - start


def touch_record(flat: np.ndarray, shape: tuple[int, int, int], threads: int) -> None:
    """One write into each page of `flat`, a (probe, run, record) array of `shape` flattened,
    by `threads` threads, each the rows of its own runs (as the kernels' threads write)."""
    probes, runs, width = shape
    threads = max(1, min(threads, runs))
    bounds = [runs * t // threads for t in range(threads + 1)]
    stride = PAGE // flat.itemsize

    def rows_of(t: int) -> None:
        for p in range(probes):
            touch_pages(flat, (p * runs + bounds[t]) * width,
                        (p * runs + bounds[t + 1]) * width, stride)

    with ThreadPoolExecutor(threads) as pool:
        list(pool.map(rows_of, range(threads)))


@numba.njit(nogil=True)
def touch_pages(flat: np.ndarray, lo: int, hi: int, stride: int) -> None:
    """flat[k] = 1 for k = lo, lo + stride, ... below hi, and at hi - 1: writes at most
    `stride` elements (a page) apart from the first element to the last, so every page
    that flat[lo:hi] overlaps gets one (the first touch, which makes the OS fault it in)."""
    for k in range(lo, hi, stride):
        flat[k] = 1
    if hi > lo:
        flat[hi - 1] = 1


def store_seconds(rec: np.ndarray, threads: int = 2) -> float:
    """Wall time to write every line of the record `rec` (probe, run, record; rows padded to
    and aligned on 64-byte lines, as `execute.record_buffer` makes it) once with
    non-temporal line stores, as the kernels write their records, by `threads` threads each
    on the rows of its own runs; `rec` is first written once untimed, so its pages are
    handed out already (a reused record buffer)."""
    probes, runs, width = rec.shape
    line = LINE // rec.itemsize
    if rec.ctypes.data % LINE or width % line:
        raise ValueError("rec must be 64-byte aligned with rows of whole 64-byte lines")
    values = (rec.dtype.type(1.0),) * line
    threads = max(1, min(threads, runs))
    bounds = [runs * t // threads for t in range(threads + 1)]

    def rows_of(t: int) -> None:
        _store_lines(rec, bounds[t], bounds[t + 1], values)

    with ThreadPoolExecutor(threads) as pool:
        list(pool.map(rows_of, range(threads)))  # compiles, and hands out the pages
        start = time.perf_counter()
        list(pool.map(rows_of, range(threads)))
    return time.perf_counter() - start


@numba.njit(nogil=True)
def _store_lines(rec: np.ndarray, r0: int, r1: int, values: tuple) -> None:
    """Runs r0..r1-1 of every probe of `rec`, one line of `values` (as many as a line holds)
    at a time."""
    for p in range(rec.shape[0]):
        for r in range(r0, r1):
            for k in range(0, rec.shape[2], len(values)):
                stream_store(rec, p, r, k, values)
    store_fence()
