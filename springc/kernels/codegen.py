"""Code generation: a flat netlist and `KernelOptions` in, the Python source of a Numba kernel
out, as plain text (this module never imports numba; `springc.kernels.loader` compiles it).

The kernel is specialised to the element kinds the netlist uses, the integrator (stages
unrolled from its Butcher tableau), the precision and the recorded quantities; node indices
and coefficients are runtime arguments, so netlists of the same element kinds share one
compiled kernel. For long runs of small networks the linear, input and quadratic forces are
written out per node instead (`emit_nodes`: one kernel per structure). The state is laid out
`(n_dof, lanes)` per chunk of runs; `run` integrates a range of chunks without the GIL.
Why the loops look as they do: docs/performance.md#the-shared-kernels-shape.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import importlib.util
import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from springc.kernels import terms, thermal
from springc.kernels.integrators import Tableau, get_tableau
from springc.lang.ir import FlatNetlist

KERNEL_VERSION = 8  # bump when the generated text or its calling convention changes
RECORD_ALIGN = 64  # bytes: the record's alignment and row padding (a cache line, and a
# multiple of every streaming store's size), which `emit_record`'s aligned stores rely on
LANE_CHOICES = (32, 16, 4, 1)  # compile-time lane widths a kernel is generated for (32: the
# per-element index and loop work spread over more lanes)
STAGE_BLOCK = 32  # steps of input samples staged at a time
FASTMATH = '{"contract"}'  # FMA contraction only
# the node-split kernels' parallel options: their explicit prange loops only; numba's search
# for array expressions to turn into parallel loops, and for loops to fuse, finds none in the
# generated text and cost a third of the compile (docs/performance.md, "One run on every core")
PARALLEL = ('{"prange": True, "comprehension": False, "reduction": False, '
            '"inplace_binop": False, "setitem": False, "numpy": False, "stencil": False, '
            '"fusion": False}')


@dataclass(frozen=True)
class KernelOptions:
    """Everything besides the element kinds that changes the generated text.

    `record`: store probe trajectories; `work`: accumulate input work per force element;
    `dissipation`: accumulate energy dissipated in dampers; `msq`: windowed mean squares;
    `gram`: leaky Gram sums of node-pair products (springc.sim.reductions `gram`); `lanes`: runs
    per chunk, a compile-time constant (`choose_lanes`); `nodes`: each node's force terms
    (`terms.node_terms`) when the force code is written out per node, None for the shared kernel
    that loops over the runtime index arrays; `registers`: each node's terms
    (`springc.kernels.terms.node_terms`) for a register kernel, each run's step in scalars;
    `parallel`: the shared kernel with each step's node loops split over numba's threads
    (`prange`), every node summing its own forces (`terms.node_ends`) in the serial
    kernel's order, for one or a few runs of a large network; `per_run`: coefficient arrays
    passed with a column per run, (entries, runs), sorted (the points of a `.step`/`.mc`
    group in the lanes of one call, `springc.sim.simulate.simulate_lanes`): each chunk
    copies its lanes' columns (`emit_lane_coefficients`) and the force code reads them per
    lane. Empty: every run shares the arrays (and the text is the one without points).
    `fma`: whether LLVM may fuse a product and an add (False: each rounds on its own, as the
    CUDA form with `CudaOptions.fma` False rounds them, so that the two agree to the bit)."""

    method: str = "rk4"
    precision: str = "float64"
    lanes: int = 16
    record: bool = True
    work: bool = False
    dissipation: bool = False
    msq: bool = False
    gram: bool = False
    nodes: tuple | None = None
    registers: tuple | None = None
    parallel: bool = False
    per_run: tuple[str, ...] = ()
    fma: bool = True


@dataclass(frozen=True)
class Features:
    """Which element kinds and force kinds the netlist uses."""

    local_damping: bool
    springs: bool
    duffings: bool
    couplings: bool
    quads: bool
    dashpots: bool
    monomials: bool
    in_forces: bool
    common_forces: bool
    thermal: bool = False  # `.options temp=` > 0: every damper's noise force


def features(net: FlatNetlist) -> Features:
    """The element kinds present in `net` (the part of the netlist that shapes the kernel)."""
    kinds = [s.kind for s in net.forces.source]
    return Features(
        # always on: per-node diagonal terms (local damping, springs), so damped/undamped and
        # sprung/free variants share one kernel
        local_damping=True,
        springs=True,
        duffings=len(net.duffings) > 0,
        couplings=len(net.couplings) > 0,
        quads=len(net.quads) > 0,
        dashpots=len(net.dashpots) > 0,
        monomials=len(net.monomials) > 0,
        in_forces=any(k == "in" for k in kinds),
        common_forces=any(k != "in" for k in kinds),
        thermal=float(net.options.get("temp", 0.0)) > 0,
    )


# Runtime arguments of `accel`, per feature (coefficients prepared by springc.sim.simulate, the
# inverse mass folded in: `bm` = b/m, `km` = springs/m per node, element coefficients per end).
_ACCEL_ARGS = {
    "local_damping": ("bm",),
    "springs": ("km",),
    "duffings": ("d_node", "d_lm"),
    "couplings": ("l_ptr", "l_col", "l_val"),
    "quads": ("q_i", "q_j", "q_a", "q_gi", "q_gj"),
    "dashpots": ("b_i", "b_j", "b_bi", "b_bj"),
    "monomials": ("p_c", "p_ptr", "p_var", "p_exp"),
    "in_forces": ("fi_node", "fi_gm", "fi_chan", "fi_ptr"),
    "common_forces": ("fc_node", "fc_gm"),
    "thermal": thermal.NOISE_ARGS,
}


def coefficient_names() -> frozenset[str]:
    """The force coefficient arrays a kernel may take with a column per run
    (`KernelOptions.per_run`): every feature's arguments but the index arrays and the
    thermal noise's."""
    names = {name for key, args in _ACCEL_ARGS.items() if key != "thermal" for name in args}
    return frozenset(names - {"d_node", "l_ptr", "l_col", "q_i", "q_j", "b_i", "b_j",
                              "p_ptr", "p_var", "p_exp", "fi_node", "fi_chan", "fi_ptr",
                              "fc_node"}) | {"minv"}


def choose_lanes(runs_per_task: int) -> int:
    """The widest lane count of `LANE_CHOICES` that a task of this many runs fills (padding a
    single run to many lanes would multiply its work)."""
    return next((w for w in LANE_CHOICES if runs_per_task >= w), 1)


def accel_args(feat: Features) -> list[str]:
    """Names of the coefficient arrays the kernel takes for these features, in order."""
    names = ["minv"]
    for key, args in _ACCEL_ARGS.items():
        if getattr(feat, key):
            names += args
    return names


def gather_args(feat: Features) -> list[str]:
    """Names of the per-node end arrays (`terms.node_ends`) a parallel kernel takes."""
    return [name for kind in terms.LOOP_ORDER if getattr(feat, kind.feature)
            for name in terms.gather_args(kind)]


# each accumulated reduction's arguments (`KernelOptions` names the reduction), in the order
# every form takes them
REDUCTION_ARGS = {"work": ("work_in", "work_c"), "dissipation": ("ds_i", "ds_j", "ds_b", "diss"),
                  "msq": ("ms_node", "ms_isv", "ms_lo", "ms_hi", "msq"),
                  "gram": ("gr_i", "gr_j", "gr_g", "gr_w", "gr_decay", "gram")}


def run_args(feat: Features, opts: KernelOptions) -> list[str]:
    """Names of all arguments of the generated `run`, in order."""
    names = ["x0", "v0", "u", "g", "nsteps", "substeps", "h", "chunk", "c0", "c1",
             "check_every", "limit"]
    names += accel_args(feat)
    if opts.parallel:
        names += gather_args(feat)
    if opts.record:
        names += ["rec_every", "rec_node", "rec_isv", "rec", "rec_col"]
    for key, args in REDUCTION_ARGS.items():
        if getattr(opts, key):
            names += args
    names += ["xf", "vf", "status", "bad_node"]
    return names


