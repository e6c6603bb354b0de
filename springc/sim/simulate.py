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
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from springc.kernels import codegen, expint, loader, regkernel, terms
from springc.kernels.lower import kernel_netlist
from springc.sim import execute, gpu, reductions, sources, thermal
from springc.sim.marshal import Lanes, LanesRefused, kernel_arrays, lane_arrays, member_arrays
from springc.sim.reductions import plan as reductions_plan
from springc.sim.timegrid import Settings, settings
from springc.sim.audio import resample
from springc.errors import CheckError, UsageError
from springc.check.checks import CheckedNetlist, require_checked, require_stable_many
from springc.lang.ir import FlatNetlist, Probe

DEFAULT_BATCH = 256  # runs per kernel call (one progress-bar tick)
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


@dataclass
class SimResult:
    """Simulation output: `t` (T,), `probes[label]` (runs, T), `reductions[spec]` (runs,)."""

    t: np.ndarray
    probes: dict[str, np.ndarray]
    reductions: dict[str, np.ndarray]
    runs: list[str]
    info: dict[str, object] = field(default_factory=dict)


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


@dataclass
class RunPlan:
    """Everything one call runs, decided before any array is made: the netlists (with the
    call's thermal overrides), their settings, the input signals and run names (`reps`
    inputs per member), the probes and reductions, the device, and the batching (runs per
    kernel call, runs per thread task, lanes per chunk)."""

    nets: list[FlatNetlist]
    lanes: bool  # the members of `simulate_lanes`, a column per run
    st: Settings
    signals: np.ndarray | None
    names: list[str]
    reps: int
    probes: list[Probe]
    reductions: list[str]
    rplan: reductions.Plan
    device: str
    batch: int
    task: int
    width: int


def _simulate(group: list[CheckedNetlist], labels: list[str] | None, inputs, input_rate, *,
              progress=False, write_out=None, record_into=None, node_threads=None,
              first_run=0, fma=True, **options) -> SimResult:
    """`simulate` of the first netlist of `group` or, with `labels`, `simulate_lanes` of
    them all: the plan, the kernel arrays, the kernel, the calls."""
    plan = _plan(group, labels, inputs, input_rate, record_into, **options)
    knet, coeffs, lanes = _marshal(plan)
    start = time.perf_counter()
    kernel, coeffs = _kernel(plan, knet, coeffs, lanes, write_out, node_threads, fma)
    rec = execute.records_buffer(len(plan.probes), plan.st.nsteps // plan.st.rec_every + 1,
                                 len(plan.names), np.dtype(plan.st.precision), record_into)
    t, probes, reds = execute.run_batches(
        plan.nets[0], kernel, plan.st, coeffs, plan.signals, plan.names, plan.probes,
        plan.rplan, plan.batch, plan.task, progress, rec, lanes, first_run)
    return SimResult(t, probes, reds, list(plan.names),
                     {"wall_s": time.perf_counter() - start, "kernel": str(kernel.path),
                      "compile_s": kernel.compile_s, "settings": plan.st, "records": rec})


def _plan(group: list[CheckedNetlist], labels: list[str] | None, inputs, input_rate,
          record_into, *, tstep=None, tstop=None, substeps=None, method=None, precision=None,
          outrate=None, probes=None, reductions=(), batch=None, channel=None, chunk=None,
          check_step=True, temp=None, seed=None, device=None) -> RunPlan:
    """The call's `RunPlan`; a step above the stability limit, records beyond memory and a
    device that cannot serve are refused here, before anything runs."""
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
    execute.require_memory(len(plist), st.nsteps // st.rec_every + 1, len(names),
                           st.precision, record_into)
    dev = _device(net, st, rplan, device, labels is not None)
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
    return RunPlan(nets, labels is not None, st, signals, names, reps, plist, list(reductions),
                   rplan, dev, batch, task, width)


def _device(net: FlatNetlist, st: Settings, rplan, device: str | None, lanes: bool) -> str:
    """Where the call runs: `device` (None: the session's), the CPU where CUDA was chosen
    rather than asked for and its form does not serve; an error where it was asked for."""
    dev = gpu.resolve(device or gpu.current())
    if dev == "cuda" and device in ("auto", None) and not gpu.serves(net, st.method):
        dev = "cpu"  # chosen, not asked for: the CPU where the CUDA form does not serve
    if lanes and dev == "cuda" and device in ("auto", None):
        dev = "cpu"  # per-run coefficients have no CUDA form: chosen, not asked for
    if lanes:
        _lanes_serve(net, rplan, dev)
    if dev == "cuda":
        gpu.require(net, st.method)
    return dev


def _marshal(plan: RunPlan) -> tuple[FlatNetlist, dict, Lanes | None]:
    """The kernel netlist (the same forces, cheaper terms), its coefficient arrays (with the
    thermal noise's) and, for lanes, every member's per-run arrays (`springc.sim.marshal`)."""
    net, st = plan.nets[0], plan.st
    knet = kernel_netlist(net)
    coeffs = kernel_arrays(knet, st, np.dtype(st.precision))
    if thermal.temperature(net) > 0:
        coeffs.update(thermal.noise_arrays(net, st.h, np.dtype(st.precision)))
    lanes = None
    if plan.lanes:
        lanes = lane_arrays(plan.nets, coeffs, st, plan.reps,
                            member_arrays(plan.nets, plan.reductions, plan.rplan, st))
        coeffs = {**coeffs, **lanes.per_run}
    return knet, coeffs, lanes


