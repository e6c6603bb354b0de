"""The CUDA kernel form: one run per GPU thread, generated as numba.cuda source text from the
same description of the step as the CPU kernels (this module never imports numba;
`springc.kernels.loader` imports the text and `springc.sim.gpu` launches it).

- Forces: the shared kernel's rendering of `springc.kernels.terms` for one run: the linear
  rows and inputs per node (`terms.own_sum`, `ROW`, `INPUT`), then `terms.element_loop` per
  kind in `LOOP_ORDER`, monomials, shared signals; or, with `CudaOptions.nodes`
  (`terms.node_terms`), one sum per node (`terms.node_sum`) with every index a constant and
  the coefficients read once per thread into scalars.
- Stages: the Runge-Kutta-Nystrom stage and combine terms of `codegen.stage_terms` and
  `combine_terms` over the tableau (any of `integrators.TABLEAUX`), the stages unrolled.
- Inputs: linearly interpolated at each stage time as `codegen.emit_interp` does, every
  stage's at the step's start (`_emit_step_inputs`).
- State: each thread's positions, velocities and stage forces in local arrays of the
  network's size (a compile-time constant), read from and written back to device arrays
  (n, runs) at each call, so that the host can integrate a long recording call by call over
  ranges of steps, feeding each range's input samples (`springc.sim.gpu`).
- Split runs (`CudaOptions.threads` > 1, for networks too large to write out): one run per
  block, its nodes split over the block's threads, each node gathering its own element ends
  (`terms.node_ends`, the CPU kernels' parallel form, so the sums round alike); the run's
  state in shared memory, the threads meeting at a barrier wherever one reads what another
  wrote. One run per thread keeps a 10,000-run launch to a few warps per multiprocessor,
  each waiting on its local memory; split, the same launch runs many warps on each and the
  state stays on the chip (docs/bench-gpu.md).
- Records and the reductions `work`, `dissipation`, `msq`, `gram` (and, on the host, `final`,
  `energy`, `loss`) as the shared kernel accumulates them.

- Lawson schemes (`springc.kernels.expint`: exp-rk4, exp-heun3): the Runge-Kutta part of the
  split netlist as above, its rows of the exact blocks skipped, and each block's exact flow
  to every stage and to the step's end (`_emit_blocks`, summed as `expint`'s kernels sum it),
  the input interpolated at each fraction of the step the scheme reads.

- Products (`CudaOptions.fma` False): every product of the kernel as `cudamul.mul_rn`, which
  NVVM rounds on its own rather than fusing it with an add, so that the GPU rounds each
  operation as the CPU kernels compiled without contraction (`KernelOptions.fma`) do.

Strang splitting and thermal noise have no CUDA form.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path
from dataclasses import dataclass

from springc.kernels import expint, terms
from springc.kernels.codegen import (REDUCTION_ARGS, Features, LaneLayout, _Code, accel_args,
                                     combine_terms, damper_update, emit_coefficients,
                                     emit_linear, emit_monomials, emit_nystrom_constants,
                                     emit_step_start, features, gather_args, interp_weights,
                                     msq_update, one_run, source_hash, stage_terms,
                                     work_common_update, work_in_update)
from springc.kernels.integrators import Tableau, get_tableau
from springc.lang.ir import FlatNetlist

CUDA_VERSION = 5  # bump when the generated text or its calling convention changes
BLOCK = 32  # threads (runs) per block where each run is one thread
# Networks up to this many nodes get their force code written out per node (constant
# indices, coefficients in scalars), one run per thread; larger ones loop over the runtime
# index arrays, each run split over a block's threads (`CudaOptions.threads`) where its state
# fits a block's static shared memory (`shared_bytes`), else one run per thread.
WRITE_OUT_MAX = terms.NODES_MAX
SPLIT_MIN = WRITE_OUT_MAX + 1
# Threads per run of the split form, where set (a `Layout` sets it); None: one node a
# thread (`node_threads`) where the register form's code fits there, else LOOP_THREADS, the
# fastest of 32-512 for the loops (docs/bench-gpu.md). On the H200 the 8x3 feature network's
# register form ran 9% faster at 512 threads (one node a thread) than at 256 (two).
SPLIT_THREADS: int | None = None
LOOP_THREADS = 256
THREADS_MAX = 1024  # a block's most threads
# Split form: each thread holds this many of each node's terms of each list (`slot_lists`) in
# registers for the whole launch, read once; a node's further terms are read in a loop. Only
# while the code written out per thread stays under SLOT_CODE_MAX term blocks (`slot_code`):
# numba-cuda compiled 16 (the 8x3 feature network) in about 8 s, 75 (the 564-dof network) in
# about 70 s (docs/bench-gpu.md).
SLOT_MAX = 8
SLOT_CODE_MAX = 32
# The split form's registers a thread, where set: numba-cuda's max_registers (ptxas spills the
# rest to local memory); None: ptxas's choice, capped where a block of more than 256 threads
# would not fit a multiprocessor's REGISTERS (`register_limit`: such a launch fails).
MAX_REGISTERS: int | None = None
REGISTERS = 65536  # a multiprocessor's (and a block's) 32-bit registers, sm_70 to sm_90
SHARED_BYTES = 48 * 1024
ONE_RUN = LaneLayout(1, 1, one_run=True)  # codegen's lane statements, rendered for one run


@dataclass(frozen=True)
class CudaOptions:
    """Everything besides the element kinds that shapes a CUDA kernel's text: the tableau,
    the precision, the sizes of the per-thread arrays (dofs, input channels, input and
    shared-signal forces, probes, damper rows, mean-square rows, Gram groups; 0: not
    accumulated), whether input work is summed, the nodes whose stage
    velocity is read (`vneed`) and, for small networks, each node's terms (`nodes`); for the
    split form its threads per run and the terms a node holds in registers (`slots`)."""

    method: str
    precision: str
    n: int
    channels: int
    inputs: int = 0
    common: int = 0
    probes: int = 0
    work: bool = False
    dampers: int = 0
    msq: int = 0
    gram: int = 0
    vneed: tuple[bool, ...] = ()
    nodes: tuple | None = None
    threads: int = 1  # threads per run: > 1, the split form
    blocks: tuple[int, ...] = ()  # a Lawson scheme's exact blocks: their sizes (nodes)
    block_channels: int = 1  # the input channels of their propagators
    # split form: each list's (`slot_lists`) terms a node holds in registers, and whether
    # some node has more (then read in a loop); () : every term read in a loop
    slots: tuple[tuple[str, int, bool], ...] = ()
    max_registers: int | None = None  # numba-cuda's limit (`MAX_REGISTERS`); not simulated
    fma: bool = True  # False: no product fused with an add (`rounded_products`)


@dataclass(frozen=True)
class SlotList:
    """One list of a node's terms, in its sum's order, that the split form reads into
    registers (`CudaOptions.slots`): each node's range of entries (`ptr`), the element of an
    entry (`elem`, for element kinds) and its fields (name, array, whether that array is
    indexed by the element rather than the entry)."""

    name: str
    ptr: str
    elem: str | None
    fields: tuple[tuple[str, str, bool], ...]


def slot_lists(feat: Features) -> list[SlotList]:
    """A node's lists of terms after its own, in the order its sum adds them: its stiffness
    row, its inputs, its ends of each element kind (`terms.LOOP_ORDER`, `terms.node_ends`)."""
    out = []
    if feat.couplings:
        out.append(SlotList("row", "l_ptr", None, (("c", "l_col", False), ("w", "l_val", False))))
    if feat.in_forces:
        out.append(SlotList("in", "fi_ptr", None, (("c", "fi_chan", False),
                                                   ("w", "fi_gm", False))))
    for kind in terms.LOOP_ORDER:
        if not getattr(feat, kind.feature):
            continue
        names = terms.gather_args(kind)
        ends = ((("o", names[2], False), ("end", names[3], False))
                if kind.node_j is not None else ())
        out.append(SlotList(kind.name, names[0], names[1],
                            ends + tuple((f, arr, True) for f, arr in kind.coefs)))
    return out


def slot_code(lists: list[SlotList], held: list[int], n: int, threads: int) -> int:
    """The term blocks the split form's force code writes out per thread when each node holds
    `held` terms of each of `lists`: per node the thread holds, per term, one block per end
    variant of its kind (two-node kinds two, three with a ground end)."""
    def variants(sl: SlotList) -> int:
        kind = terms.BY_NAME.get(sl.name)
        if kind is None or kind.node_j is None:
            return 1
        return 3 if kind.ground is not None else 2

    nodes = -(-n // threads)
    return nodes * sum(k * variants(sl) for sl, k in zip(lists, held))


def node_threads(n: int) -> int | None:
    """Threads per run that give each thread of the split form one node (`n` rounded up to
    a warp), or None where a block cannot hold that many."""
    threads = -(-n // 32) * 32
    return threads if threads <= THREADS_MAX else None


@dataclass(frozen=True)
class Layout:
    """How the CUDA form lays a network out: the defaults above, which the measuring
    scripts' sweeps change for a block of code (`springc.sim.gpu.layout`)."""

    write_out_max: int = WRITE_OUT_MAX  # most nodes written out per node
    split_min: int = SPLIT_MIN  # fewest nodes split over a block's threads
    split_threads: int | None = SPLIT_THREADS  # threads a run of the split form
    slot_max: int = SLOT_MAX  # terms of each list a thread holds in registers
    slot_code_max: int = SLOT_CODE_MAX  # most term blocks written out per thread
    max_registers: int | None = MAX_REGISTERS  # registers a thread (None: ptxas's)


