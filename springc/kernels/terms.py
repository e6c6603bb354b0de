"""Every force term, described once; each kernel form renders the descriptions.

A node's acceleration is a sum of terms: its own damping and spring (`own_sum`), its
stiffness row and input forces (`ROW`, `INPUT`), and one end of each element of the `KINDS`
that touches it (quadratic coupling, Duffing, dashpot, shared signal). A `Kind` names the
coefficient arrays it reads, the subexpressions both ends share, and the force on each end
(over the mass) as a template over the ends' positions {xi} {xj} and velocities {vi} {vj}.

    rendering            function        used by
    element loops        element_loop    the shared and exponential kernels
                                         (codegen.emit_accel_body): both ends in place
    ends per node        gather_end      the shared kernel with its nodes split over
                                         threads (codegen.emit_linear): each node sums
                                         its own ends (`node_ends`), in the loops' order
    one sum per node     node_sum        the written-out kernels (codegen.emit_nodes) and
                                         the register kernels (regkernel): coefficients in
                                         scalars (`scalar_loads`), indices constants

A `Kind` also carries its force in the netlist's own coefficients, not over the mass
(`physical`, a `Physical`); with the springs, couplings and input forces that the kernels
fold into the rows these are `ELEMENTS`, from which the adjoint renders each force and its
derivatives (`springc.grad.render`).

A new term kind is a `Kind` here with its `physical`, its arrays in
`springc.sim.marshal.coefficient_arrays` and `springc.grad.model`, and its flag in
`codegen.Features`. Monomials (any number of factors) keep their own loop,
`codegen.emit_monomials`, in every form.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

STATE = ("xi", "xj", "vi", "vj")  # the template fields that read the state (per lane)


@dataclass(frozen=True)
class Physical:
    """An element kind in the netlist's own coefficients, its forces not over the mass: what
    the adjoint differentiates (`springc.grad.render`). `params`: (template field, its
    array in `springc.grad.model.Model`, its block of `model.BLOCKS`), the fields named as
    the element's keywords in the netlist (`letter`); `temps`, `force` and `ground` as a
    `Kind`'s; `channel`: the Model array of each element's input channel, read as {u}."""

    name: str
    letter: str  # the element's letter in a netlist
    node_i: str
    node_j: str | None
    params: tuple[tuple[str, str, str], ...]
    temps: tuple[tuple[str, str], ...]
    force: tuple[tuple[str, str], ...]
    ground: str | None = None
    channel: str | None = None
    signal: bool = False  # reads its shared source's value {g}


# the linear elements and input forces, which the simulator's kernels fold into each node's
# stiffness row and input terms (`ROW`, `INPUT`, `own_sum`) and the adjoint keeps apart
SPRING = Physical("spring", "K", "k_node", None, (("k", "k_k", "k"),), (),
                  (("i", "- {k} * {xi}"),))
COUPLING = Physical(  # U = k/(2a) (x_i - a x_j)^2
    "coupling", "C", "c_i", "c_j", (("k", "c_k", "ck"), ("a", "c_a", "ca")),
    (("KA", "{k} / {a}"), ("R", "{xi} - {a} * {xj}")),
    (("i", "- {KA} * {R}"), ("j", "+ {k} * {R}")))
INPUT_FORCE = Physical("input", "F", "fi_node", None, (("gain", "fi_gain", "fi"),), (),
                       (("i", "+ {gain} * {u}"),), channel="fi_chan")


@dataclass(frozen=True)
class Kind:
    """One element kind: its node arrays, the coefficients it reads, the subexpressions its
    ends share (`temps`, in order; one without state fields is a per-element scalar) and
    the force on each end. `node_j` None: one-node elements; an entry < 0 in it: the
    element's second end is the ground, and end i gets `ground` instead."""

    name: str
    feature: str  # the `codegen.Features` flag
    node_i: str
    node_j: str | None
    coefs: tuple[tuple[str, str], ...]  # (template field, coefficient array)
    temps: tuple[tuple[str, str], ...]  # (template field, template)
    force: tuple[tuple[str, str], ...]  # (end, template): added to that end's acceleration
    ground: str | None = None
    signal: bool = False  # reads the element's shared-signal value {g} (`grow[e]`)
    physical: Physical | None = None  # the same force in the netlist's coefficients

    def reads_velocity(self) -> bool:
        """Whether its force reads its ends' velocities (a damper)."""
        text = " ".join([t for _, t in self.temps + self.force] + [self.ground or ""])
        return "{vi}" in text or "{vj}" in text