def generate(net: FlatNetlist, options: KernelOptions) -> str:
    """Python source of the kernel for `net` under `options`, with a descriptive header."""
    return with_header(net, options, *hashed_body(features(net), options))


def with_header(net: FlatNetlist, options: KernelOptions, body: str, digest: str) -> str:
    """A kernel body under its header: the netlist, the options, the integrator, the body's
    hash."""
    tab = get_tableau(options.method)
    header = [
        "# springc generated kernel: do not edit (regenerated from the netlist)",
        f"# netlist: {net.file}",
        f"# title: {net.title}",
        *options_header(options),
        f"# integrator: {tab.name} ({tab.description})",
        f"# dofs: {net.n}; elements: {net.element_counts()}",
        f"# body-hash: {digest}",
        "",
    ]
    return "\n".join(header) + body


def options_header(options: KernelOptions) -> list[str]:
    """Header lines naming the options (the per-node terms only by how the force code is
    written: they are in the body)."""
    # vars, not asdict, which deep-copies (a noticeable share of a short call)
    # `parallel` only where set: the serial kernels' text (and cache key) is unchanged by it
    # `per_run` likewise: a kernel without points keeps its text
    shown = {k: v for k, v in vars(options).items()
             if k not in ("nodes", "registers") and (k not in ("parallel", "per_run") or v)}
    how = ("written out per node, the state in registers (springc.kernels.regkernel)"
           if options.registers else "written out per node" if options.nodes
           else "per node over the runtime index arrays, nodes split over threads"
           if options.parallel else "loops over the runtime index arrays")
    return [f"# options: {shown}", f"# force code: {how}"]


@functools.lru_cache(maxsize=64)
def hashed_body(feat: Features, options: KernelOptions) -> tuple[str, str]:
    """The kernel body and its hash: text that depends on the element kinds and the options
    only, so it is kept per process (writing it out was a large share of a short
    simulation of a small network)."""
    body = _body(feat, options, get_tableau(options.method))
    return body, source_hash(body)


def source_hash(text: str) -> str:
    """Short content hash naming the kernel file (same text -> same compiled cache)."""
    return hashlib.sha256(f"{KERNEL_VERSION}\n{text}".encode()).hexdigest()[:20]


_PER_NETLIST = ("# netlist: ", "# title: ", "# dofs: ")


def shared_text(source: str) -> str:
    """The source without the header lines that name one netlist: what the cache stores, so
    every netlist with the same element kinds and options shares one compiled kernel (and a
    cached file is never rewritten with another header, which would invalidate numba's
    cache)."""
    return "".join(line for line in source.splitlines(keepends=True)
                   if not line.startswith(_PER_NETLIST))


@functools.lru_cache(maxsize=256)
def kernel_hash(source: str) -> str:
    """The hash naming a kernel's cache file (of `shared_text`)."""
    return source_hash(shared_text(source))


class _Code:
    """A tiny indented-line writer."""

    def __init__(self) -> None:
        self.lines: list[str] = []
        self.level = 0
        self.tags = 0

    def next_tag(self) -> str:
        """A suffix no other call has had (`lanes`' own names)."""
        self.tags += 1
        return f"_t{self.tags}_"

    def __call__(self, text: str = "") -> None:
        self.lines.append("    " * self.level + text if text else "")

    def indent(self, by: int = 1) -> None:
        self.level += by

    def dedent(self, by: int = 1) -> None:
        self.level -= by

    def text(self) -> str:
        return "\n".join(self.lines) + "\n"


@functools.cache
def _module_hash(module: str) -> str:
    """A hash of a module's source that kernels import (`springc.kernels.streamstore`,
    `springc.kernels.stackalign`, `springc.kernels.chunk`), written into the kernels that
    import it: numba's cache of a kernel checks only the kernel's own file, so a change there
    must change the kernel's text (and so its cache key). Read, not imported: this module
    never imports numba."""
    origin = importlib.util.find_spec(module).origin
    return hashlib.sha256(Path(origin).read_bytes()).hexdigest()[:16]


def decorator(parallel: bool = False, fma: bool = True) -> str:
    """The njit decorator of every generated function (`fma` False: LLVM may not contract a
    product and an add into a fused multiply-add, so each rounds on its own)."""
    fast = FASTMATH if fma else "False"
    if parallel:
        return (f'@nb.njit(parallel={PARALLEL}, cache=True, error_model="numpy", '
                f'nogil=True, fastmath={fast})')
    return f'@nb.njit(cache=True, error_model="numpy", nogil=True, fastmath={fast})'


def preamble(c: _Code, opts: KernelOptions, args: list[str], stages: int) -> None:
    """Imports and module constants of a generated kernel."""
    c("import numpy as np")
    c("import numba as nb")
    c("from springc.kernels.chunk import guard, load_lanes, mark_nodes, record_tail, "
      "restage, store_lanes  "
      f"# {_module_hash('springc.kernels.chunk')}")
    if aligned_frame(opts):
        c("from springc.kernels.stackalign import align_stack  "
          f"# {_module_hash('springc.kernels.stackalign')}")
    if opts.record:
        c("from springc.kernels.streamstore import stream_store, store_fence  "
          f"# {_module_hash('springc.kernels.streamstore')}")
    c("")
    c(f"FT = np.{opts.precision}")
    c(f"ARGS = {tuple(args)!r}")
    c(f"STAGES = {stages}")
    c(f"LANES = {opts.lanes}  # runs per chunk (compile-time: the lane code is unrolled)")
    c(f"STAGE_BLOCK = {STAGE_BLOCK}")
    if opts.record:
        c(f"RB = {record_block(opts.precision)}  # records staged per run, written by lines")
    c("CHUNK_RANGE = True  # run(c0, c1) integrates only chunks c0..c1-1: callers use threads")
    if opts.parallel:
        c("NODE_THREADS = True  # each step's node loops run on numba's threads: call it once")


def _body(feat: Features, opts: KernelOptions, tab: Tableau) -> str:
    c = _Code()
    c('"""Generated by springc.kernels.codegen; see the header. Arrays are (n_dof, lanes)."""')
    preamble(c, opts, run_args(feat, opts), tab.stages)
    c("")
    if feat.thermal:
        thermal.emit_helpers(c, decorator(fma=opts.fma))
    _emit_run(c, feat, opts, tab)
    return c.text()


@dataclass(frozen=True)
class LaneLayout:
    """Lanes per chunk (`width`) and lanes written out per statement (`group`: one 256-bit
    vector, 4 float64 or 8 float32; wider chunks loop over groups, which keeps the text, and
    numba's compile time, small)."""

    width: int
    group: int
    one_run: bool = False  # a form that holds one run (CUDA): no lane index (`one_run`)


def one_run(stmt: str, name: str = "0") -> str:
    """A lane statement (`xa[i, {b}]`, `X{b}`) for a form that holds one run per thread:
    the lane index left out of every subscript, `{b}` in a name replaced by `name`."""
    return re.sub(r", \{b\}\]", "]", stmt).replace("{b}", name)


def lane_layout(opts: KernelOptions) -> LaneLayout:
    """The lane layout of a kernel with these options."""
    per_vector = 32 // (8 if opts.precision == "float64" else 4)
    return LaneLayout(opts.lanes, min(opts.lanes, per_vector))


