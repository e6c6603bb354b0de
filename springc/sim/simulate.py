"""The runtime: a checked netlist and input signals in, a `SimResult` out, all runs in lockstep.

Time grid: the integration step is `h = tstep / substeps`; input signals are resampled to the
input grid `1/tstep` and interpolated linearly at every stage time (see `springc.sim.sources`).
Outputs are recorded every `round(1 / (outrate h))` steps (default: every `tstep`), starting
with the initial state at t = 0. Runs are simulated in batches of `batch` (one progress tick
each, recording into one shared buffer); inside a batch, chunks of runs go to a thread pool
(the kernel releases the GIL), each chunk in lockstep.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import numpy as np

from springc.kernels import codegen, expint, loader, regkernel, terms
from springc.kernels.lower import kernel_netlist
from springc.lang import physics
from springc.sim import gpu, reductions, sources, thermal
from springc.sim.marshal import (
    Lanes,
    LanesRefused,
    damper_coefficients,
    kernel_arrays,
    lane_arrays,
    member_arrays,
)
from springc.sim.audio import resample
from springc.errors import CheckError, DivergedRuns, UsageError
from springc.kernels.integrators import DEFAULT_METHOD, TABLEAUX, get_tableau, max_stable_step
from springc.check.checks import CheckedNetlist, require_checked
from springc.lang.ir import FlatNetlist, Probe

DEFAULT_BATCH = 256  # runs per kernel call (one progress-bar tick)
CHECK_EVERY = 256  # steps between divergence checks
# dof-steps (dofs x steps x runs) from which a simulation gets a kernel with its force code
# written out per node (`terms.node_terms`): such a kernel is compiled once per netlist
# structure instead of being shared by every netlist of the same element kinds, so short
# simulations (tests, one-off runs) keep the shared kernel; long ones repay the compile
# (docs/performance.md#kernel-forms-shared-written-out-register).
WRITE_OUT_FROM = 10_000_000
# dofs x runs from which fewer runs than threads get a kernel with each step's node loops
# split over the threads (`codegen.KernelOptions.parallel`): below it a step is too short to
# repay the threads' start and join, several a stage
# (docs/performance.md#one-run-on-every-core).
NODE_THREADS_FROM = 20_000
LIMITS = {"float64": 1e30, "float32": 1e15}  # |x| or |v| beyond this counts as divergence


@dataclass
class SimResult:
    """Simulation output: `t` (T,), `probes[label]` (runs, T), `reductions[spec]` (runs,)."""

    t: np.ndarray
    probes: dict[str, np.ndarray]
    reductions: dict[str, np.ndarray]
    runs: list[str]
    info: dict[str, object] = field(default_factory=dict)


@dataclass(frozen=True)
class Settings:
    """Resolved simulation settings (netlist defaults with overrides applied)."""

    tstep: float
    tstop: float
    substeps: int
    method: str
    precision: str
    outrate: float

    @property
    def h(self) -> float:
        return self.tstep / self.substeps

    @property
    def nsteps(self) -> int:
        return int(round(self.tstop / self.h))

    @property
    def rec_every(self) -> int:
        return max(1, int(round(1.0 / (self.outrate * self.h))))


def settings(net: FlatNetlist, tstep=None, tstop=None, substeps=None, method=None,
             precision=None, outrate=None, input_seconds: float | None = None) -> Settings:
    """Resolve settings: explicit arguments win over `.options`, which win over `.tran`."""
    opt = net.options
    tstep = tstep or (net.tran.tstep if net.tran else None)
    if tstep is None or tstep <= 0:
        raise UsageError("no time step: the netlist has no .tran and no --tstep was given")
    tstop = tstop or (net.tran.tstop if net.tran else input_seconds)
    if tstop is None or tstop <= 0:
        raise UsageError("no stop time: the netlist has no .tran and no --tstop was given")
    substeps = int(substeps or opt.get("substeps", 1))
    method = str(method or opt.get("method", DEFAULT_METHOD)).lower()
    precision = str(precision or opt.get("precision", "float64")).lower()
    outrate = float(outrate or opt.get("outrate", 1.0 / tstep))
    if substeps < 1:
        raise UsageError(f"substeps must be a positive integer, got {substeps}")
    if method not in TABLEAUX and not expint.is_split(method):
        known = ", ".join([*TABLEAUX, *expint.SCHEMES])
        raise UsageError(f"unknown integrator {method!r}", hint=f"known: {known}")
    if precision not in LIMITS:
        raise UsageError(f"unknown precision {precision!r}", hint="float64 or float32")
    if outrate <= 0:
        raise UsageError(f"output rate must be positive, got {outrate}")
    return Settings(float(tstep), float(tstop), substeps, method, precision, outrate)


def resolve_probes(net: FlatNetlist, probes) -> list[Probe]:
    """Probes to record: the netlist's `.probe`s, or the given labels/`Probe`s."""
    if probes is None:
        return list(net.probes)
    out = []
    for p in probes:
        if isinstance(p, Probe):
            out.append(p)
            continue
        node, isv = reductions.parse_quantity(p, net)
        out.append(Probe("v" if isv else "x", node, p.strip(), net.node_locs[node]))
    return out