def _kernel(plan: RunPlan, knet: FlatNetlist, coeffs: dict, lanes: Lanes | None,
            write_out: bool | None, node_threads: bool | None, fma: bool) -> tuple:
    """The kernel of the plan's form (`kernel_form`; the CUDA form on a GPU), loaded, and
    the arrays it takes (`_kernel_text`)."""
    text, coeffs = _kernel_text(plan, knet, coeffs, lanes, write_out, node_threads, fma)
    return loader.load(text), coeffs


def _kernel_text(plan: RunPlan, knet: FlatNetlist, coeffs: dict, lanes: Lanes | None,
                 write_out: bool | None, node_threads: bool | None, fma: bool
                 ) -> tuple[str, dict]:
    """The text of the plan's kernel and the arrays it takes: `coeffs` with each node's
    element ends where nodes gather them (the node-split form; CUDA)."""
    st, rplan = plan.st, plan.rplan
    opts = codegen.KernelOptions(st.method, st.precision, plan.width,
                                 record=bool(plan.probes), work=rplan.work,
                                 dissipation=bool(rplan.damper_rows), msq=bool(rplan.msq),
                                 gram=bool(rplan.gram),
                                 per_run=tuple(sorted(lanes.per_run)) if lanes else (),
                                 fma=fma)
    opts = kernel_form(knet, opts, coeffs, st, len(plan.names), write_out, node_threads)
    if plan.device == "cuda" or opts.parallel:
        coeffs = {**coeffs, **terms.node_ends(coeffs, knet.n)}
    if plan.device != "cuda":
        return kernel_source(knet, opts), coeffs
    fnet, blocks = gpu.force_netlist(knet, st.method)
    copts = gpu.options(fnet, blocks, st.method, st.precision, coeffs, len(plan.probes), rplan,
                        fma)
    return gpu.kernel_text(fnet, copts), coeffs


def kernel_text(checked: CheckedNetlist, inputs=None, input_rate: float | None = None, *,
                device: str = "cpu", write_out: bool | None = None,
                node_threads: bool | None = None, fma: bool = True, **options) -> str:
    """The text of the kernel `simulate` would load for these arguments (`device` "cuda":
    the CUDA form's, generated without a GPU), generated, neither compiled nor run: what a
    change to the code generators must keep for a kernel's bits to stay
    (scripts/kernel_texts.py compares two versions' texts)."""
    plan = _plan([checked], None, inputs, input_rate, None, device="cpu", **options)
    if device == "cuda":
        gpu.require(plan.nets[0], plan.st.method)
        plan = replace(plan, device="cuda")
    knet, coeffs, lanes = _marshal(plan)
    return _kernel_text(plan, knet, coeffs, lanes, write_out, node_threads, fma)[0]


def _require_stable(group: list[CheckedNetlist], labels: list[str] | None,
                    st: Settings) -> None:
    """Every netlist's step within its stability limit; a member's error names its label."""
    for k, err in enumerate(require_stable_many(group, st.method, st.h, st.substeps)):
        if err is None:
            continue
        if labels is None:
            raise err
        raise CheckError([replace(d, message=f"{d.message} at {labels[k]}")
                          for d in err.diagnostics]) from None


def _lanes_serve(net: FlatNetlist, rplan, dev: str) -> None:
    """Raise `LanesRefused` where the members cannot share a kernel call (`simulate_lanes`)."""
    if dev == "cuda":
        raise LanesRefused("the CUDA form takes no per-run coefficients")


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
    and when it is None, for fewer runs than `execute.threads()` (their chunks would leave threads
    idle) of at least `NODE_THREADS_FROM` dofs x runs. Never for splitting schemes
    (`springc.kernels.expint` has no such form)."""
    if expint.is_split(st.method):
        return False
    if want is not None:
        return want
    cores = execute.threads()
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
    return max(1, -(-min(runs, batch or DEFAULT_BATCH) // execute.threads()))


def kernel_source(net: FlatNetlist, opts: codegen.KernelOptions) -> str:
    """The kernel text for `opts.method`: a Runge-Kutta tableau (`springc.kernels.codegen`) or a
    splitting scheme (`springc.kernels.expint`, generated for the Runge-Kutta part of the split)."""
    if expint.is_split(opts.method):
        return expint.kernel_source(net, opts)
    if opts.registers is not None:
        return regkernel.generate(net, opts)
    return codegen.generate(net, opts)


def method_order(method: str) -> int:
    """Order of convergence of `method` (a split scheme's: its inner tableau's; the blocks are
    exact)."""
    return expint.stage_tableau(method).order


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


def batch_size(batch: int | None) -> int:
    """Runs per kernel call: `batch` (None: DEFAULT_BATCH)."""
    if batch is not None and batch < 1:
        raise UsageError(f"batch must be a positive number of runs, not {batch}")
    return batch or DEFAULT_BATCH