def lanes(c: _Code, ln: LaneLayout, loads: list[str], arith: list[str],
          stores: list[str], own_arith: bool = False) -> None:
    """Straight-line code for the lanes: the loads, then the arithmetic, then the stores, each
    statement for every lane of a group in turn (`{b}` in a statement is the lane). Loads
    before stores lets LLVM's SLP vectoriser merge a group's lanes into vector loads, FMAs
    and stores without alias checks; the generator guarantees that no store of an element
    overlaps a load of the same element (distinct nodes). A group's lane indices are named
    once (`g1_t7_ = g0_t7_ + 1`...): numba types and lowers each `g_ + b` written in an index
    apart, while LLVM folds them to the same machine code (docs/performance.md, cold-cache
    compiles).

    The temporaries the loads define (and the arithmetic's, with `own_arith`) are this
    call's own, as are the group indices: each gets the call's number (`X{b}` -> `X_t7_{b}`),
    so that every name is defined once in the kernel. numba's SSA reconstruction rewrites
    the whole function once for each name defined more than once (a tenth of a large
    kernel's compile). The arithmetic's names stay as written by default: an accumulator
    (`A{b}`) carries over to later calls."""
    tag = c.next_tag()
    loads, arith, stores = _own_names(tag, loads, arith, stores, own_arith)
    looped = ln.group < ln.width
    lane_names = [f"g{b}{tag}" if looped else str(b) for b in range(ln.group)]
    if looped:
        c(f"for {lane_names[0]} in range(0, {ln.width}, {ln.group}):")
        c.indent()
        for b in range(1, ln.group):
            c(f"{lane_names[b]} = {lane_names[0]} + {b}")
    for part in (loads, arith, stores):
        # one statement's lanes together: stores to one row must not be interleaved with
        # stores to another, which the vectoriser cannot reorder (the rows might overlap)
        for stmt in part:
            for b in range(ln.group):
                c(one_run(stmt) if ln.one_run else _lane_stmt(stmt, b, lane_names[b]))
    if looped:
        c.dedent()


def _own_names(tag: str, loads: list[str], arith: list[str], stores: list[str],
               own_arith: bool) -> tuple[list[str], list[str], list[str]]:
    """The statements with the names that `loads` (and `arith`, with `own_arith`) define
    tagged."""
    defining = loads + arith if own_arith else loads
    names = {m.group(1) for stmt in defining
             for m in [re.match(r"([A-Za-z_]\w*)\{b\} = ", stmt)] if m}
    if not names:
        return loads, arith, stores
    pattern = re.compile(r"\b(" + "|".join(sorted(names, key=len, reverse=True)) + r")\{b\}")

    def own(stmt: str) -> str:
        return pattern.sub(lambda m: f"{m.group(1)}{tag}{{b}}", stmt)

    return [own(s) for s in loads], [own(s) for s in arith], [own(s) for s in stores]


def _lane_stmt(stmt: str, b: int, lane: str) -> str:
    """One lane of a statement: temporaries (`X{b}`) get the lane's number, indices its
    position (`x[i, {b}]`)."""
    return re.sub(r"\[([^\[\]]*)\{b\}\]", lambda m: f"[{m.group(1)}{lane}]",
                  stmt).replace("{b}", str(b))


def emit_stage_loop(c: _Code, feat: Features, tab: Tableau, width: LaneLayout,
                    prelude: Callable[[int], None],
                    after: Callable[[], None] | None = None,
                    nodes: tuple | None = None, parallel: bool = False,
                    per_run: tuple[str, ...] = ()) -> None:
    """The stages of one step as a loop whose body holds the force code once (a call per
    stage passes ~20 array arguments; the force code written out per stage compiles far
    slower: docs/performance.md#the-shared-kernels-shape). `prelude(s)` writes stage s's own
    code (its state xs, vs, its input); the force code then reads xa, va and writes ka
    (with `uniform_stages`, `prelude(None)` writes every stage after the first at once, from
    the tables of `emit_nystrom_coefficients`); `after()`, when given, writes what follows
    every stage's forces, once (it reads the stage
    s_ through xa, va and the stage weights `hbd_`, `emit_stage_weights`; stages of weight
    zero skip it); `nodes` (`terms.node_terms`), when given, has the linear, input and
    quadratic-coupling forces written out per node;
    `parallel`: the force code's node loop is a `prange` (`emit_linear`); `per_run`: the
    coefficient arrays read per lane (`KernelOptions.per_run`)."""
    uniform = uniform_stages(tab)
    if uniform:
        c(f"kvs_ = ({', '.join(f'kv{s}' for s in range(tab.stages))},)")
    c("for s_ in range(STAGES):")
    c.indent()
    for s in ([0, None] if uniform else range(tab.stages)):
        if s is None:
            c("else:  # every later stage, its coefficients from the tables")
        else:
            c(f"{'if' if s == 0 else 'elif'} s_ == {s}:  # c = {tab.c[s]!r}")
        c.indent()
        prelude(s)
        c("xa = x" if s == 0 else "xa = xs")
        c(f"va = {nystrom_velocity(s)}")
        c("ka = kv0" if s == 0 else "ka = kvs_[s_]" if s is None else f"ka = kv{s}")
        c.dedent()
    c("grow = g[step, s_]" if feat.common_forces else "grow = g[0, 0]")
    emit_accel_body(c, feat, width, nodes, parallel, per_run)
    if after is not None:
        # once, not once per stage: a copy per stage compiled about 1 s slower per sum
        # (docs/performance.md#cold-cache-compiles-in-mass-spring-training)
        c("if hbd_[s_] != 0.0:")
        c.indent()
        after()
        c.dedent()
    c.dedent()


def emit_accel_body(c: _Code, feat: Features, width: LaneLayout,
                    nodes: tuple | None = None, parallel: bool = False,
                    per_run: tuple[str, ...] = ()) -> None:
    """The force code: ka = M^-1 F(xa, va, uc, grow), from the term descriptions of
    `springc.kernels.terms`: with `nodes` (`terms.node_terms`) one sum per node, else the
    linear rows and then a loop per element kind (`parallel`: each node gathers its
    elements' ends instead, in the loops' order); monomials loop in all. `per_run`: the
    coefficient arrays read per lane (not with `parallel`)."""
    lane = frozenset(per_run)
    if nodes is not None:
        emit_nodes(c, nodes, width, lane)
    elif parallel:
        assert not lane, "per-run coefficients are not written for split nodes"
        emit_linear(c, feat, width, parallel=True)
    else:
        emit_linear(c, feat, width, per_run=lane)
        for kind in terms.LOOP_ORDER:
            if getattr(feat, kind.feature):
                _emit_kind(c, width, kind, lane)
    if feat.monomials:
        emit_monomials(c, width, lane)
    if feat.common_forces and nodes is None:
        _emit_kind(c, width, terms.COMMON, lane)
    if feat.thermal:
        thermal.emit_add(c)


def _emit_kind(c: _Code, width: LaneLayout, kind: terms.Kind,
               per_run: frozenset[str] = frozenset()) -> None:
    """The loop over the elements of `kind` (`terms.element_loop`), with a branch for a
    second end at the ground where the kind has one. Each element's lanes are straight-line
    code, its rows indexed in place (a row view would cost a reference-count update per
    element)."""
    c(f"for e in range({kind.node_i}.shape[0]):")
    c.indent()
    if kind.ground is None:
        _emit_element(c, width, terms.element_loop(kind, per_run=per_run))
    else:
        c(f"j = {kind.node_j}[e]")
        c("if j < 0:  # to ground")
        c.indent()
        _emit_element(c, width, terms.element_loop(kind, ground=True, per_run=per_run))
        c.dedent()
        c("else:")
        c.indent()
        _emit_element(c, width, terms.element_loop(kind, per_run=per_run))
        c.dedent()
    c.dedent()


def _emit_element(c: _Code, width: LaneLayout, code: terms.LoopCode) -> None:
    for line in code.head:
        c(line)
    lanes(c, width, code.loads, code.arith, code.stores)


def emit_nodes(c: _Code, nodes: tuple, width: LaneLayout,
               per_run: frozenset[str] = frozenset()) -> None:
    """The force code written out node by node (`terms.node_sum`): the node's coefficients
    read into scalars, then one lane loop ka[i] = its terms, with every row index a
    constant (faster than the shared kernel's loops over index arrays for small networks).
    The scalars are read before the loop so that the loop reads no coefficient array (LLVM
    cannot prove they do not alias ka, and each one added a runtime alias check). A node
    without any force keeps its rows of zeros. Coefficients of `per_run` arrays are read in
    the lane loop, each lane its own."""
    for i, node in enumerate(nodes):
        if not (node.damped or node.sprung or node.row or node.ins or node.ends
                or node.looped):
            continue  # its force rows stay zero
        for line in terms.scalar_loads(i, node, per_run):
            c(line)
        expr = terms.node_sum(i, node, lambda j: f"xa[{j}, b]", lambda j: f"va[{j}, b]",
                              lambda ch: f"uc[{ch}, b]", lambda e: f"grow[{e}]")
        c(f"for b in range({width.width}):")
        for line in terms.scalar_loads(i, node, per_run, "b"):
            c(f"    {line}")
        c(f"    ka[{i}, b] = {expr}")