QUAD = Kind(  # U = g/(2a) (x_i^2 - a x_j)^2; q_gi, q_gj: each end's factor over its mass
    "quad", "quads", "q_i", "q_j", (("a", "q_a"), ("gi", "q_gi"), ("gj", "q_gj")),
    (("S", "{xi} * {xi} - {a} * {xj}"),), (("i", "- {gi} * {xi} * {S}"), ("j", "+ {gj} * {S}")),
    physical=Physical(
        "quad", "Q", "q_i", "q_j", (("g", "q_g", "qg"), ("a", "q_a", "qa")),
        (("GA", "2.0 * {g} / {a}"), ("S", "{xi} * {xi} - {a} * {xj}")),
        (("i", "- {GA} * {xi} * {S}"), ("j", "+ {g} * {S}"))))
DUFFING = Kind("duffing", "duffings", "d_node", None, (("lm", "d_lm"),), (),
               (("i", "- {lm} * ({xi} * {xi} * {xi})"),),
               physical=Physical("duffing", "D", "d_node", None, (("l", "d_l", "l"),), (),
                                 (("i", "- {l} * ({xi} * {xi} * {xi})"),)))
DASHPOT = Kind(
    "dashpot", "dashpots", "b_i", "b_j", (("bi", "b_bi"), ("bj", "b_bj")),
    (("R", "{vi} - {vj}"),), (("i", "- {bi} * {R}"), ("j", "+ {bj} * {R}")),
    ground="- {bi} * {vi}",
    physical=Physical("dashpot", "B", "b_i", "b_j", (("b", "b_b", "bb"),),
                      (("R", "{vi} - {vj}"),), (("i", "- {b} * {R}"), ("j", "+ {b} * {R}")),
                      ground="- {b} * {vi}"))
COMMON = Kind("common", "common_forces", "fc_node", None, (("gm", "fc_gm"),),
              (("F", "{gm} * {g}"),), (("i", "+ {F}"),), signal=True,
              physical=Physical("common", "F", "fc_node", None,
                                (("gain", "fc_gain", "fc"),), (),
                                (("i", "+ {gain} * {g}"),), signal=True))

# The order of a node's sum (after its own, row and input terms). The shared kernel's loops
# run in `LOOP_ORDER`: another order would round differently from the kernels it replaced.
KINDS = (QUAD, DUFFING, DASHPOT, COMMON)
LOOP_ORDER = (DUFFING, QUAD, DASHPOT)  # then monomials, then COMMON (codegen.emit_accel_body)
BY_NAME = {k.name: k for k in KINDS}
# every element kind as the adjoint sees it, in the order of `springc.grad.model.BLOCKS`
# (the monomials, between the dashpots and the input forces there, keep their own loop)
ELEMENTS = (SPRING, DUFFING.physical, COUPLING, QUAD.physical, DASHPOT.physical, INPUT_FORCE,
            COMMON.physical)
ROW = "+ {w} * {xj}"  # an off-diagonal stiffness entry (l_val) times the other node's position
INPUT = "+ {gm} * {u}"  # an input force's gain over the mass (fi_gm) times its channel


def own_sum(damped: bool, sprung: bool, bm: str, km: str, v: str, x: str) -> str:
    """A node's own terms, -(b/m v + k/m x), of those it has ('' if none)."""
    own = ([f"{bm} * {v}"] if damped else []) + ([f"{km} * {x}"] if sprung else [])
    return f"- ({' + '.join(own)})" if own else ""


@dataclass(frozen=True)
class NodeTerms:
    """One node's force terms, as indices into the kernel's coefficient arrays."""

    damped: bool  # bm != 0: reads its own velocity
    sprung: bool  # km != 0
    row: tuple[tuple[int, int], ...]  # (entry of l_val, column): off-diagonal stiffness
    ins: tuple[tuple[int, int], ...]  # (entry of fi_gm, channel): input forces
    ends: tuple[tuple[str, int, str, int], ...]  # (kind, element, end, other node or -1)
    looped: bool  # touched by a monomial, which every form keeps in its loop

    def reads_velocity(self) -> bool:
        """Whether its force reads its own velocity (a damper on it)."""
        return self.damped or any(k == "dashpot" for k, *_ in self.ends)