def simulate(checked: CheckedNetlist, inputs=None, input_rate: float | None = None, *,
             tstep=None, tstop=None, substeps=None, method=None, precision=None, outrate=None,
             probes=None, reductions: tuple[str, ...] | list[str] = (), batch: int | None = None,
             channel: int | None = None, progress: bool = False,
             chunk: int | None = None, write_out: bool | None = None,
             record_into: np.ndarray | None = None, check_step: bool = True,
             node_threads: bool | None = None, temp: float | None = None,
             seed: int | None = None, device: str | None = None,
             first_run: int = 0, fma: bool = True) -> SimResult:
    """Simulate the checked netlist for every input signal (`springc.check.check(net)`).

    `inputs`: None (one run, no input), an array (runs, channels, samples) sampled at
    `input_rate` (default 1/tstep), or a list of sound files / folders. Returns a `SimResult`
    with only the probed quantities and the requested reductions. `write_out`: whether the
    kernel's force code is written out, per node or as each run's step in registers where
    `springc.kernels.regkernel` serves (None: for long simulations of small networks,
    `WRITE_OUT_FROM`, and for single runs of up to `regkernel.REGISTER_ALWAYS` masses;
    `kernel_form`). `record_into`: the record buffer of an earlier call
    (its `info["records"]`) to record into instead of fresh memory, for a caller simulating
    batch after batch: the OS zeroes every fresh page before the kernel writes it
    (docs/performance.md#what-recording-costs). The earlier result's probes,
    views of it, are overwritten. A step above the stability limit of the method is refused
    before anything runs (`CheckError`, as `springc build` words it) unless `check_step` is
    False (experiments that confirm a limit: the divergence guard then stops the run), and so
    are records that would not fit in memory. `node_threads`: whether each step's node loops
    are split over the threads (None: for fewer runs than threads of at least
    `NODE_THREADS_FROM` dofs x runs; `split_nodes`). `temp` (kelvin) and `seed` override
    `.options temp=`/`seed=`: above 0 K every damper's thermal noise force is drawn per step
    (`springc.sim.thermal`), run r's the same whatever the batch or kernel form. `batch`:
    runs per kernel call, rounded up to whole chunks of the kernel's lanes, so that run r is in
    lane r mod lanes and its result is bitwise the same whatever the batch. `device`:
    'cpu', 'cuda' (the CUDA kernel form, `springc.sim.gpu`; UsageError where no GPU is),
    'auto' (CUDA where a GPU is present and the CUDA form runs the method and the noise) or
    None (that of `gpu.default_device`, falling back as 'auto' does; the CPU outside one);
    on CUDA every run is one batch unless `batch` is given. `first_run`: the index of this
    call's first run in a larger population, whose noise streams run r draws as run
    `first_run` + r (`springc.sim.points`: each device its own). `fma` False: no product is
    fused with an add into one fused multiply-add (which rounds once where the two round
    twice), on the CPU and on CUDA alike, so that a run gives the same bits on either; no
    more accurate (docs/bench-gpu.md#fused-multiply-add)."""
    options = {k: v for k, v in locals().items() if k not in ("checked", "inputs",
                                                               "input_rate")}
    return _simulate([require_checked(checked, "simulate")], None, inputs, input_rate,
                     **options)