def node_loop(parallel: bool) -> str:
    """The header of a loop over the nodes: split over numba's threads with `parallel`."""
    return "for i in nb.prange(n):" if parallel else "for i in range(n):"


def emit_linear(c: _Code, feat: Features, width: LaneLayout, parallel: bool = False,
                per_run: frozenset[str] = frozenset(), loop: str | None = None,
                store: list[str] | None = None, rows: terms.Rows = terms.ROWS) -> None:
    """Per node, all lanes in registers and one store: ka = -(bm v + km x), plus (with
    couplings) the node's off-diagonal stiffness row (`marshal.linear_rows`) and (with
    inputs) its input forces (`fi_ptr`: the node's range of the node-ordered inputs). Pushing
    each element into both ends' rows costs a load and a store per end, and the kernel is
    bound by that memory traffic. All lanes at once (no group loop): the FMAs into
    one accumulator are a chain, and only the lanes' independent chains keep the FMA units
    busy. `parallel`: the loop is a `prange`, and each node then adds its ends of the
    element kinds (`_emit_gathers`) before its one store. `per_run`: the coefficient
    arrays read per lane (`_emit_linear_lanes`). `loop`: the header of the loop over the
    nodes, where a form has its own (the CUDA split form's threads' shares); `store`: the
    lane statements that take the node's sum A{b} (default: into ka), where a form does more
    with it (the CUDA split form's last stage combines the step there); `rows`: the stage's
    arrays (`terms.Rows`)."""
    full = dataclasses.replace(width, group=width.width)
    c(loop or node_loop(parallel))
    c.indent()
    if per_run & {"bm", "km", "l_val", "fi_gm"}:
        _emit_linear_lanes(c, feat, full, per_run)
        c.dedent()
        return
    c("bi = bm[i]")
    c("ki = km[i]")
    # an undamped node's force reads no velocity (its stage velocity is not even computed,
    # `nystrom_stage_state`)
    c("if bi != 0.0:")
    c.indent()
    own = terms.own_sum(True, True, "bi", "ki", "V{b}", "X{b}")
    xload = f"X{{b}} = {rows.x}[i, {{b}}]"
    lanes(c, full, [f"V{{b}} = {rows.v}[i, {{b}}]", xload], [f"A{{b}} = {own}"], [])
    c.dedent()
    c("else:")
    c.indent()
    own = terms.own_sum(False, True, "bi", "ki", "V{b}", "X{b}")
    lanes(c, full, [xload], [f"A{{b}} = {own}"], [])
    c.dedent()
    if feat.couplings:
        _gather(c, full, "l_ptr", ("j = l_col[e]", "w = l_val[e]"), f"{rows.x}[j, {{b}}]",
                terms.ROW.format(w="w", xj="Y{b}"))
    if feat.in_forces:
        _gather(c, full, "fi_ptr", ("ch = fi_chan[e]", "gm = fi_gm[e]"), "uc[ch, {b}]",
                terms.INPUT.format(gm="gm", u="Y{b}"))
    if parallel:
        _emit_gathers(c, feat, full, rows)
    lanes(c, full, [], [], store or [f"{rows.k}[i, {{b}}] = A{{b}}"])
    c.dedent()


def _emit_linear_lanes(c: _Code, feat: Features, full: LaneLayout,
                       per_run: frozenset[str]) -> None:
    """Node i's linear and input terms (`emit_linear`) with the `per_run` arrays' coefficients
    read per lane. A per-run damping is always read (a run of another point may be damped
    where this one is not: b/m = 0 then adds nothing)."""
    def coef(array: str, entry: str, name: str) -> tuple[list[str], str]:
        if array in per_run:
            return [f"{name}{{b}} = {terms.lane_array(array)}[{entry}, {{b}}]"], f"{name}{{b}}"
        c(f"{name} = {array}[{entry}]")
        return [], name

    bload, bname = coef("bm", "i", "BI")
    kload, kname = coef("km", "i", "KI")
    loads = kload + ["X{b} = xa[i, {b}]"]
    if "bm" in per_run:
        own = terms.own_sum(True, True, bname, kname, "V{b}", "X{b}")
        lanes(c, full, bload + ["V{b} = va[i, {b}]"] + loads, [f"A{{b}} = {own}"], [])
    else:
        c(f"if {bname} != 0.0:")
        own = terms.own_sum(True, True, bname, kname, "V{b}", "X{b}")
        c.indent()
        lanes(c, full, ["V{b} = va[i, {b}]"] + loads, [f"A{{b}} = {own}"], [])
        c.dedent()
        c("else:")
        c.indent()
        own = terms.own_sum(False, True, bname, kname, "V{b}", "X{b}")
        lanes(c, full, loads, [f"A{{b}} = {own}"], [])
        c.dedent()
    for on, ptr, head, array, row, term in (
            (feat.couplings, "l_ptr", "j = l_col[e]", "l_val", "xa[j, {b}]", terms.ROW),
            (feat.in_forces, "fi_ptr", "ch = fi_chan[e]", "fi_gm", "uc[ch, {b}]",
             terms.INPUT)):
        if not on:
            continue
        c(f"for e in range({ptr}[i], {ptr}[i + 1]):")
        c.indent()
        c(head)
        wload, wname = coef(array, "e", "W")
        text = term.format(w=wname, xj="Y{b}", gm=wname, u="Y{b}")
        lanes(c, full, wload + [f"Y{{b}} = {row}"], [f"A{{b}} = A{{b}} {text}"], [])
        c.dedent()
    lanes(c, full, [], [], ["ka[i, {b}] = A{b}"])


def _emit_gathers(c: _Code, feat: Features, full: LaneLayout,
                  rows: terms.Rows = terms.ROWS) -> None:
    """Node i's ends of every element kind (`terms.node_ends`), kind by kind in
    `terms.LOOP_ORDER` and element by element, added to its accumulator: the additions
    the element loops make to ka[i], in their order, so the sums round alike."""
    for kind in terms.LOOP_ORDER:
        if not getattr(feat, kind.feature):
            continue
        names = terms.gather_args(kind)
        c(f"for k_ in range({names[0]}[i], {names[0]}[i + 1]):")
        c.indent()
        c(f"e = {names[1]}[k_]")
        if kind.node_j is None:
            _emit_element(c, full, terms.gather_end(kind, "i", rows=rows))
            c.dedent()
            continue
        c(f"o = {names[2]}[k_]")
        c(f"if {names[3]}[k_] == 0:")
        c.indent()
        if kind.ground is not None:
            c("if o < 0:  # to ground")
            c.indent()
            _emit_element(c, full, terms.gather_end(kind, "i", ground=True, rows=rows))
            c.dedent()
            c("else:")
            c.indent()
            _emit_element(c, full, terms.gather_end(kind, "i", rows=rows))
            c.dedent()
        else:
            _emit_element(c, full, terms.gather_end(kind, "i", rows=rows))
        c.dedent()
        c("else:")
        c.indent()
        _emit_element(c, full, terms.gather_end(kind, "j", rows=rows))
        c.dedent(2)


def _gather(c: _Code, full: LaneLayout, ptr: str, head: tuple[str, ...], row: str,
            term: str) -> None:
    """A{b} = A{b} + term over node i's entries `ptr[i]..ptr[i + 1]` (`head` sets the
    entry's scalars; `row` is the row read into Y{b}, `{b}` its lane)."""
    c(f"for e in range({ptr}[i], {ptr}[i + 1]):")
    c.indent()
    for line in head:
        c(line)
    lanes(c, full, [f"Y{{b}} = {row}"], [f"A{{b}} = A{{b}} {term}"], [])
    c.dedent()