# Writing the force code out per node: at most this many nodes (numba's compile time grows
# with the text, and very long texts overflow its recursion limit) and this many row, input
# and quadratic-coupling terms on any node (denser nodes run faster in the shared loops;
# docs/performance.md#kernel-forms-shared-written-out-register).
NODES_MAX = 48
NODE_TERMS_MAX = 8


def node_terms(co: dict, n: int) -> tuple[NodeTerms, ...] | None:
    """Each node's terms from the coefficient arrays `co` (`marshal.coefficient_arrays`),
    the kinds' ends in `KINDS` order and each kind's element order; None when the network
    is too large to write out (`NODES_MAX`, `NODE_TERMS_MAX`)."""
    if n > NODES_MAX:
        return None
    ends: list[list] = [[] for _ in range(n)]
    for kind in KINDS:
        if kind.node_i not in co:
            continue
        first = co[kind.node_i].tolist()
        second = co[kind.node_j].tolist() if kind.node_j else [-1] * len(first)
        for e, (i, j) in enumerate(zip(first, second)):
            ends[i].append((kind.name, e, "i", j))
            if j >= 0:
                ends[j].append((kind.name, e, "j", i))
    looped = set(co["p_var"].tolist()) if "p_var" in co else set()
    ptr, col, fptr, chan = (co[k].tolist() for k in ("l_ptr", "l_col", "fi_ptr", "fi_chan"))
    out = []
    for i in range(n):
        row = tuple((e, col[e]) for e in range(ptr[i], ptr[i + 1]))
        ins = tuple((e, chan[e]) for e in range(fptr[i], fptr[i + 1]))
        quads = sum(1 for k, *_ in ends[i] if k == "quad")
        if len(row) + len(ins) + quads > NODE_TERMS_MAX:
            return None
        # sorted by kind order, then element: each kind's loop visits a node in that order
        order = sorted(ends[i], key=lambda t: (KINDS.index(BY_NAME[t[0]]), t[1]))
        # any run's coefficient: a per-run array (`lane_array`) has a column per run
        out.append(NodeTerms(bool(np.any(co["bm"][i] != 0.0)), bool(np.any(co["km"][i] != 0.0)),
                             row, ins, tuple(order), i in looped))
    return tuple(out)


def scalar(array: str, e: int) -> str:
    """The scalar a per-node rendering reads entry e of a coefficient array into."""
    return f"{array}{e}"


def lane_array(array: str) -> str:
    """The chunk's copy of a per-run coefficient array, (entries, LANES): each lane's run's
    coefficients (`codegen.emit_lane_coefficients`)."""
    return f"{array}_l"


def scalar_loads(i: int, node: NodeTerms, per_run: frozenset[str] = frozenset(),
                 lane: str | None = None) -> list[str]:
    """`name = array[entry]` for every coefficient node i's sum reads (`node_sum`). With
    `per_run` (arrays with a column per run) these are left out, and with `lane` only they
    are loaded, as `name = lane_array(array)[entry, lane]`."""
    entries = ([("bm", i)] if node.damped else []) + ([("km", i)] if node.sprung else [])
    entries += [("l_val", e) for e, _ in node.row]
    entries += [("fi_gm", e) for e, _ in node.ins]
    for name, e, end, other in node.ends:
        kind = BY_NAME[name]
        text = _end_template(kind, end, other)
        entries += [(arr, e) for field, arr in kind.coefs if "{" + field + "}" in text]
    if lane is None:
        return [f"{scalar(arr, e)} = {arr}[{e}]" for arr, e in entries if arr not in per_run]
    return [f"{scalar(arr, e)} = {lane_array(arr)}[{e}, {lane}]" for arr, e in entries
            if arr in per_run]


Names = Callable[[int], str]