def simulate_lanes(members: Sequence[CheckedNetlist], labels: Sequence[str], inputs=None,
                   input_rate: float | None = None, **options) -> SimResult:
    """Every input on every member netlist in the lanes of one kernel call per batch: the
    members (the points of one structure of a `.step`/`.mc` netlist) differ in element
    coefficients only. Run p*R + r is input r on member p, named '<input> at <label p>'
    (`labels`: how messages name the members; a member's step-limit error names it too).
    The coefficient arrays that differ between members are passed with a column per run
    (`codegen.KernelOptions.per_run`), the others shared, so the kernel is that of the
    members' structure and nothing is compiled per member. The lane width comes from the
    number of runs and a batch is rounded up to whole chunks, so that each run's lane, and
    its result to the bit, is the same whatever the batch and the threads. `options`:
    `simulate`'s. Raises `LanesRefused` (before any work) where the members cannot share a
    call: `device` 'cuda' (inside `gpu.default_device`, the call takes the CPU instead), a
    Strang split scheme whose exact blocks differ between members, and thermal noise whose
    noisy dampers differ (one with b = 0 in some member). With thermal
    noise each run draws its own streams (run r of the call those of run `first_run` + r),
    so every device of a population meets its own noise."""
    if len(members) != len(labels):
        raise ValueError("one label per member")
    nets = [require_checked(m, "simulate_lanes") for m in members]
    return _simulate(nets, list(labels), inputs, input_rate, **options)