def emit_monomials(c: _Code, width: LaneLayout, per_run: frozenset[str] = frozenset(),
                   rows: terms.Rows = terms.ROWS) -> None:
    """The monomials' loop: each factor's partial derivative, summed over the factors (the
    product rule, so repeated variables need no special case); rare and irregular, a plain
    loop over the lanes (none where the form holds one run)."""
    lane = bool(per_run & {"p_c", "minv"})
    pc = f"{terms.lane_array('p_c')}[e, b]" if "p_c" in per_run else "p_c[e]"
    mi = f"{terms.lane_array('minv')}[i, b]" if "minv" in per_run else "minv[i]"
    at = (lambda stmt: one_run(stmt, "")) if width.one_run else in_lanes
    c("for e in range(p_c.shape[0]):")
    c.indent()
    c("lo = p_ptr[e]")
    c("hi = p_ptr[e + 1]")
    c("for kf in range(lo, hi):")
    c.indent()
    c("i = p_var[kf]")
    c("ex = p_exp[kf]")
    if not lane:
        c(f"cm = {pc} * ex * {mi}")
    if not width.one_run:
        c(f"for b in range({width.width}):")
        c.indent()
    if lane:  # each lane its own point's coefficient
        c(f"cm = {pc} * ex * {mi}")
    c(at(f"term = cm * {rows.x}[i, {{b}}] ** (ex - 1)"))
    c("for ko in range(lo, hi):")
    c.indent()
    c("if ko != kf:")
    c(at(f"    term *= {rows.x}[p_var[ko], {{b}}] ** p_exp[ko]"))
    c.dedent()
    c(at(f"{rows.k}[i, {{b}}] -= term"))
    c.dedent(2 if width.one_run else 3)


def _emit_run(c: _Code, feat: Features, opts: KernelOptions, tab: Tableau) -> None:
    ln = lane_layout(opts)
    emit_run_head(c, feat, opts, tab)
    velocity_needed(c, feat, opts)
    c("for ci in range(c0, c1):")
    c.indent()
    emit_chunk_start(c, opts, ["xs", "vs"] + [f"kv{s}" for s in range(tab.stages)])
    if feat.thermal:
        thermal.emit_chunk_init(c)
    c("for step in range(nsteps):")
    c.indent()
    emit_step_start(c, feat.in_forces)
    if feat.thermal:
        thermal.emit_draw(c, opts.per_run)

    def prelude(s: int | None) -> None:
        if s != 0:
            nystrom_stage_state(c, tab, s, ln, parallel=opts.parallel)
        if feat.in_forces:
            emit_stage_input(c, tab, s, ln)

    def after() -> None:
        emit_stage_reductions(c, feat, opts)

    emit_stage_loop(c, feat, tab, ln, prelude, after if opts.work or opts.dissipation else None,
                    opts.nodes, opts.parallel, opts.per_run)
    nystrom_combine(c, tab, ln, parallel=opts.parallel)
    emit_step_end(c, opts, ln)
    c.dedent()
    emit_chunk_end(c, opts)
    c.dedent(2)


def emit_run_head(c: _Code, feat: Features, opts: KernelOptions, tab: Tableau) -> None:
    """The kernel function's decorator, signature and docstring, then its h-scaled
    coefficients (the body follows, indented)."""
    emit_def(c, run_args(feat, opts), "nsteps steps of h", aligned_frame(opts), opts.parallel,
             opts.fma)
    emit_coefficients(c, tab)
    emit_nystrom_coefficients(c, tab)
    if opts.work or opts.dissipation:
        emit_stage_weights(c, tab)


def aligned_frame(opts: KernelOptions) -> bool:
    """Whether the kernel aligns its stack frame (`springc.kernels.stackalign`): register kernels
    for lanes, whose lane loop spills hundreds of vectors a step. The others spill few, and the
    realignment costs them a register (see
    docs/performance.md#the-float32-row-and-the-stack-frame)."""
    return bool(opts.registers) and opts.lanes > 1


def emit_def(c: _Code, args: list[str], steps: str, align: bool = False,
             parallel: bool = False, fma: bool = True) -> None:
    """The kernel function's decorator, signature and docstring (integrating for `steps`),
    and with `align`, the alignment of its frame; `parallel`: numba's parallel=True, for
    the node loops' `prange`."""
    # Serial and nogil: the runtime runs chunks on threads (numba's parallel=True over the
    # chunks was no faster and compiles several times slower:
    # docs/performance.md#measured-and-not-taken); over the nodes it serves a single run.
    c(decorator(parallel, fma))
    c(f"def run({', '.join(args)}):")
    c.indent()
    c(f'"""Integrate chunks c0..c1-1 of LANES runs (columns of x0) for {steps}."""')
    if align:
        c("align_stack()")


def emit_chunk_start(c: _Code, opts: KernelOptions, scratch: list[str]) -> None:
    """Chunk setup inside `for ci in ...`: valid lanes `nv_`, state x, v and `scratch` rows,
    input staging buffer, reductions, the initial record. Padding lanes (beyond the runs) start
    from the chunk's first run with zero input and are never stored."""
    c("n, runs = x0.shape")
    c("nch = u.shape[1]")
    c("lo_ = ci * LANES")
    c("nv_ = min(runs, lo_ + LANES) - lo_")
    c("nb_ = LANES")
    for name in ["x", "v"] + scratch:
        c(f"{name} = np.zeros((n, LANES), FT)")
    emit_lane_coefficients(c, opts.per_run)
    c("uc = np.zeros((max(nch, 1), LANES), FT)")
    c("ustg = np.zeros((STAGE_BLOCK + 2, max(nch, 1), LANES), FT)")
    c("ubase = -2 * STAGE_BLOCK")
    c("load_lanes(x, x0, lo_, nv_)")  # springc.kernels.chunk
    c("load_lanes(v, v0, lo_, nv_)")
    _emit_reduction_init(c, opts)
    if opts.record:
        # the streaming stores fault on a misaligned address: refuse such a buffer instead
        c(f"if rec.ctypes.data % {RECORD_ALIGN} or (rec.shape[2] * rec.itemsize) % {RECORD_ALIGN}:")
        c(f"    raise ValueError('rec must be {RECORD_ALIGN}-byte aligned with rows padded to "
          f"{RECORD_ALIGN} bytes')")
        c("stg = np.zeros((max(rec_node.shape[0], 1), RB, LANES), FT)")
        c("r_hi = -1")
        emit_record(c, "0", lane_layout(opts), record_block(opts.precision))
    # counters, not step % substeps and friends: a 64-bit division costs tens of cycles, and
    # four a step were 40% of a one-dof kernel's time
    c("sub = substeps - 1")
    c("k0 = -1")
    c("rc_ = 0")
    c("rn_ = 0")
    c("cc_ = 0")


def emit_lane_coefficients(c: _Code, per_run: tuple[str, ...]) -> None:
    """The chunk's columns of each per-run coefficient array (`KernelOptions.per_run`) into
    its `terms.lane_array`, (entries, LANES): padding lanes take the chunk's last run's."""
    for name in per_run:
        local = terms.lane_array(name)
        if name.startswith("lw"):
            _emit_lane_propagators(c, name, local)
            continue
        c(f"{local} = np.empty(({name}.shape[0], LANES), {name}.dtype)")
        c(f"load_lanes({local}, {name}, lo_, nv_)")


def _emit_lane_propagators(c: _Code, name: str, local: str) -> None:
    """A Lawson kernel's per-run propagator array (blocks, fractions, rows, columns, runs),
    `springc.kernels.expint`, into its chunk copy with LANES columns, flat (the kernel reads
    it with one index): `load_lanes` on both seen as (entries, columns)."""
    c(f"{local} = np.empty({name}.size // {name}.shape[4] * LANES, {name}.dtype)")
    c(f"load_lanes({local}.reshape((-1, LANES)), {name}.reshape((-1, {name}.shape[4])), "
      "lo_, nv_)")