def node_sum(i: int, node: NodeTerms, x: Names, v: Names, u: Names, g: Names) -> str:
    """Node i's acceleration as one expression summed left to right: own terms, stiffness
    row, inputs, then each end in `node.ends`; `x`, `v` name a node's stage position and
    velocity, `u` a channel's input, `g` a shared-signal element's value (coefficients as
    `scalar_loads` names them). 'FT(0.0)' for a node without terms."""
    terms = [own_sum(node.damped, node.sprung, f"bm{i}", f"km{i}", v(i), x(i))]
    terms += [ROW.format(w=scalar("l_val", e), xj=x(j)) for e, j in node.row]
    terms += [INPUT.format(gm=scalar("fi_gm", e), u=u(ch)) for e, ch in node.ins]
    for name, e, end, other in node.ends:
        kind = BY_NAME[name]
        ends = (i, other) if end == "i" else (other, i)
        state = {"xi": x(ends[0]), "vi": v(ends[0])}
        if ends[1] >= 0:
            state |= {"xj": x(ends[1]), "vj": v(ends[1])}
        fields = {field: scalar(arr, e) for field, arr in kind.coefs}
        if kind.signal:
            fields["g"] = g(e)
        terms.append(_end_template(kind, end, other).format(**state, **fields))
    return " ".join(t for t in terms if t).removeprefix("+ ") or "FT(0.0)"


def _end_template(kind: Kind, end: str, other: int) -> str:
    """The force on one end, its subexpressions inlined (in parentheses)."""
    template = kind.ground if other < 0 and kind.ground is not None else dict(kind.force)[end]
    for name, temp in reversed(kind.temps):
        template = template.replace("{" + name + "}", "(" + temp + ")")
    return template


@dataclass(frozen=True)
class Rows:
    """The arrays a stage's force code reads positions (`x`) and velocities (`v`) from and
    stores accelerations (`k`) into: the CPU kernels bind xa, va, ka in their loop over the
    stages; a form that writes its stages out names each stage's own (the CUDA form)."""

    x: str = "xa"
    v: str = "va"
    k: str = "ka"


ROWS = Rows()


@dataclass(frozen=True)
class LoopCode:
    """An element loop's code for `codegen.lanes`: per-element scalar statements, then per
    lane the loads, the arithmetic and the stores (`{b}`: the lane)."""

    head: list[str]
    loads: list[str]
    arith: list[str]
    stores: list[str]


def element_loop(kind: Kind, ground: bool = False,
                 per_run: frozenset[str] = frozenset(), rows: Rows = ROWS) -> LoopCode:
    """One element of `kind` in the shared kernel: its nodes and coefficients into scalars,
    the ends' state and accelerations loaded per lane, the shared subexpressions, then each
    end's acceleration stored. A kind with a `ground` force is rendered twice, inside a
    branch on `j = node_j[e]` (the caller's): `ground` True for a second end at the ground.
    Coefficient arrays in `per_run` are loaded per lane from their `lane_array`; the state
    and accelerations are read from and stored to `rows`."""
    two = kind.node_j is not None and not ground
    ends = ["i", "j"] if two else ["i"]
    forces = {"i": kind.ground} if ground else dict(kind.force)
    used = " ".join([forces[e] for e in ends] + [t for _, t in kind.temps])
    head = [f"i = {kind.node_i}[e]"]
    if two and kind.ground is None:
        head.append(f"j = {kind.node_j}[e]")
    coefs = [(f, arr) for f, arr in kind.coefs if "{" + f + "}" in used]
    head += [f"{f} = {arr}[e]" for f, arr in coefs if arr not in per_run]
    if kind.signal:
        head.append("gv = grow[e]")  # not `g`: the kernel's argument of that name
    fields = {f: f for f, _ in kind.coefs} | {"g": "gv"}
    lane_fields = {f: f"C{f}{{b}}" for f, arr in coefs if arr in per_run}
    fields |= lane_fields
    state = {s: s.upper() + "{b}" for s in STATE}
    loads = [f"{s.upper()}{{b}} = {rows.x if s[0] == 'x' else rows.v}[{s[1]}, {{b}}]"
             for s in STATE if "{" + s + "}" in used and s[1] in ends]
    loads += [f"{lane_fields[f]} = {lane_array(arr)}[e, {{b}}]" for f, arr in coefs
              if f in lane_fields]
    loads += [f"O{e.upper()}{{b}} = {rows.k}[{e}, {{b}}]" for e in ends]
    arith = []
    for name, temp in kind.temps:
        if "{" + name + "}" not in used:
            continue
        if any("{" + s + "}" in temp for s in (*STATE, *lane_fields)):
            arith.append(f"{name}{{b}} = " + _fill(temp, state, fields))
            fields[name] = name + "{b}"
        else:  # per element, not per lane
            head.append(f"{name} = " + _fill(temp, state, fields))
            fields[name] = name
    stores = [f"{rows.k}[{e}, {{b}}] = O{e.upper()}{{b}} " + _fill(forces[e], state, fields)
              for e in ends]
    return LoopCode(head, loads, arith, stores)