def _simulate(group: list[CheckedNetlist], labels: list[str] | None, inputs, input_rate, *,
              tstep=None, tstop=None, substeps=None, method=None, precision=None, outrate=None,
              probes=None, reductions=(), batch=None, channel=None, progress=False,
              chunk=None, write_out=None, record_into=None, check_step=True,
              node_threads=None, temp=None, seed=None, device=None,
              first_run=0, fma=True) -> SimResult:
    """`simulate` of the first netlist of `group` or, with `labels`, `simulate_lanes` of
    them all."""
    nets = [thermal.with_overrides(c.net, temp, seed) for c in group]
    net = nets[0]
    tstep0 = tstep or (net.tran.tstep if net.tran else None)
    signals, names, seconds = _gather_inputs(net, inputs, input_rate, tstep0, channel)
    st = settings(net, tstep, tstop, substeps, method, precision, outrate, seconds)
    if check_step:
        _require_stable(group, labels, st)
    reps = len(names)
    if labels is not None:
        names = [f"{name} at {label}" for label in labels for name in names]
    plist = resolve_probes(net, probes)
    rplan = reductions_plan(list(reductions), net)
    require_memory(len(plist), st.nsteps // st.rec_every + 1, len(names), st.precision,
                   record_into)
    dev = gpu.resolve(device or gpu.current())
    if dev == "cuda" and device in ("auto", None) and not gpu.serves(net, st.method):
        dev = "cpu"  # chosen, not asked for: the CPU where the CUDA form does not serve
    if labels is not None and dev == "cuda" and device in ("auto", None):
        dev = "cpu"  # per-run coefficients have no CUDA form: chosen, not asked for
    if labels is not None:
        _lanes_serve(net, rplan, dev)
    if dev == "cuda":
        gpu.require(net, st.method)
    if batch is None and dev == "cuda":  # the GPU takes every run in one launch
        batch = len(names)
    batch = batch_size(batch)
    task = task_runs(len(names), batch, chunk)
    width = codegen.choose_lanes(task)
    if labels is not None:  # the width from all the runs, whatever the batch and the threads
        width = codegen.choose_lanes(len(names))
    # batches of whole chunks: run r is in lane r mod width whatever the batch, and a lane's
    # rounding can differ from another's (the vectoriser may treat lanes of a chunk apart)
    batch = -(-batch // width) * width
    knet = kernel_netlist(net)  # the same forces, cheaper terms
    coeffs = kernel_arrays(knet, st, np.dtype(st.precision))
    if thermal.temperature(net) > 0:
        coeffs.update(thermal.noise_arrays(net, st.h, np.dtype(st.precision)))
    lanes = None if labels is None else lane_arrays(
        nets, coeffs, st, reps, member_arrays(nets, list(reductions), rplan, st))
    if lanes is not None:
        coeffs = {**coeffs, **lanes.per_run}
    opts = codegen.KernelOptions(st.method, st.precision, width,
                                 record=bool(plist), work=rplan.work,
                                 dissipation=bool(rplan.damper_rows), msq=bool(rplan.msq),
                                 gram=bool(rplan.gram),
                                 per_run=tuple(sorted(lanes.per_run)) if lanes else (),
                                 fma=fma)
    opts = kernel_form(knet, opts, coeffs, st, len(names), write_out, node_threads)
    copts = None
    if dev == "cuda" or opts.parallel:  # nodes gather their element ends (CUDA: if split)
        coeffs = {**coeffs, **terms.node_ends(coeffs, knet.n)}
    if dev == "cuda":
        fnet, blocks = gpu.force_netlist(knet, st.method)
        copts = gpu.options(fnet, blocks, st.method, st.precision, coeffs, len(plist), rplan,
                            fma)
    start = time.perf_counter()
    kernel = gpu.load(fnet, copts) if copts else loader.load(kernel_source(knet, opts))
    rec = _records(len(plist), st.nsteps // st.rec_every + 1, len(names),
                   np.dtype(st.precision), record_into)
    out = _run_batches(net, kernel, st, coeffs, signals, names, plist, rplan, batch, task,
                       progress, rec, lanes, first_run)
    out.info.update(wall_s=time.perf_counter() - start, kernel=str(kernel.path),
                    compile_s=kernel.compile_s, settings=st, records=rec)
    return out


def _require_stable(group: list[CheckedNetlist], labels: list[str] | None,
                    st: Settings) -> None:
    """Every netlist's step within its stability limit; a member's error names its label."""
    for k, member in enumerate(group):
        try:
            member.require_stable(st.method, st.h, st.substeps)
        except CheckError as err:
            if labels is None:
                raise
            raise CheckError([replace(d, message=f"{d.message} at {labels[k]}")
                              for d in err.diagnostics]) from None


def _lanes_serve(net: FlatNetlist, rplan, dev: str) -> None:
    """Raise `LanesRefused` where the members cannot share a kernel call (`simulate_lanes`)."""
    if dev == "cuda":
        raise LanesRefused("the CUDA form takes no per-run coefficients")


def _records(probes: int, records: int, runs: int, dtype, reuse: np.ndarray | None
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


reductions_plan = reductions.plan


def kernel_form(net: FlatNetlist, opts: codegen.KernelOptions, coeffs: dict, st: Settings,
                runs: int, write_out: bool | None, node_threads: bool | None = None
                ) -> codegen.KernelOptions:
    """`opts` with the form of the force code: the shared kernel with its nodes split over
    threads where `split_nodes` says so (every run in one chunk); else a register kernel
    (`springc.kernels.regkernel`) where the force code would be written out (`written_out`),
    and for chunks of one run of a small network (`REGISTER_ALWAYS`) unless `write_out` is
    False; else the per-node terms of `written_out` (None: the shared kernel)."""
    if not opts.per_run and split_nodes(net, st, runs, node_threads):
        return replace(opts, parallel=True, lanes=codegen.choose_lanes(runs))
    nodes = written_out(net, coeffs, st, runs, write_out)
    small = (opts.lanes == 1 and net.n <= regkernel.REGISTER_ALWAYS
             and write_out is not False)
    if (small or nodes is not None) and regkernel.eligible(net, opts):
        regs = nodes if nodes is not None else terms.node_terms(coeffs, net.n)
        if regs is not None:
            return replace(opts, registers=regs)
    return replace(opts, nodes=nodes)


def split_nodes(net: FlatNetlist, st: Settings, runs: int, want: bool | None) -> bool:
    """Whether the kernel splits each step's node loops over the threads: as `want` says,
    and when it is None, for fewer runs than `threads()` (their chunks would leave threads
    idle) of at least `NODE_THREADS_FROM` dofs x runs. Never for splitting schemes
    (`springc.kernels.expint` has no such form)."""
    if expint.is_split(st.method):
        return False
    if want is not None:
        return want
    cores = threads()
    return 1 < cores and runs < cores and net.n * runs >= NODE_THREADS_FROM


def written_out(net: FlatNetlist, coeffs: dict, st: Settings, runs: int,
                write_out: bool | None) -> tuple | None:
    """The per-node force terms for a kernel with its force code written out
    (`terms.node_terms`), or None for the shared kernel: as `write_out` says, and when it is
    None, for simulations of at least `WRITE_OUT_FROM` dof-steps. Networks too large to write out,
    and splitting schemes (`springc.kernels.expint`: their exact block updates dominate, so
    writing out gains nothing), always get the shared kernel."""
    if expint.is_split(st.method):
        return None
    if write_out is None:
        write_out = net.n * st.nsteps * runs >= WRITE_OUT_FROM
    return terms.node_terms(coeffs, net.n) if write_out else None


def task_runs(runs: int, batch: int | None, chunk: int | None) -> int:
    """Runs per parallel task: `chunk` when given (a caller running one task per core passes
    its whole batch), else a kernel call's runs spread over the threads."""
    if chunk:
        return int(chunk)
    return max(1, -(-min(runs, batch or DEFAULT_BATCH) // threads()))


def kernel_source(net: FlatNetlist, opts: codegen.KernelOptions) -> str:
    """The kernel text for `opts.method`: a Runge-Kutta tableau (`springc.kernels.codegen`) or a
    splitting scheme (`springc.kernels.expint`, generated for the Runge-Kutta part of the split)."""
    if expint.is_split(opts.method):
        return expint.kernel_source(net, opts)
    if opts.registers is not None:
        return regkernel.generate(net, opts)
    return codegen.generate(net, opts)


def stage_tableau(method: str):
    """The tableau whose stage times the kernel of `method` evaluates forces at."""
    return expint.SCHEMES[method].tableau if expint.is_split(method) else get_tableau(method)


def method_order(method: str) -> int:
    """Order of convergence of `method` (a split scheme's: its inner tableau's; the blocks are
    exact)."""
    return stage_tableau(method).order


def _gather_inputs(net, inputs, input_rate, tstep, channel):
    """Input signals at the input grid rate 1/tstep: (array or None, run names, seconds)."""
    nch = sources.channels_used(net)
    if inputs is None:
        return None, ["run0"], None
    if tstep is None:
        raise UsageError("no time step: the netlist has no .tran and no --tstep was given")
    rate = 1.0 / tstep
    if isinstance(inputs, np.ndarray):
        arr = np.asarray(inputs, dtype=np.float64)
        if arr.ndim != 3:
            raise UsageError(f"inputs must have shape (runs, channels, samples), got {arr.shape}")
        if input_rate is not None and not math.isclose(input_rate, rate):
            arr = np.stack([np.stack([resample(ch, input_rate, rate) for ch in run])
                            for run in arr])
        return arr, [f"run{r}" for r in range(len(arr))], arr.shape[2] / rate
    paths = sources.expand_inputs(list(inputs))
    arr = sources.read_inputs(paths, rate, nch, channel)
    return arr, [str(p) for p in paths], arr.shape[2] / rate


def threads() -> int:
    """Cores this process may use: the threads a kernel call spreads its chunks over."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def _run_batches(net, kernel, st: Settings, coeffs, signals, names, plist, rplan, batch, task,
                 progress, rec: np.ndarray, lanes: Lanes | None = None,
                 first_run: int = 0) -> SimResult:
    """The kernel calls, batch by batch, all recording into `rec` (one record for all the
    calls, each writing its own runs' rows: no copy at the end, a recording at every step is
    hundreds of MB). With `lanes`, run r reads input r % reps. Run r draws the noise streams
    of run `first_run` + r."""
    runs = len(names)
    dtype = np.dtype(st.precision)
    tab = stage_tableau(st.method)
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
    return SimResult(t, probes, reds, list(names))


def _batch_inputs(signals: np.ndarray, lo: int, hi: int) -> np.ndarray:
    """The inputs of runs lo..hi-1, run r reading input r % len(signals) (the members of
    `simulate_lanes` share the inputs)."""
    if hi <= len(signals):
        return signals[lo:hi]
    return signals[np.arange(lo, hi) % len(signals)]


def batch_size(batch: int | None) -> int:
    """Runs per kernel call: `batch` (None: DEFAULT_BATCH)."""
    if batch is not None and batch < 1:
        raise UsageError(f"batch must be a positive number of runs, not {batch}")
    return batch or DEFAULT_BATCH


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
        check_every=CHECK_EVERY, limit=LIMITS[st.precision],
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
    _run_chunks(kernel, args, runs, task)
    work = np.zeros((nf, runs))
    work[sources.input_forces(net)] = args["work_in"]
    work[sources.common_forces(net)] = args["work_c"]
    with np.errstate(all="ignore"):  # a diverged run's sums are NaN; the others are kept
        out = _finish_reductions(net, rplan, args, work, wins, st,
                                 None if lanes is None else lanes.members(col, col + runs),
                                 None if lanes is None else lanes.nets)
    _check_divergence(net, st, args, names, out)
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


def _run_chunks(kernel, args: dict, runs: int, task: int) -> None:
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


def _finish_reductions(net, rplan, args, work, wins, st, members=None,
                       nets=None) -> dict[str, np.ndarray]:
    xf, vf = args["xf"].astype(np.float64), args["vf"].astype(np.float64)
    out: dict[str, np.ndarray] = {}
    msq_rows = {r.spec: k for k, r in enumerate(rplan.msq)}
    for r in rplan.items:
        match r.kind:
            case "final":
                out[r.spec] = (vf if r.isv else xf)[r.node].copy()
            case "msq":
                k = msq_rows[r.spec]
                out[r.spec] = args["msq"][k] / max(wins[k][2], 1)
            case "work":
                out[r.spec] = work[list(r.forces)].sum(axis=0)
            case "dissipated":
                out[r.spec] = _dissipated(args, rplan, r.spec, xf.shape[-1])
            case "loss":
                diss = _dissipated(args, rplan, r.spec, xf.shape[-1])
                with np.errstate(divide="ignore", invalid="ignore"):
                    out[r.spec] = -10.0 * np.log10(diss / work.sum(axis=0))
            case "energy" if members is not None:  # each run's own netlist
                out[r.spec] = np.empty(xf.shape[-1])
                for m in np.unique(members):
                    cols = members == m
                    out[r.spec][cols] = physics.energy(nets[m], xf[:, cols], vf[:, cols])
            case "energy":
                out[r.spec] = physics.energy(net, xf, vf)
            case "gram":
                acc = args["gram"][rplan.gram_slices[r.spec]]
                out[r.spec] = reductions.gram_finish(r, acc, args["x0"].astype(np.float64), xf,
                                                     st.h, st.nsteps * st.h)
            case _:
                raise TypeError(f"unhandled reduction kind {r.kind!r}")
    return out


def _dissipated(args, rplan, spec: str, runs: int) -> np.ndarray:
    """Energy dissipated per run in the dampers of `spec` (none in the network: nothing)."""
    rows = rplan.damper_slices.get(spec)
    return np.zeros(runs) if rows is None else args["diss"][rows].sum(axis=0)


def _check_divergence(net, st: Settings, args, names, reductions: dict) -> None:
    status = args["status"]
    if not status.any():
        return
    bad = np.flatnonzero(status)
    r = int(bad[0])
    when = status[r] * st.h
    node = net.nodes[int(args["bad_node"][r])]
    more = f" (and {len(bad) - 1} more run(s))" if len(bad) > 1 else ""
    raise DivergedRuns(
        f"run {names[r]} diverged by t = {when:.6g} s: node {node} is NaN, infinite or beyond "
        f"{LIMITS[st.precision]:g}{more}", bad, reductions, hint=likely_cause(net, st))


def likely_cause(net: FlatNetlist, st: Settings) -> str:
    """Why a run may have diverged: the step against the linear stability limit when the
    linearisation is small enough to diagonalise, and the other causes otherwise."""
    others = ("a potential unbounded below (P elements), or an input too large for the "
              "nonlinear elements (their stiffness grows with amplitude)")
    if net.n > 3000:
        return f"a step too large for the integrator, {others}"
    if expint.is_split(st.method):  # the blocks are exact: the split's own limit
        from springc.check.checks import step_limit

        hmax = step_limit(net, st.method).dt
    else:
        hmax, _ = max_stable_step(stage_tableau(st.method), linear_eigenvalues(net))
    if st.h > hmax:
        return (f"unstable step: h = {st.h:.4g} s exceeds the largest stable step "
                f"{hmax:.4g} s of {st.method} for the linearised network; raise --substeps "
                f"to at least {math.ceil(st.tstep / hmax)}")
    return f"h = {st.h:.4g} s is linearly stable (limit {hmax:.4g} s), so likely {others}"


def linear_eigenvalues(net: FlatNetlist) -> np.ndarray:
    """Eigenvalues of the first-order linearisation at rest."""
    minv = 1.0 / net.mass()
    n = net.n
    a = np.zeros((2 * n, 2 * n))
    a[:n, n:] = np.eye(n)
    a[n:, :n] = -minv[:, None] * physics.stiffness_matrix(net)
    a[n:, n:] = -minv[:, None] * physics.damping_matrix(net)
    return np.linalg.eigvals(a)