def emit_step_start(c: _Code, inputs: bool) -> None:
    """Step counters; with `inputs`, restage the input samples when the step leaves the
    staged block."""
    c("sub += 1")
    c("if sub == substeps:")
    c("    sub = 0")
    c("    k0 += 1")
    if not inputs:
        return
    c("if k0 >= ubase + STAGE_BLOCK:")
    c("    ubase = k0")
    c("    restage(ustg, u, lo_, nv_, ubase)")  # springc.kernels.chunk


def emit_stage_input(c: _Code, tab: Tableau, s: int | None, width: LaneLayout) -> None:
    """The input at stage s's time into uc: linear interpolation of the input samples (grid
    step h * substeps); a stage at the same time as the previous one reuses it. Stage None:
    the stage s_ of `uniform_stages`."""
    if s is None:
        c("if cs_[s_] != cs_[s_ - 1]:")
        c.indent()
        emit_interp(c, "uc", "(sub + cs_[s_]) / substeps", width)
        c.dedent()
    elif s == 0 or tab.c[s] != tab.c[s - 1]:
        emit_interp(c, "uc", f"(sub + {tab.c[s]!r}) / substeps", width)


def emit_interp(c: _Code, target: str, pos: str, width: LaneLayout, channels: str = "nch") -> None:
    """Linear interpolation of the staged input at input-grid position k0 + `pos` into the
    first `channels` rows of `target`."""
    for line in interp_weights(pos, "k0 + {i} - ubase"):
        c(line)
    c(f"for ch in range({channels}):")
    c.indent()
    lanes(c, width, ["A{b} = ustg[kk, ch, {b}]", "B{b} = ustg[kk + 1, ch, {b}]"], [],
          [f"{target}[ch, {{b}}] = gr * A{{b}} + fr * B{{b}}"])
    c.dedent()


def interp_weights(pos: str, sample: str, suffix: str = "") -> list[str]:
    """The statements of a linear interpolation on the input grid at position `pos` (in
    samples): the sample before it, kk (`sample` with `{i}` standing for the position's
    whole part), and the weights of the samples after (fr) and before it (gr); each name
    with `suffix`."""
    p = f"pos{suffix}"
    return [f"{p} = {pos}", f"kk{suffix} = " + sample.replace("{i}", f"int({p})"),
            f"fr{suffix} = FT({p} - int({p}))", f"gr{suffix} = FT(1.0) - fr{suffix}"]


def emit_chunk_end(c: _Code, opts: KernelOptions) -> None:
    """Store the final state and the reductions of the valid lanes; fence the record's
    streaming stores."""
    c("store_lanes(xf, x, lo_, nv_)")  # springc.kernels.chunk
    c("store_lanes(vf, v, lo_, nv_)")
    _emit_reduction_store(c, opts)
    if opts.record:
        emit_record_tail(c)
        c("store_fence()")


def emit_coefficients(c: _Code, tab: Tableau) -> None:
    """h-scaled tableau coefficients as typed constants (keeps float32 kernels in float32)."""
    for s, row in enumerate(tab.a):
        for j, a in enumerate(row):
            if a != 0.0:
                c(f"ha{s}_{j} = FT(h * {a!r})")
    for s, b in enumerate(tab.b):
        if b != 0.0:
            c(f"hb{s} = FT(h * {b!r})")
            c(f"hbd{s} = h * {b!r}")


def emit_stage_weights(c: _Code, tab: Tableau) -> None:
    """`hbd_`: h b_s of every stage in float64 (zeros too), indexed by the stage loop's s_
    for the work and dissipation sums (`emit_stage_reductions`)."""
    c(f"hbd_ = ({', '.join(f'h * {b!r}' for b in tab.b)},)")


def nystrom_coefficients(tab: Tableau) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """The tableau for x' = v, v' = f with the velocity stages substituted (Runge-Kutta-Nystrom
    form): X_s = x + h c_s v + h^2 sum_k (A A)_sk K_k, x_new = x + h (sum b) v + h^2
    sum_k (b A)_k K_k. Returns (c_s as A's row sums, A A, b A, sum b)."""
    n = tab.stages
    a = np.zeros((n, n))
    for s, row in enumerate(tab.a):
        a[s, :len(row)] = row
    b = np.asarray(tab.b, dtype=float)
    return np.array([math.fsum(row) for row in a]), a @ a, b @ a, math.fsum(tab.b)


def emit_nystrom_coefficients(c: _Code, tab: Tableau) -> None:
    """`emit_nystrom_constants`, and the stage tables where the stages are uniform."""
    emit_nystrom_constants(c, tab)
    if uniform_stages(tab):
        emit_stage_tables(c, tab)


def emit_nystrom_constants(c: _Code, tab: Tableau) -> None:
    """h- and h^2-scaled constants of `nystrom_coefficients` (typed like the state)."""
    cs, aa, ba, bsum = nystrom_coefficients(tab)
    for s in range(1, tab.stages):
        c(f"hc{s} = FT(h * {float(cs[s])!r})")
        for k in np.flatnonzero(aa[s]):
            c(f"hh{s}_{k} = FT(h * h * {float(aa[s, k])!r})")
    c(f"hbs = FT(h * {bsum!r})")
    for k in np.flatnonzero(ba):
        c(f"hhb{k} = FT(h * h * {float(ba[k])!r})")


def uniform_stages(tab: Tableau) -> bool:
    """Whether every stage after the first reads one force stage for its velocity and at
    most one for its position (RK4, heun3): their state updates are then one code that reads
    the stage's coefficients and force arrays from tuples indexed by s_ (`emit_stage_tables`).
    A copy per stage made the keyword-spotting features kernel compile 40% slower
    (docs/performance.md#cold-cache-compiles-in-mass-spring-training)."""
    reads = [stage_reads(tab, s) for s in range(1, tab.stages)]
    return tab.stages >= 3 and all(len(row) == 1 and len(sq) <= 1 for row, sq in reads)


def emit_stage_tables(c: _Code, tab: Tableau) -> None:
    """Per stage (index s_; stage 0's entries unused): the force stage its velocity reads
    (`jv_`) and its position reads (`jx_`, with coefficient 0 where it reads none), their
    h-scaled coefficients `hv_`, `hx_`, `hc_` (as `emit_nystrom_coefficients` names them) and
    the stage times `cs_`."""
    jv, jx, hv, hx = [0], [0], ["FT(0.0)"], ["FT(0.0)"]
    for s in range(1, tab.stages):
        row, sq = stage_reads(tab, s)
        jv.append(row[0])
        hv.append(f"ha{s}_{row[0]}")
        jx.append(sq[0] if sq else row[0])
        hx.append(f"hh{s}_{sq[0]}" if sq else "FT(0.0)")
    c(f"jv_ = ({', '.join(map(str, jv))},)")
    c(f"jx_ = ({', '.join(map(str, jx))},)")
    c(f"hv_ = ({', '.join(hv)},)")
    c(f"hx_ = ({', '.join(hx)},)")
    c(f"hc_ = (FT(0.0), {', '.join(f'hc{s}' for s in range(1, tab.stages))},)")
    c(f"cs_ = ({', '.join(repr(float(t)) for t in tab.c)},)")


def nystrom_velocity(s: int) -> str:
    return "v" if s == 0 else "vs"


def stage_reads(tab: Tableau, s: int) -> tuple[list[int], list[int]]:
    """The force stages stage s's velocity and position read (nonzero a_sj, (A A)_sk)."""
    _, aa, _, _ = nystrom_coefficients(tab)
    return [j for j, a in enumerate(tab.a[s]) if a != 0.0], [int(k) for k in np.flatnonzero(aa[s])]


def stage_terms(tab: Tableau, s: int, v: str, k: Callable[[int], str]) -> tuple[str, str]:
    """Stage s's increments over the step's state: (h c_s v + h^2 sum_k (A A)_sk K_k,
    h sum_j a_sj K_j), with `v` the velocity and `k(j)` stage j's force as each kernel
    form names them (the coefficients `emit_nystrom_coefficients` defines)."""
    row, sq = stage_reads(tab, s)
    xterm = " + ".join([f"hc{s} * {v}"] + [f"hh{s}_{j} * {k(j)}" for j in sq])
    return xterm, " + ".join(f"ha{s}_{j} * {k(j)}" for j in row) or "FT(0.0)"