def kernel_shape(path: str | None) -> dict:
    """A generated CUDA kernel file's threads per run, register limit and whether it holds
    terms in registers (read from its module constants; {} for anything else, such as a CPU
    kernel's file)."""
    if not path or not str(path).endswith(".py"):
        return {}
    text = Path(path).read_text()
    found = {k: re.search(rf"^{k} = (\S+)", text, re.M) for k in ("T", "MAX_REGISTERS")}
    slots = re.search(r"^SLOTS = (.*)$", text, re.M)
    if not found["T"] or "CUDA = True" not in text:
        return {}
    return {"threads_per_run": int(found["T"].group(1)),
            "max_registers": ast.literal_eval(found["MAX_REGISTERS"].group(1)),
            "registers_held": bool(slots and ast.literal_eval(slots.group(1)))}


def register_limit(threads: int, max_registers: int | None = MAX_REGISTERS) -> int | None:
    """The split form's registers a thread at `threads` a run: `max_registers` where set, at
    most the most that let one block fit a multiprocessor (registers are given out a warp at
    a time, eight a thread at a time, 255 at most); None: ptxas's choice, which always fits
    at 256 threads or fewer."""
    cap = min(255, REGISTERS // (-(-threads // 32) * 32) // 8 * 8)
    if max_registers:
        return min(max_registers, cap)
    return cap if cap < 255 else None


def tableau(method: str) -> Tableau:
    """The Runge-Kutta tableau of `method` (a Lawson scheme's: its inner one)."""
    return expint.SCHEMES[method].tableau if expint.is_split(method) else get_tableau(method)


def _lawson(opts: CudaOptions) -> bool:
    return expint.is_split(opts.method)


def shared_bytes(n: int, precision: str, method: str, gram: int = 0,
                 folded: bool = True) -> int:
    """The split form's shared memory per block: positions, velocities, their stage values
    and the stages' forces, n each (`folded`: the last stage's kept in a register,
    `_folds`), and the Gram sums."""
    size = 8 if precision == "float64" else 4
    stages = tableau(method).stages
    arrays = 4 + stages - (folded and stages > 1)
    return arrays * n * size + 8 * gram + 64


def _folds(feat: Features, opts: CudaOptions, tab: Tableau) -> bool:
    """Whether the split form folds the combine into the last stage's force loop: each node's
    new state from its last stage force as soon as it is summed, kept in a register rather
    than in shared memory (not where monomials or shared signals add to the forces after
    the loop)."""
    return (opts.threads > 1 and tab.stages > 1 and not feat.monomials
            and not feat.common_forces and not _lawson(opts))


def run_args(feat: Features, opts: CudaOptions) -> list[str]:
    """The generated `run`'s arguments, in order: the state (device arrays (n, runs)),
    this call's input samples and shared signals, its range of steps, the coefficients, the
    records and reductions (each (rows, runs)), the divergence status."""
    names = ["xst", "vst", "u", "ubase", "g", "s0", "s1", "nsteps", "substeps", "h",
             "check_every", "limit"]
    names += accel_args(feat) + ["vneed"]
    if opts.threads > 1:
        names += gather_args(feat) + ["deal"]
    if opts.slots:
        names += ["sl_n"] + [f"sl_{sl.name}_{f}" for sl, (_, k, _) in
                             zip(slot_lists(feat), opts.slots) if k for f, _, _ in sl.fields]
    if _lawson(opts):
        names += ["frz"] + [f"lw{m}_{k}" for m in opts.blocks for k in ("node", "e", "p0", "p1")]
        names += ["fi_w"] if opts.work and feat.in_forces else []
    names += ["rec_every", "rec_node", "rec_isv", "rec", "rbase"]
    for args in REDUCTION_ARGS.values():  # every reduction's, used or not
        names += args
    if opts.threads > 1:
        names += ["gr_ptr"]  # the split form's Gram pairs, ordered by group
    names += ["status", "bad_node"]
    return names


def generate(net: FlatNetlist, opts: CudaOptions) -> str:
    """numba.cuda source of the kernel for `net` (the kernel netlist, `lower.kernel_netlist`)
    under `opts`, with a header naming the netlist and options."""
    feat = features(net)
    if getattr(feat, "thermal", False):
        raise ValueError("thermal noise has no CUDA kernel form")
    tab = tableau(opts.method)
    body = _body(feat, opts, tab)
    if not opts.fma:
        body = rounded_products(body)
    shown = {k: v for k, v in vars(opts).items() if k not in ("nodes", "vneed")}
    header = [
        "# springc generated CUDA kernel: do not edit (regenerated from the netlist)",
        f"# netlist: {net.file}",
        f"# title: {net.title}",
        f"# options: {shown}",
        "# force code: " + _form(opts),
        f"# integrator: {tab.name} ({tab.description})",
        f"# dofs: {net.n}; elements: {net.element_counts()}",
        f"# body-hash: {source_hash(f'cuda {CUDA_VERSION}' + body)}",
        "",
    ]
    return "\n".join(header) + body


class _RoundedProducts(ast.NodeTransformer):
    """Inside functions, `a * b` -> `mul_rn(a, b)` and `t *= b` -> `t = mul_rn(t, b)`; the
    sizes of local and shared arrays (compile-time constants) stay as they are."""

    def __init__(self) -> None:
        self.depth = 0

    def visit_FunctionDef(self, node: ast.FunctionDef) -> ast.AST:
        self.depth += 1
        self.generic_visit(node)
        self.depth -= 1
        return node

    def visit_Call(self, node: ast.Call) -> ast.AST:
        if ast.unparse(node.func).endswith((".local.array", ".shared.array")):
            return node
        return self.generic_visit(node)

    def visit_BinOp(self, node: ast.BinOp) -> ast.AST:
        self.generic_visit(node)
        if self.depth and isinstance(node.op, ast.Mult):
            return ast.Call(ast.Name("mul_rn", ast.Load()), [node.left, node.right], [])
        return node

    def visit_AugAssign(self, node: ast.AugAssign) -> ast.AST:
        self.generic_visit(node)
        if not (self.depth and isinstance(node.op, ast.Mult)):
            return node
        load = ast.parse(ast.unparse(node.target), mode="eval").body
        return ast.Assign([node.target], ast.Call(ast.Name("mul_rn", ast.Load()),
                                                  [load, node.value], []))


def rounded_products(body: str) -> str:
    """The kernel text with every product inside its functions a `mul_rn` call (NVVM fuses a
    product and an add into one fused multiply-add unless told not to, and numba-cuda cannot
    tell it: `springc.kernels.cudamul`). Comments do not survive the rewrite."""
    tree = _RoundedProducts().visit(ast.parse(body))
    return ast.unparse(ast.fix_missing_locations(tree)) + "\n"


def _form(opts: CudaOptions) -> str:
    if opts.threads > 1:
        return f"split: one run per block of {opts.threads} threads, nodes gathering their ends"
    return "written out per node" if opts.nodes else "loops over the runtime index arrays"


def _body(feat: Features, opts: CudaOptions, tab: Tableau) -> str:
    split = opts.threads > 1
    c = _Code()
    c('"""Generated by springc.kernels.cuda; see the header."""')
    c("import numpy as np")
    c("from numba import config, cuda")
    if not opts.fma:
        c("from springc.kernels.cudamul import mul_rn")
    c("")
    c(f"FT = np.{opts.precision}")
    c(f"ARGS = {tuple(run_args(feat, opts))!r}")
    c(f"N = {opts.n}")
    c(f"NCH = {max(opts.channels, 1)}")
    c(f"NFI = {opts.inputs}  # input forces")
    c(f"NFC = {opts.common}  # shared-signal forces")
    c(f"BLOCK = {opts.threads if split else BLOCK}  # threads per block")
    c(f"T = {opts.threads}  # threads per run")
    c("CUDA = True")
    c("LANES = 1  # runs per thread")
    c(f"VNEED = {tuple(opts.vneed)!r}  # whether anything reads a node's stage velocity")
    c("# the register lists' tables the host builds: (list, entries, ptr, elem, fields)")
    c(f"SLOTS = {_slot_spec(feat, opts)!r}")
    c(f"MAX_REGISTERS = {opts.max_registers!r}  # numba-cuda's limit a thread (None: ptxas's)")
    c("# split: the node lists whose counts the host deals the nodes by (`deal`)")
    c(f"DEAL = {tuple(sl.ptr for sl in slot_lists(feat)) if split else ()!r}")
    c("")
    c("")
    # cache=True: numba-cuda keeps the compiled kernel beside this file (keyed on the GPU's
    # architecture and the CUDA version), so a network compiles once per machine, not once
    # per process (the 8x3 feature network's register form: about 8 s)
    # numba's simulator takes no register limit
    c("JIT = {} if config.ENABLE_CUDASIM or not MAX_REGISTERS else "
      "{'max_registers': MAX_REGISTERS}")
    c("@cuda.jit(cache=True, **JIT)")
    c(f"def run({', '.join(run_args(feat, opts))}):")
    c.indent()
    if split:
        c('"""Integrate steps s0..s1-1 of run blockIdx.x, its nodes split over the threads."""')
        c("r = cuda.blockIdx.x")
        c("t = cuda.threadIdx.x")
    else:
        c('"""Integrate steps s0..s1-1 of run cuda.grid(1) from its state in xst, vst."""')
        c("r = cuda.grid(1)")
    c("if r >= xst.shape[1] or status[r] != 0:")
    c("    return")
    emit_coefficients(c, tab)  # h-scaled tableau and Nystrom constants, as codegen names them
    emit_nystrom_constants(c, tab)
    if _lawson(opts):
        c("hh = FT(h)")
    if opts.nodes is not None:
        for i, node in enumerate(opts.nodes):
            for line in terms.scalar_loads(i, node):
                c(line)
    _emit_state(c, feat, opts, tab)
    if opts.slots:
        _emit_slot_loads(c, feat, opts)
    _emit_counters(c)
    c("for step in range(s0, s1):")
    c.indent()
    emit_step_start(c, inputs=False)  # the input is read from the device's whole call
    if _reads_inputs(feat, opts):
        _emit_step_inputs(c, _input_fractions(opts, tab))
    for s in range(tab.stages):
        _emit_stage(c, feat, opts, tab, s)
    _emit_combine(c, feat, opts, tab)
    _emit_step_end(c, opts)
    c.dedent()
    _emit_store(c, feat, opts)
    return c.text()


def _sync(c: _Code, opts: CudaOptions) -> None:
    """A barrier of the run's threads (split form only)."""
    if opts.threads > 1:
        c("cuda.syncthreads()")


def _first(c: _Code, opts: CudaOptions) -> None:
    """Open a block that one thread of the run runs (split form: thread 0)."""
    if opts.threads > 1:
        c("if t == 0:")
        c.indent()


def _end_first(c: _Code, opts: CudaOptions) -> None:
    if opts.threads > 1:
        c.dedent()


def _emit_state(c: _Code, feat: Features, opts: CudaOptions, tab: Tableau) -> None:
    """The run's arrays (split: in shared memory), its state read from the device, its
    reductions' sums (split: thread 0's)."""
    split = opts.threads > 1
    where = "shared" if split else "local"
    stages = tab.stages - _folds(feat, opts, tab)
    for name in ["x", "v", "xs", "vs"] + [f"kv{s}" for s in range(stages)]:
        c(f"{name} = cuda.{where}.array(N, FT)")
    if _reads_inputs(feat, opts):  # a stage's input `uc` is one of these (`_emit_stage`)
        for k in range(len(_input_fractions(opts, tab))):
            c(f"ut{k} = cuda.local.array(NCH, FT)")
    c(_node_loop(opts))
    c("    x[i] = xst[i, r]")
    c("    v[i] = vst[i, r]")
    c("    vs[i] = FT(0.0)")
    sums = _sums(feat, opts)
    for local, out, size in sums:
        c(f"{local} = cuda.local.array({size}, np.float64)")
        c(f"for q in range({size}):")
        c(f"    {local}[q] = {out}[q, r]")
    if split and opts.gram:
        c(f"gracc = cuda.shared.array({opts.gram}, np.float64)")
        c(f"for q in range(t, {opts.gram}, T):")
        c("    gracc[q] = gram[q, r]")
    if split:
        c("stop_ = cuda.shared.array(1, np.int32)")
        c("if t == 0:")
        c("    stop_[0] = 0")
        c("cuda.syncthreads()")


def _node_loop(opts: CudaOptions) -> str:
    """The loop over the run's nodes (split: this thread's share, the nodes dealt to it:
    positions t, t + T, ... of the host's order `deal`)."""
    return "for i in deal[t:N:T]:" if opts.threads > 1 else "for i in range(N):"


def _sums(feat: Features, opts: CudaOptions) -> list[tuple[str, str, int]]:
    """(local array, device array, rows) of each reduction the kernel accumulates."""
    out = []
    if opts.work and feat.in_forces:
        out.append(("w_in", "work_in", "fi_node.shape[0]"))
    if opts.work and feat.common_forces:
        out.append(("w_c", "work_c", "fc_node.shape[0]"))
    gram = 0 if opts.threads > 1 else opts.gram  # split: shared (`_emit_split_gram`)
    out += [(loc, dev, size) for loc, dev, size in (("dsacc", "diss", opts.dampers),
                                                  ("msacc", "msq", opts.msq),
                                                  ("gracc", "gram", gram)) if size]
    # local arrays need compile-time sizes: the force counts are the netlist's
    fixed = {"fi_node.shape[0]": "NFI", "fc_node.shape[0]": "NFC"}
    return [(loc, dev, fixed.get(size, size)) for loc, dev, size in out]


def _emit_counters(c: _Code) -> None:
    """The step counters of `codegen.emit_step_start` at step s0 (sub, k0: the step's
    position on the input grid, before its increment), the record counter."""
    c("k0 = s0 // substeps")
    c("sub = s0 - k0 * substeps - 1")
    c("if sub < 0:")
    c("    sub = substeps - 1")
    c("    k0 -= 1")
    c("rc_ = s0 % rec_every")
    c("rn_ = s0 // rec_every")


def _emit_stage(c: _Code, feat: Features, opts: CudaOptions, tab: Tableau, s: int) -> None:
    """Stage s: its state (Nystrom form), its input, its forces, its reductions. Split, the
    run's threads meet after the stage state (the forces read every node's) and after forces
    that read the stage state, before the next stage overwrites it (with a Lawson scheme
    after every stage's forces: a block's thread reads its nodes' forces)."""
    c(f"# stage {s} (c = {tab.c[s]!r})")
    power = opts.work or opts.dampers
    if s > 0:
        _emit_stage_state(c, opts, tab, s)
        if _lawson(opts):  # the blocks' exact flow to the stage, their rows of xs (and vs)
            _emit_blocks(c, opts, tab, s, "xs", "vs" if power else None)
        _sync(c, opts)
    if feat.in_forces:
        c(f"uc = ut{_input_fractions(opts, tab).index(tab.c[s])}")
    xa, va = ("x", "v") if s == 0 else ("xs", "vs")
    if feat.common_forces:
        c(f"grow = g[step - s0, {s}]")
    folded = s == tab.stages - 1 and _folds(feat, opts, tab)
    rows = terms.Rows(xa, va, f"kv{s}")
    for line in force_code(feat, opts, rows, _combine_store(tab) if folded else None):
        c(line)
    if tab.b[s] != 0.0 and (opts.dampers or opts.work and (feat.in_forces
                                                           or feat.common_forces)):
        _first(c, opts)
        _emit_stage_reductions(c, feat, opts, s, va)
        _end_first(c, opts)
    # a Lawson scheme's blocks read their nodes' stage forces in threads of their own
    if _lawson(opts) or 0 < s < tab.stages - 1:
        _sync(c, opts)


def _combine_store(tab: Tableau) -> list[str]:
    """The split form's folded combine (`_folds`) as the lane statements that take each
    node's last stage force, its sum A{b}: the node's new state, that force kept in the
    register rather than stored."""
    last = tab.stages - 1
    xterm, vterm = combine_terms(tab, "V", lambda k: "A{b}" if k == last else f"kv{k}[i, {{b}}]")
    return ["V = v[i, {b}]", f"x[i, {{b}}] = x[i, {{b}}] + ({xterm})",
            f"v[i, {{b}}] = V + ({vterm})"]


def _reads_inputs(feat: Features, opts: CudaOptions) -> bool:
    """Whether the step reads the input samples: input forces, or a Lawson scheme's blocks."""
    return feat.in_forces or _lawson(opts)


def _input_fractions(opts: CudaOptions, tab: Tableau) -> list[float]:
    """The fractions of the step where it reads the input: the tableau's stage times, and a
    Lawson scheme's blocks' (`expint.lawson_fractions`)."""
    return expint.lawson_fractions(tab)[1] if _lawson(opts) else sorted(set(tab.c))


def _emit_step_inputs(c: _Code, fractions: list[float]) -> None:
    """The input at every fraction of the step where it is read (`ut{k}`, interpolated as the
    CPU kernels interpolate it), all at the step's start: the loads of the later stages'
    samples wait on nothing, where read stage by stage each would wait for the barrier
    before its stage (the split form) and then hold up the stage."""
    for k, frac in enumerate(fractions):
        for line in interp_weights(f"(sub + {frac!r}) / substeps", "k0 + {i} - ubase"):
            c(line)
        c("for ch in range(NCH):")
        c(f"    ut{k}[ch] = gr * u[ch, kk, r] + fr * u[ch, kk + 1, r]")


def _emit_blocks(c: _Code, opts: CudaOptions, tab: Tableau, stage: int | None, xo: str,
                 vo: str | None) -> None:
    """A Lawson scheme's exact blocks, from the step's start to stage `stage` (None: its end):
    the free flow E, the input through P0 and P1, and the stage forces on the block's nodes
    carried by E (`expint._Lawson.step`), written into their rows of `xo` (and `vo`) as
    `expint`'s kernels sum them. Split, each thread its share of the blocks."""
    fracs, ufracs = expint.lawson_fractions(tab)
    step = expint._Lawson(tab, fracs, ufracs, list(opts.blocks), opts.block_channels,
                          LaneLayout(1, 1)).step(stage)
    for m in opts.blocks:
        _emit_block_size(c, opts, step, m, xo, vo)


def _emit_block_size(c: _Code, opts: CudaOptions, step, m: int, xo: str,
                     vo: str | None) -> None:
    rows = 2 * m if vo else m  # output rows: positions, then velocities
    first = "t, " if opts.threads > 1 else ""
    stride = ", T" if opts.threads > 1 else ""
    c(f"for q in range({first}lw{m}_node.shape[0]{stride}):")
    c.indent()
    for r in range(m):
        c(f"i{r} = lw{m}_node[q, {r}]")
    for r in range(m):
        c(f"Z{r} = x[i{r}]")
        c(f"Z{m + r} = v[i{r}]")
    for t in step.terms:
        c(f"hw{t.j} = {t.weight}")
        for r in range(m):
            c(f"S{t.j}_{r} = hw{t.j} * {t.kv}[i{r}]")
    f0 = step.f0
    for r in range(rows):
        parts = [f"lw{m}_e[q, {f0}, {r}, {k}] * Z{k}" for k in range(2 * m)]
        parts += [f"lw{m}_p0[q, {f0}, {r}, {ch}] * ut0[{ch}] + "
                  f"lw{m}_p1[q, {f0}, {r}, {ch}] * {step.input}[{ch}]"
                  for ch in range(opts.block_channels)]
        for t in step.terms:
            if t.fraction is not None:
                parts += [f"lw{m}_e[q, {t.fraction}, {r}, {m + k}] * S{t.j}_{k}"
                          for k in range(m)]
            elif r >= m:
                parts.append(f"S{t.j}_{r - m}")
        c(f"O{r} = {' + '.join(parts)}")
    for r in range(m):
        c(f"{xo}[i{r}] = O{r}")
        if vo:
            c(f"{vo}[i{r}] = O{m + r}")
    c.dedent()


def _emit_stage_state(c: _Code, opts: CudaOptions, tab: Tableau, s: int) -> None:
    """xs = x + h c_s v + h^2 sum (A A)_sk kv_k, vs = v + h sum a_sj kv_j (where read)."""
    xterm, vterm = stage_terms(tab, s, "v[i]", lambda k: f"kv{k}[i]")
    for i, line in _per_node(opts):
        c(line)
        if i is None and _lawson(opts):
            c("    if frz[i]:  # an exact block's: `_emit_blocks`")
            c("        continue")
        if i is None:
            c("    xs[i] = x[i] + (" + xterm + ")")
            c("    if vneed[i]:")
            c(f"        vs[i] = v[i] + {vterm}")
            continue
        c(f"xs[{i}] = x[{i}] + (" + _at(xterm, i) + ")")
        if opts.vneed[i]:
            c(f"vs[{i}] = v[{i}] + " + _at(vterm, i))


def _per_node(opts: CudaOptions) -> list[tuple[int | None, str]]:
    """A loop over the nodes (`(None, 'for i ...')`) or, written out, each node i."""
    if opts.nodes is None:
        return [(None, _node_loop(opts))]
    return [(i, f"# node {i}") for i in range(opts.n)]


def _at(expr: str, i: int) -> str:
    return expr.replace("[i]", f"[{i}]")


def force_code(feat: Features, opts: CudaOptions, rows: terms.Rows = terms.ROWS,
               store: list[str] | None = None) -> list[str]:
    """rows.k = M^-1 F(rows.x, rows.v, uc, grow) for one run, as lines (relative
    indentation); the split form takes each node's sum with the lane statements `store`
    (default: into rows.k)."""
    if opts.threads > 1:
        return _split_force_code(feat, opts, rows,
                                 store or [f"{rows.k}[i, {{b}}] = A{{b}}"])
    out: list[str] = []
    if opts.nodes is not None:
        for i, node in enumerate(opts.nodes):
            expr = terms.node_sum(i, node, lambda j: f"{rows.x}[{j}]",
                                  lambda j: f"{rows.v}[{j}]", lambda ch: f"uc[{ch}]",
                                  lambda e: f"grow[{e}]")
            out.append(f"{rows.k}[{i}] = {expr}")
    else:
        out += _linear(feat, rows)
        for kind in terms.LOOP_ORDER:
            if getattr(feat, kind.feature):
                out += _kind_loop(kind, rows)
    if feat.monomials:
        out += _monomials(rows)
    if feat.common_forces and opts.nodes is None:
        out += _kind_loop(terms.COMMON, rows)
    return out


def _split_force_code(feat: Features, opts: CudaOptions, rows: terms.Rows,
                      store: list[str]) -> list[str]:
    """The split form's forces: each thread's nodes sum their own terms and element ends
    (`codegen.emit_linear`'s parallel form, one lane; with `opts.slots`, `_slot_force_code`);
    monomials and shared signals, which scatter, are then added by thread 0 alone, after a
    barrier, and the run's threads meet again before anyone reads them."""
    if opts.slots:
        out = _slot_force_code(feat, opts, rows, [one_run(line) for line in store])
    else:
        sub = _Code()
        emit_linear(sub, feat, ONE_RUN, parallel=True, loop=_node_loop(opts), store=store,
                    rows=rows)
        out = sub.lines
    scattered = (_monomials(rows) if feat.monomials else []) + (
        _kind_loop(terms.COMMON, rows) if feat.common_forces else [])
    if scattered:
        out += ["cuda.syncthreads()", "if t == 0:"] + ["    " + line for line in scattered]
        out += ["cuda.syncthreads()"]
    return out


def _slot_spec(feat: Features, opts: CudaOptions) -> tuple:
    """The tables of `opts.slots` (`springc.sim.gpu` builds them): per list, its name, its
    entries per node, its `ptr` and `elem` arrays and its fields."""
    return tuple((sl.name, k, sl.ptr, sl.elem, sl.fields)
                 for sl, (_, k, _) in zip(slot_lists(feat), opts.slots))


def _slot_count(opts: CudaOptions) -> int:
    """The nodes each thread of the split form holds (its slots)."""
    return -(-opts.n // opts.threads)


def _emit_slot_loads(c: _Code, feat: Features, opts: CudaOptions) -> None:
    """Each of the thread's nodes (slot j: the node at position t + j T of the host's order
    `deal`) and its terms' fields, read once per launch into scalars (`sl_{list}_{field}`:
    entry q of node i at [q, i]; a node's count of each list in `sl_n`). A thread past the
    last node reads the last node's (not used)."""
    for j in range(_slot_count(opts)):
        p = f"t + {j * opts.threads}"
        c(f"s_i{j} = deal[{p}] if {p} < N else N")
        c(f"s_c{j} = s_i{j} if s_i{j} < N else N - 1")
        c(f"s_bm{j} = bm[s_c{j}]")
        c(f"s_km{j} = km[s_c{j}]")
        for row, (sl, (_, k, _)) in enumerate(zip(slot_lists(feat), opts.slots)):
            if not k:
                continue
            c(f"s_n{sl.name}{j} = sl_n[{row}, s_c{j}]")
            for q in range(k):
                for f, _, _ in sl.fields:
                    c(f"s_{sl.name}{j}_{q}_{f} = sl_{sl.name}_{f}[{q}, s_c{j}]")


def _slot_force_code(feat: Features, opts: CudaOptions, rows: terms.Rows,
                     store: list[str]) -> list[str]:
    """The split form's force code with each of the thread's nodes written out (slot j), its
    terms' fields in the registers `_emit_slot_loads` filled, each term guarded by the
    node's count, the terms past a list's registers read in a loop: the same sum in the same
    order as `codegen.emit_linear`'s parallel form, so that it rounds alike."""
    out: list[str] = []
    last = _slot_count(opts) - 1
    for j in range(last + 1):
        body = [f"i = s_i{j}"] + _slot_node(feat, opts, j, rows) + store
        if j == last and opts.n % opts.threads:
            out += [f"if s_i{j} < N:"] + ["    " + line for line in body]
        else:
            out += body
    return out


def _slot_node(feat: Features, opts: CudaOptions, j: int, rows: terms.Rows) -> list[str]:
    """Slot j's node's sum A0: own terms, then each list's terms."""
    v, x = f"{rows.v}[i]", f"{rows.x}[i]"
    own = terms.own_sum(True, True, f"s_bm{j}", f"s_km{j}", v, x)
    spring = terms.own_sum(False, True, f"s_bm{j}", f"s_km{j}", v, x)
    out = [f"if s_bm{j} != 0.0:", f"    A0 = {own}", "else:", f"    A0 = {spring}"]
    for sl, (_, k, looped) in zip(slot_lists(feat), opts.slots):
        for q in range(k):
            scalars = {f: f"s_{sl.name}{j}_{q}_{f}" for f, _, _ in sl.fields}
            out += [f"if s_n{sl.name}{j} > {q}:"] + [
                "    " + line for line in _slot_term(sl, scalars, rows)]
        if looped:
            out += _slot_loop(sl, k, rows)
    return out


def _slot_loop(sl: SlotList, k: int, rows: terms.Rows) -> list[str]:
    """A node's terms of list `sl` past its first k, read from the arrays."""
    at = f"{sl.elem}[q_]" if sl.elem else "q_"
    fields = {f: f"{arr}[{at if by_elem else 'q_'}]" for f, arr, by_elem in sl.fields}
    head = [f"for q_ in range({sl.ptr}[i] + np.uint64({k}), {sl.ptr}[i + 1]):"]
    return head + ["    " + line for line in _slot_term(sl, fields, rows)]


def _slot_term(sl: SlotList, fields: dict[str, str], rows: terms.Rows) -> list[str]:
    """One term of list `sl` added to A0, its fields read from the expressions `fields`."""
    if sl.name == "row":
        return ["A0 = A0 " + terms.ROW.format(w=fields["w"], xj=f"{rows.x}[{fields['c']}]")]
    if sl.name == "in":
        return ["A0 = A0 " + terms.INPUT.format(gm=fields["w"], u=f"uc[{fields['c']}]")]
    kind = terms.BY_NAME[sl.name]

    def end(which: str, ground: bool = False) -> list[str]:
        code = terms.gather_end(kind, which, ground, coef=lambda f, _: fields[f], rows=rows)
        # one lane, numbered 0 as the accumulator A0 is
        return ["    " + one_run(line) for line in code.head + code.loads + code.arith]

    if kind.node_j is None:
        return [line[4:] for line in end("i")]
    out = [f"o = {fields['o']}", f"if {fields['end']} == 0:"]
    if kind.ground is not None:
        out += ["    if o < 0:  # to ground"] + ["    " + line for line in end("i", True)]
        out += ["    else:"] + ["    " + line for line in end("i")]
    else:
        out += end("i")
    return out + ["else:"] + end("j")


def _linear(feat: Features, rows: terms.Rows) -> list[str]:
    """Each node's own terms, stiffness row and inputs, stored once (`codegen.emit_linear`)."""
    own = terms.own_sum(True, True, "bi", "ki", f"{rows.v}[i]", f"{rows.x}[i]")
    spring = terms.own_sum(False, True, "bi", "ki", f"{rows.v}[i]", f"{rows.x}[i]")
    out = ["for i in range(N):", "    bi = bm[i]", "    ki = km[i]", "    if bi != 0.0:",
           f"        A = {own}", "    else:", f"        A = {spring}"]
    if feat.couplings:
        out += ["    for e in range(l_ptr[i], l_ptr[i + 1]):",
                "        A = A " + terms.ROW.format(w="l_val[e]", xj=f"{rows.x}[l_col[e]]")]
    if feat.in_forces:
        out += ["    for e in range(fi_ptr[i], fi_ptr[i + 1]):",
                "        A = A " + terms.INPUT.format(gm="fi_gm[e]", u="uc[fi_chan[e]]")]
    return out + [f"    {rows.k}[i] = A"]


def _kind_loop(kind: terms.Kind, rows: terms.Rows) -> list[str]:
    """The loop over the elements of `kind` (`codegen._emit_kind` for one run)."""
    def element(code: terms.LoopCode, pad: str) -> list[str]:
        lines = code.head + code.loads + code.arith + code.stores
        return [pad + one_run(line, "") for line in lines]

    out = [f"for e in range({kind.node_i}.shape[0]):"]
    if kind.ground is None:
        return out + element(terms.element_loop(kind, rows=rows), "    ")
    out += [f"    j = {kind.node_j}[e]", "    if j < 0:"]
    out += element(terms.element_loop(kind, ground=True, rows=rows), "        ")
    out += ["    else:"] + element(terms.element_loop(kind, rows=rows), "        ")
    return out


def _monomials(rows: terms.Rows) -> list[str]:
    """The monomials' loop for the thread's one run (`codegen.emit_monomials`)."""
    sub = _Code()
    emit_monomials(sub, ONE_RUN, rows=rows)
    return sub.lines


def _emit_stage_reductions(c: _Code, feat: Features, opts: CudaOptions, s: int,
                           va: str) -> None:
    """Stage s's share of the input work and dissipation (`codegen.emit_stage_reductions`)."""
    if opts.work and feat.in_forces:
        c("for e in range(NFI):")
        # a Lawson kernel's rest has its blocks' inputs at gain 0: their own gains, fi_w
        gain = "fi_w[e]" if _lawson(opts) else "(fi_gm[e] / minv[fi_node[e]])"
        c(f"    fw = hbd{s} * {gain}")
        c("    " + one_run(work_in_update(va), ""))
    if opts.work and feat.common_forces:
        c("for e in range(NFC):")
        c(f"    fv = fc_gm[e] / minv[fc_node[e]] * g[step - s0, {s}, e]")
        c("    " + one_run(work_common_update(va, f"hbd{s}"), ""))
    if opts.dampers:
        c(f"for d in range({opts.dampers}):")
        c("    i = ds_i[d]")
        c("    j = ds_j[d]")
        for stmt in damper_update(va, f"hbd{s}", "ds_b[d]"):
            c("    " + one_run(stmt, ""))


def _emit_combine(c: _Code, feat: Features, opts: CudaOptions, tab: Tableau) -> None:
    """The step's new state from its stages (split: each thread its nodes, or folded into
    the last stage's force loop, then a barrier before anyone reads them)."""
    if _folds(feat, opts, tab):
        _sync(c, opts)
        return
    _sync_before_combine(c, opts, tab)
    xterm, vterm = combine_terms(tab, "V", lambda k: f"kv{k}[i]")
    for i, line in _per_node(opts):
        c(line)
        if i is None and _lawson(opts):
            c("    if frz[i]:  # an exact block's: `_emit_blocks`")
            c("        continue")
        pad = "    " if i is None else ""
        fix = (lambda e: e) if i is None else (lambda e: _at(e, i))
        idx = "i" if i is None else str(i)
        c(f"{pad}V = v[{idx}]")
        c(f"{pad}x[{idx}] = x[{idx}] + (" + fix(xterm) + ")")
        c(f"{pad}v[{idx}] = V + (" + fix(vterm) + ")")
    if _lawson(opts):
        _emit_blocks(c, opts, tab, None, "x", "v")
    _sync(c, opts)


def _sync_before_combine(c: _Code, opts: CudaOptions, tab: Tableau) -> None:
    """A one-stage tableau's forces read x and v, which the combine then writes."""
    if tab.stages == 1:
        _sync(c, opts)


def _emit_step_end(c: _Code, opts: CudaOptions) -> None:
    """Mean squares, Gram sums, the record when due and the divergence guard
    (`codegen.emit_step_end`), by thread 0 in the split form; a diverged run stops, its
    state and sums stored (split: every thread of it, told through shared memory)."""
    c("k1 = step + 1")
    _first(c, opts)
    if opts.msq:
        c(f"for m in range({opts.msq}):")
        c("    if ms_lo[m] <= k1 and k1 <= ms_hi[m]:")
        for stmt in msq_update():
            c("        " + one_run(stmt, ""))
    if opts.gram and opts.threads == 1:
        c(f"for gq in range({opts.gram}):")
        c("    gracc[gq] *= gr_decay[gq]")
        c("for p in range(gr_i.shape[0]):")
        c("    gracc[gr_g[p]] += gr_w[p] * x[gr_i[p]] * x[gr_j[p]]")
    if opts.probes:
        c("rc_ += 1")
        c("if rc_ == rec_every:")
        c("    rc_ = 0")
        c("    rn_ += 1")
        c(f"    for p in range({opts.probes}):")
        c("        q = rec_node[p]")
        c("        rec[p, rn_ - rbase, r] = v[q] if rec_isv[p] else x[q]")
    if opts.threads > 1 and not (opts.msq or opts.probes):
        c("pass")
    _end_first(c, opts)
    if opts.gram and opts.threads > 1:
        _emit_split_gram(c, opts)
    c("if k1 % check_every == 0 or k1 == nsteps:")
    c.indent()
    _first(c, opts)
    c("worst = 0.0")
    c("wi = -1")
    c("for i in range(N):")
    c("    ax = abs(x[i])")
    c("    if not (ax <= limit and abs(v[i]) <= limit):")
    c("        ax = np.inf")
    c("    if wi < 0 or ax > worst:")
    c("        worst = ax")
    c("        wi = i")
    c("if not worst <= limit:")
    c("    status[r] = k1")
    c("    bad_node[r] = wi")
    if opts.threads > 1:
        c("    stop_[0] = 1")
        c.dedent()
        c("cuda.syncthreads()")
        c("if stop_[0] != 0:")
    c("    break")
    c.dedent()


def _emit_split_gram(c: _Code, opts: CudaOptions) -> None:
    """The Gram sums, each thread its share of the groups, each group decayed and then its
    pairs added in their order (`gr_ptr`: the pairs sorted by group), as the one-thread
    loops add them."""
    c(f"for gq in range(t, {opts.gram}, T):")
    c("    acc = gracc[gq] * gr_decay[gq]")
    c("    for p in range(gr_ptr[gq], gr_ptr[gq + 1]):")
    c("        acc += gr_w[p] * x[gr_i[p]] * x[gr_j[p]]")
    c("    gracc[gq] = acc")


def _emit_store(c: _Code, feat: Features, opts: CudaOptions) -> None:
    """The state and the sums back to the device arrays."""
    c(_node_loop(opts))
    c("    xst[i, r] = x[i]")
    c("    vst[i, r] = v[i]")
    sums = _sums(feat, opts)
    if sums:
        _first(c, opts)
    for local, out, size in sums:
        c(f"for q in range({size}):")
        c(f"    {out}[q, r] = {local}[q]")
    if sums:
        _end_first(c, opts)
    if opts.gram and opts.threads > 1:
        c(f"for q in range(t, {opts.gram}, T):")
        c("    gram[q, r] = gracc[q]")