def _fill(template: str, state: dict[str, str], fields: dict[str, str]) -> str:
    """The template with state fields as lane temporaries and the rest as `fields` name
    them (the lane marker `{b}` kept for `codegen.lanes`)."""
    out = template
    for key, value in {**state, **fields}.items():
        out = out.replace("{" + key + "}", value)
    assert not re.search(r"\{(?!b\})", out), out  # every field filled
    return out


def gather_args(kind: Kind) -> tuple[str, ...]:
    """The arrays of `node_ends` for `kind`: each node's range of ends (`_ptr`), the
    element of each (`_e`), and for two-node kinds its other node (`_o`, -1: the ground)
    and which end the node is (`_end`: 0 for i, 1 for j)."""
    names = (f"{kind.name}_ptr", f"{kind.name}_e")
    return names if kind.node_j is None else names + (f"{kind.name}_o", f"{kind.name}_end")


def node_ends(co: dict, n: int) -> dict[str, np.ndarray]:
    """`gather_args` of every kind in `co` (`marshal.coefficient_arrays`): each node's ends
    in element order, i before j within an element, the order in which the element loops
    add them to the node's acceleration, so that a node's sum rounds as theirs does."""
    out = {}
    for kind in KINDS:
        if kind.node_i not in co or kind is COMMON:
            continue
        first = co[kind.node_i].astype(np.int64)
        # int64 throughout: numpy makes float64 of uint64 and int64 together
        second = (co[kind.node_j].astype(np.int64) if kind.node_j
                  else np.full(len(first), -1, np.int64))
        two = second >= 0
        elems = np.arange(len(first), dtype=np.int64)
        node = np.concatenate([first, second[two]])
        elem = np.concatenate([elems, elems[two]])
        end = np.concatenate([np.zeros(len(first), np.uint8), np.ones(two.sum(), np.uint8)])
        other = np.concatenate([second, first[two]])
        order = np.lexsort((end, elem, node))
        names = gather_args(kind)
        out[names[0]] = np.searchsorted(node[order], np.arange(n + 1)).astype(np.uint64)
        out[names[1]] = elem[order].astype(np.uint64)
        if kind.node_j is not None:
            out[names[2]] = np.ascontiguousarray(other[order])
            out[names[3]] = np.ascontiguousarray(end[order])
    return out


def gather_end(kind: Kind, end: str, ground: bool = False,
               coef: Callable[[str, str], str] | None = None, rows: Rows = ROWS) -> LoopCode:
    """Node i's term as end `end` of element `e` of `kind` (its other node `o`), added to
    the node's accumulator A{b}: `element_loop`'s arithmetic for that end, with the node's
    running sum in place of its stored acceleration. `ground`: the other end is the
    ground. `coef(field, array)`: where a form reads a coefficient from (default
    `array[e]`; the CUDA split form's registers); the state is read from `rows`."""
    template = kind.ground if ground else dict(kind.force)[end]
    at = {"i": "i", "j": "o"} if end == "i" else {"i": "o", "j": "i"}
    temps = [(name, t) for name, t in kind.temps if "{" + name + "}" in template]
    used = " ".join([template] + [t for _, t in temps])
    read = coef or (lambda f, arr: f"{arr}[e]")
    head = [f"{f} = {read(f, arr)}" for f, arr in kind.coefs if "{" + f + "}" in used]
    fields = {f: f for f, _ in kind.coefs}
    state = {s: s.upper() + "{b}" for s in STATE}
    loads = [f"{s.upper()}{{b}} = {rows.x if s[0] == 'x' else rows.v}[{at[s[1]]}, {{b}}]"
             for s in STATE if "{" + s + "}" in used]
    arith = []
    for name, temp in temps:
        if any("{" + s + "}" in temp for s in STATE):
            arith.append(f"{name}{{b}} = " + _fill(temp, state, fields))
            fields[name] = name + "{b}"
        else:  # per element, not per lane
            head.append(f"{name} = " + _fill(temp, state, fields))
            fields[name] = name
    arith.append("A{b} = A{b} " + _fill(template, state, fields))
    return LoopCode(head, loads, arith, [])