def combine_reads(tab: Tableau) -> tuple[list[int], list[int]]:
    """The force stages the step's velocity and position updates read."""
    _, _, ba, _ = nystrom_coefficients(tab)
    return [s for s, b in enumerate(tab.b) if b != 0.0], [int(k) for k in np.flatnonzero(ba)]


def combine_terms(tab: Tableau, v: str, k: Callable[[int], str]) -> tuple[str, str]:
    """The step's increments: (h (sum b) v + h^2 sum_k (b A)_k K_k, h sum_s b_s K_s), named
    as `stage_terms`."""
    used, sq = combine_reads(tab)
    xterm = " + ".join([f"hbs * {v}"] + [f"hhb{j} * {k(j)}" for j in sq])
    return xterm, " + ".join(f"hb{s} * {k(s)}" for s in used)


def nystrom_stage_state(c: _Code, tab: Tableau, s: int | None, width: LaneLayout,
                        frozen: str | None = None, parallel: bool = False) -> None:
    """xs = x + h c_s v + h^2 sum_k (A A)_sk kv_k and vs = v + h sum_j a_sj kv_j, row by row:
    the stage state from the force stages alone, so that the combine reads no stage
    velocities and one vs row serves every stage (8 state rows instead of 10 for RK4, three
    fewer reads per step). Rows flagged in `frz` (the exactly propagated blocks of
    `springc.kernels.expint`) are left to the block code with `frozen` 'skip', and keep xs = x
    (their velocity kicked) with 'hold'. `parallel`: the rows split over threads. Stage s
    None: the stage s_ of `uniform_stages` (its force arrays `kvv_`, `kvx_`)."""
    loads = ["X{b} = x[i, {b}]", "V{b} = v[i, {b}]"]
    if s is None:
        c("kvv_ = kvs_[jv_[s_]]")
        c("kvx_ = kvs_[jx_[s_]]")
        c("hvs_ = hv_[s_]")
        c("hxs_ = hx_[s_]")
        c("hcs_ = hc_[s_]")
        xterm, vterm = "hcs_ * V{b} + hxs_ * KX_{b}", "hvs_ * KV_{b}"
        xloads = loads + ["KX_{b} = kvx_[i, {b}]"]
        loads = xloads + ["KV_{b} = kvv_[i, {b}]"]
    else:
        row, sq = stage_reads(tab, s)
        xterm, vterm = stage_terms(tab, s, "V{b}", lambda k: f"K{k}_{{b}}")
        xloads = loads + [f"K{k}_{{b}} = kv{k}[i, {{b}}]" for k in sq]
        loads += [f"K{k}_{{b}} = kv{k}[i, {{b}}]" for k in sorted(set(row) | set(sq))]
    c(node_loop(parallel))
    c.indent()
    if frozen:
        c("if frz[i]:")
        c.indent()
        if frozen == "hold":
            lanes(c, width, loads, [], [f"vs[i, {{b}}] = V{{b}} + {vterm}", "xs[i, {b}] = X{b}"])
        c("continue")
        c.dedent()
    c("if vneed[i]:")
    c.indent()
    lanes(c, width, loads, [], [f"xs[i, {{b}}] = X{{b}} + ({xterm})",
                                f"vs[i, {{b}}] = V{{b}} + {vterm}"])
    c.dedent()
    c("else:")
    c.indent()
    lanes(c, width, xloads, [], [f"xs[i, {{b}}] = X{{b}} + ({xterm})"])
    c.dedent(2)


def velocity_needed(c: _Code, feat: Features, opts: KernelOptions) -> None:
    """vneed[i]: whether anything reads node i's stage velocity: its own damping, a dashpot
    on it, or (with the work reduction) a force on it. (The dissipation reduction reads the
    dampers' nodes, already among these.) Most nodes of a delay line or the keyword-spotting
    network are undamped: their stage velocity rows, a read and a write per stage, are
    skipped."""
    c("vneed = np.zeros(x0.shape[0], np.bool_)")
    c("for i in range(x0.shape[0]):")
    if "bm" in opts.per_run:  # damped in any run of the call
        c("    for r_ in range(bm.shape[1]):")
        c("        vneed[i] = vneed[i] or bm[i, r_] != 0.0")
    else:
        c("    vneed[i] = bm[i] != 0.0")
    ends = [index for kind in terms.KINDS if getattr(feat, kind.feature)
            and kind.reads_velocity() for index in (kind.node_i, kind.node_j) if index]
    ends += (["fi_node"] if opts.work and feat.in_forces else [])
    ends += (["fc_node"] if opts.work and feat.common_forces else [])
    for index in ends:
        c(f"mark_nodes(vneed, {index})")  # springc.kernels.chunk; -1: the ground


def nystrom_combine(c: _Code, tab: Tableau, width: LaneLayout, frozen: str | None = None,
                    parallel: bool = False) -> None:
    """x += h (sum b) v + h^2 sum_k (b A)_k kv_k; v += h sum_s b_s kv_s. Rows flagged in
    `frz` take xn, vn (their exact flow) with `frozen` 'exact', and keep x (their velocity
    kicked) with 'hold'. `parallel`: the rows split over threads."""
    loads = ["X{b} = x[i, {b}]", "V{b} = v[i, {b}]"]
    loads += [f"K{k}_{{b}} = kv{k}[i, {{b}}]" for k in sorted(set().union(*combine_reads(tab)))]
    xterm, vterm = combine_terms(tab, "V{b}", lambda k: f"K{k}_{{b}}")
    c(node_loop(parallel))
    c.indent()
    if frozen:
        c("if frz[i]:")
        c.indent()
        if frozen == "exact":
            lanes(c, width, ["A{b} = xn[i, {b}]", "B{b} = vn[i, {b}]"], [],
                  ["x[i, {b}] = A{b}", "v[i, {b}] = B{b}"])
        else:
            lanes(c, width, loads, [], [f"v[i, {{b}}] = V{{b}} + ({vterm})"])
        c("continue")
        c.dedent()
    lanes(c, width, loads, [], [f"x[i, {{b}}] = X{{b}} + ({xterm})",
                                f"v[i, {{b}}] = V{{b}} + ({vterm})"])
    c.dedent()


def emit_stage_reductions(c: _Code, feat: Features, opts: KernelOptions,
                          gains: str | None = None) -> None:
    """Quadrature of power over the step with the tableau weights (consistent with RK): stage
    s_'s share, its weight `hbd_[s_]` (`emit_stage_weights`), its velocity va. The
    force on a node is its acceleration times its mass: `fi_gm` holds gain / mass. `gains`:
    an array of the input forces' own gains to use instead (a split kernel's Runge-Kutta part
    has its blocks' inputs at gain 0). An array with a column per run
    (`KernelOptions.per_run`) is read per lane, inside the lane loop."""
    per, read = opts.per_run, _lane_reader(opts.per_run)
    if opts.work and feat.in_forces:
        arrays = (gains,) if gains else ("fi_gm", "minv")
        gain = read(gains, "e") if gains else \
            f"{read('fi_gm', 'e')} / {read('minv', 'fi_node[e]')}"
        _emit_lane_sum(c, "fi_node", f"hbd_[s_] * {gain}", "fw", set(arrays) & set(per),
                       in_lanes(work_in_update("va")))
    if opts.work and feat.common_forces:
        gain = f"{read('fc_gm', 'e')} / {read('minv', 'fc_node[e]')} * g[step, s_, e]"
        _emit_lane_sum(c, "fc_node", gain, "fv", {"fc_gm", "minv"} & set(per),
                       in_lanes(work_common_update("va", "hbd_[s_]")))
    if opts.dissipation:
        c("for d in range(ds_i.shape[0]):")
        c("    i = ds_i[d]")
        c("    j = ds_j[d]")
        c("    for b in range(nb_):")
        for stmt in damper_update("va", "hbd_[s_]", read("ds_b", "d")):
            c("        " + in_lanes(stmt))


# The reductions' updates, each written once as lane statements (`{b}`: the lane) that every
# form renders: inside its loop over the lanes (`in_lanes`) or for one run (`one_run`).
def in_lanes(stmt: str) -> str:
    """A lane statement inside a loop over the lanes, `for b in ...`."""
    return stmt.replace("{b}", "b")


def work_in_update(va: str) -> str:
    """Input force e's work over a stage: its stage weight times its gain (`fw`) times the
    input times its node's stage velocity (`va`)."""
    return f"w_in[e, {{b}}] += fw * uc[fi_chan[e], {{b}}] * {va}[fi_node[e], {{b}}]"


def work_common_update(va: str, weight: str) -> str:
    """Shared-signal force e's work over a stage: the stage's `weight` times its force `fv`
    times its node's stage velocity."""
    return f"w_c[e, {{b}}] += {weight} * fv * {va}[fc_node[e], {{b}}]"


def damper_update(va: str, weight: str, coef: str) -> list[str]:
    """Damper row d's (nodes i, j; j < 0: the ground) dissipation over a stage: the stage's
    `weight` times its coefficient `coef` times the square of the velocity across it."""
    return [f"dv = {va}[i, {{b}}] - ({va}[j, {{b}}] if j >= 0 else 0.0)",
            f"dsacc[d, {{b}}] += {weight} * {coef} * dv * dv"]


def msq_update() -> list[str]:
    """Mean-square row m's sum after a step: its node's position or velocity, squared."""
    return ["q = v[ms_node[m], {b}] if ms_isv[m] else x[ms_node[m], {b}]",
            "msacc[m, {b}] += q * q"]


def _lane_reader(per_run: tuple[str, ...]) -> Callable[[str, str], str]:
    """`read(array, index)`: the element's expression, per lane (`[index, b]` of its
    `terms.lane_array`) where the array has a column per run."""
    return lambda array, index: (f"{terms.lane_array(array)}[{index}, b]" if array in per_run
                                 else f"{array}[{index}]")


def _emit_lane_sum(c: _Code, nodes: str, factor: str, name: str, lane: set[str],
                   update: str) -> None:
    """`for e: name = factor; for b: update`, the factor inside the lane loop where it reads
    an array per lane (`lane`, the arrays of `KernelOptions.per_run` it reads)."""
    c(f"for e in range({nodes}.shape[0]):")
    if not lane:
        c(f"    {name} = {factor}")
    c("    for b in range(nb_):")
    if lane:
        c(f"        {name} = {factor}")
    c(f"        {update}")


def record_block(precision) -> int:
    """Records of `precision` (a name or dtype) staged per run before they are written as one
    aligned line (RECORD_ALIGN bytes): the elements a line holds."""
    return RECORD_ALIGN // np.dtype(precision).itemsize


def emit_record(c: _Code, r: str, width: LaneLayout, rb: int) -> None:
    """Probes of record `r` into the staging block `stg` (probe, RB, lane); a full block is
    written to rec (probe, run, record: each run's trajectory contiguous, rows padded to and
    aligned on RECORD_ALIGN bytes) as one non-temporal line per probe and run
    (`springc.kernels.streamstore`), each chunk's runs from row `rec_col + lo_` on: every thread
    writes pages of its own runs only."""
    c(f"r_ = {r}")
    if width.width == 1:
        # one run per chunk: its records are consecutive already, and stay in the caches
        # when the run is short (streaming them out was slower)
        c("for p in range(rec_node.shape[0]):")
        c("    q = rec_node[p]")
        c("    rec[p, rec_col + lo_, r_] = v[q, 0] if rec_isv[p] else x[q, 0]")
        return
    c("rb_ = r_ % RB")
    c("for p in range(rec_node.shape[0]):")
    c.indent()
    c("q = rec_node[p]")
    for cond, src in (("if rec_isv[p]:", "v"), ("else:", "x")):
        c(cond)
        c.indent()
        lanes(c, width, [f"A{{b}} = {src}[q, {{b}}]"], [], ["stg[p, rb_, {b}] = A{b}"])
        c.dedent()
    c.dedent()
    c("r_hi = r_")
    c("if rb_ == RB - 1:")
    c.indent()
    c("r0 = r_ - (RB - 1)")
    c("for p in range(rec_node.shape[0]):")
    c("    for b in range(nv_):")
    c.indent(2)
    c("stream_store(rec, p, rec_col + lo_ + b, r0, ("
      + ", ".join(f"stg[p, {k}, b]" for k in range(rb)) + "))")
    c.dedent(3)


def emit_record_tail(c: _Code) -> None:
    """The records of the last, partial staging block (ordinary stores)."""
    c("record_tail(rec, stg, rec_node.shape[0], r_hi, rec_col + lo_, nv_)")


def emit_step_end(c: _Code, opts: KernelOptions, width: LaneLayout,
                  before: Callable[[], None] | None = None) -> None:
    """After a step's combine: reductions, the record when due, the divergence guard.
    `before` writes what precedes reading the state rows (a register kernel's write-back)."""
    c("k1 = step + 1")
    if opts.msq:
        c("for m in range(ms_node.shape[0]):")
        c("    if ms_lo[m] <= k1 and k1 <= ms_hi[m]:")
        c("        for b in range(nb_):")
        for stmt in msq_update():
            c("            " + in_lanes(stmt))
    if opts.gram:
        _emit_gram_step(c)
    if opts.record:
        c("rc_ += 1")
        c("if rc_ == rec_every:")
        c.indent()
        c("rc_ = 0")
        c("rn_ += 1")
        if before is not None:
            before()
        emit_record(c, "rn_", width, record_block(opts.precision))
        c.dedent()
    # Divergence guard every `check_every` steps and at the last: a lane with NaN/Inf or a
    # state beyond `limit` is marked (step and node, once); the chunk stops when every lane
    # is marked, so the caller can keep the other runs and simulate the marked ones again.
    c("cc_ += 1")
    c("if cc_ == check_every or k1 == nsteps:")
    c.indent()
    c("cc_ = 0")
    if before is not None:
        before()
    c("if guard(x, v, status, bad_node, lo_, nv_, limit, k1) == 0:")  # springc.kernels.chunk
    c("    break")
    c.dedent()


def _emit_gram_step(c: _Code) -> None:
    # Leaky sum: decay every group by exp(-h/tau), then add this step's weighted products;
    # stays bounded (no exp(t/tau) growth) and needs no stored trajectory.
    c("for gq in range(gracc.shape[0]):")
    c("    dg = gr_decay[gq]")
    c("    for b in range(nb_):")
    c("        gracc[gq, b] *= dg")
    c("for p in range(gr_i.shape[0]):")
    c("    xi_ = x[gr_i[p]]")
    c("    xj_ = x[gr_j[p]]")
    c("    gp = gr_g[p]")
    c("    wp = gr_w[p]")
    c("    for b in range(nb_):")
    c("        gracc[gp, b] += wp * xi_[b] * xj_[b]")


def _emit_reduction_init(c: _Code, opts: KernelOptions) -> None:
    if opts.work:
        c("w_in = np.zeros((work_in.shape[0], nb_))")
        c("w_c = np.zeros((work_c.shape[0], nb_))")
    if opts.dissipation:
        c("dsacc = np.zeros((ds_i.shape[0], nb_))")
    if opts.msq:
        c("msacc = np.zeros((ms_node.shape[0], nb_))")
    if opts.gram:
        c("gracc = np.zeros((gram.shape[0], nb_))")
        c("for p in range(gr_i.shape[0]):")
        c("    for b in range(nb_):")
        c("        gracc[gr_g[p], b] += gr_w[p] * x[gr_i[p], b] * x[gr_j[p], b]")


def _emit_reduction_store(c: _Code, opts: KernelOptions) -> None:
    pairs = []
    if opts.work:
        pairs += [("w_in", "work_in"), ("w_c", "work_c")]
    if opts.dissipation:
        pairs.append(("dsacc", "diss"))
    if opts.msq:
        pairs.append(("msacc", "msq"))
    if opts.gram:
        pairs.append(("gracc", "gram"))
    for local, out in pairs:
        c(f"store_lanes({out}, {local}, lo_, nv_)")
