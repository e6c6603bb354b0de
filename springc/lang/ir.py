"""The elaborated, flat, index-based intermediate representation of a netlist.

Every node is an integer degree of freedom; every element kind is a table of arrays (endpoints
and coefficients), with the element's full hierarchical name and source location kept beside it.
The front end builds it with `IRBuilder`; checks, code generation, the runtime and the analyses
only read it. `text()` is a deterministic dump for golden tests; `validate()` checks invariants.
"""

from __future__ import annotations

import itertools
from collections import defaultdict
from dataclasses import dataclass, field

import numpy as np

from springc.errors import SourceLoc

GROUND = -1  # node index of ground ('0'), allowed only as the second node of a dashpot

SOURCE_KINDS = ("in", "sin", "gauss", "step", "pwl", "wav")
# the argument columns of each kind `IRBuilder.rows` takes (i: node index, f: value)
_COLUMNS = {"M": (np.int64,) + (np.float64,) * 4, "K": (np.int64, np.float64),
            "D": (np.int64, np.float64), "C": (np.int64,) * 2 + (np.float64,) * 2,
            "Q": (np.int64,) * 2 + (np.float64,) * 2, "B": (np.int64,) * 2 + (np.float64,)}


@dataclass
class Table:
    """Provenance shared by all element tables: one name and location per element."""

    names: list[str] = field(default_factory=list)
    locs: list[SourceLoc] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.names)


@dataclass
class Masses(Table):
    """`M` elements. Several may sit on one node (rigidly joined bodies): they add."""

    node: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    b: np.ndarray = field(default_factory=lambda: np.zeros(0))
    x0: np.ndarray = field(default_factory=lambda: np.zeros(0))
    v0: np.ndarray = field(default_factory=lambda: np.zeros(0))


@dataclass
class Springs(Table):
    """`K`: V = k/2 x^2."""

    node: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    k: np.ndarray = field(default_factory=lambda: np.zeros(0))


@dataclass
class Duffings(Table):
    """`D`: V = l/4 x^4."""

    node: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    l: np.ndarray = field(default_factory=lambda: np.zeros(0))  # noqa: E741


@dataclass
class Couplings(Table):
    """`C`: V = k/(2a) (x_i - a x_j)^2."""

    i: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    j: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    k: np.ndarray = field(default_factory=lambda: np.zeros(0))
    a: np.ndarray = field(default_factory=lambda: np.zeros(0))


@dataclass
class QuadCouplings(Table):
    """`Q`: V = g/(2a) (x_i^2 - a x_j)^2."""

    i: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    j: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    g: np.ndarray = field(default_factory=lambda: np.zeros(0))
    a: np.ndarray = field(default_factory=lambda: np.zeros(0))


@dataclass
class Dashpots(Table):
    """`B`: force -b (v_i - v_j) on i and the opposite on j; j may be GROUND."""

    i: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    j: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    b: np.ndarray = field(default_factory=lambda: np.zeros(0))


@dataclass
class Monomials(Table):
    """`P`: V = c * prod_k x_{var[k]}^{exp[k]}, factors of element e at ptr[e]:ptr[e+1]."""

    c: np.ndarray = field(default_factory=lambda: np.zeros(0))
    ptr: np.ndarray = field(default_factory=lambda: np.zeros(1, np.int64))
    var: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    exp: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))


@dataclass(frozen=True)
class Source:
    """A force signal. kind 'in': channel of the simulator's input signals; 'wav': a sound
    file (absolute path); analytic kinds carry their numeric arguments in `args`."""

    kind: str
    args: tuple[float, ...] = ()
    channel: int = 0
    path: str = ""


@dataclass
class Forces(Table):
    """`F`: force gain * source(t) on node."""

    node: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    gain: np.ndarray = field(default_factory=lambda: np.zeros(0))
    source: list[Source] = field(default_factory=list)


@dataclass(frozen=True)
class Probe:
    """A recorded quantity: 'x' or 'v' of a node; `label` as written, e.g. 'x(X1.out)'."""

    quantity: str
    node: int
    label: str
    loc: SourceLoc


@dataclass(frozen=True)
class Tran:
    """`.tran tstep tstop`."""

    tstep: float
    tstop: float
    loc: SourceLoc


@dataclass(frozen=True)
class AcSpec:
    """`.ac to-node fstart fstop points= input=`."""

    node: int
    fstart: float
    fstop: float
    points: int
    input: int
    loc: SourceLoc


@dataclass(frozen=True)
class NoiseSpec:
    """`.noise to-node fstart fstop points= input=`: thermal noise at rest."""

    node: int
    fstart: float
    fstop: float
    points: int
    input: int
    loc: SourceLoc


@dataclass(frozen=True)
class Instance:
    """One subcircuit instance: its full path (`X1.X2`), subcircuit name and where written."""

    path: str
    subckt: str
    loc: SourceLoc


@dataclass
class FlatNetlist:
    """A flattened netlist: nodes are 0..n-1, element tables index into them."""

    title: str
    file: str
    nodes: list[str]
    node_locs: list[SourceLoc]
    masses: Masses
    springs: Springs
    duffings: Duffings
    couplings: Couplings
    quads: QuadCouplings
    dashpots: Dashpots
    monomials: Monomials
    forces: Forces
    probes: list[Probe]
    tran: Tran | None
    acs: list[AcSpec]
    options: dict[str, object]
    option_locs: dict[str, SourceLoc]
    instances: list[Instance]
    noises: list[NoiseSpec] = field(default_factory=list)

    @property
    def n(self) -> int:
        """Number of degrees of freedom."""
        return len(self.nodes)

    def node_index(self, name: str) -> int:
        """Index of node `name`; KeyError if there is none."""
        return self.nodes.index(name)

    def mass(self) -> np.ndarray:
        """Total mass per node (summed over `M` elements)."""
        out = np.zeros(self.n)
        np.add.at(out, self.masses.node, self.masses.m)
        return out

    def local_damping(self) -> np.ndarray:
        """Total local damping b per node (from `M` elements)."""
        out = np.zeros(self.n)
        np.add.at(out, self.masses.node, self.masses.b)
        return out

    def initial_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Initial positions and velocities per node (from `M` elements; several add)."""
        x0, v0 = np.zeros(self.n), np.zeros(self.n)
        np.add.at(x0, self.masses.node, self.masses.x0)
        np.add.at(v0, self.masses.node, self.masses.v0)
        return x0, v0

    def tables(self) -> dict[str, Table]:
        """Element tables by element letter, in a fixed order."""
        return {
            "M": self.masses,
            "K": self.springs,
            "D": self.duffings,
            "C": self.couplings,
            "Q": self.quads,
            "B": self.dashpots,
            "P": self.monomials,
            "F": self.forces,
        }

    def element_counts(self) -> dict[str, int]:
        """Number of elements per letter after flattening (letters with none are left out)."""
        return {k: len(t) for k, t in self.tables().items() if len(t)}

    def element_loc(self, letter: str, index: int) -> SourceLoc:
        """Source location of element `index` of kind `letter`."""
        return self.tables()[letter].locs[index]

    def text(self) -> str:
        """A deterministic, human-readable dump used by golden tests."""
        return _dump(self)

    def validate(self) -> None:
        """Assert the structural invariants (indices in range, array lengths agree)."""
        _validate(self)


def _fmt(v: float) -> str:
    return f"{float(v):.10g}"


def _dump(net: FlatNetlist) -> str:
    lines = [f"title {net.title!r}", f"dofs {net.n}"]
    for idx, name in enumerate(net.nodes):
        lines.append(f"node {idx} {name}")
    name = net.nodes.__getitem__
    t = net.masses
    for e in range(len(t)):
        lines.append(
            f"M {t.names[e]} {name(t.node[e])} m={_fmt(t.m[e])} b={_fmt(t.b[e])}"
            f" x0={_fmt(t.x0[e])} v0={_fmt(t.v0[e])}"
        )
    for e in range(len(net.springs)):
        s = net.springs
        lines.append(f"K {s.names[e]} {name(s.node[e])} k={_fmt(s.k[e])}")
    for e in range(len(net.duffings)):
        s = net.duffings
        lines.append(f"D {s.names[e]} {name(s.node[e])} l={_fmt(s.l[e])}")
    for e in range(len(net.couplings)):
        s = net.couplings
        lines.append(
            f"C {s.names[e]} {name(s.i[e])} {name(s.j[e])} k={_fmt(s.k[e])} a={_fmt(s.a[e])}"
        )
    for e in range(len(net.quads)):
        s = net.quads
        lines.append(
            f"Q {s.names[e]} {name(s.i[e])} {name(s.j[e])} g={_fmt(s.g[e])} a={_fmt(s.a[e])}"
        )
    for e in range(len(net.dashpots)):
        s = net.dashpots
        other = "0" if s.j[e] == GROUND else name(s.j[e])
        lines.append(f"B {s.names[e]} {name(s.i[e])} {other} b={_fmt(s.b[e])}")
    p = net.monomials
    for e in range(len(p)):
        lo, hi = p.ptr[e], p.ptr[e + 1]
        factors = " ".join(f"{name(p.var[k])}^{p.exp[k]}" for k in range(lo, hi))
        lines.append(f"P {p.names[e]} c={_fmt(p.c[e])} {factors}")
    f = net.forces
    for e in range(len(f)):
        lines.append(f"F {f.names[e]} {name(f.node[e])} {_source_text(f.source[e])}"
                     f" gain={_fmt(f.gain[e])}")
    for pr in net.probes:
        lines.append(f"probe {pr.label} {pr.quantity} {name(pr.node)}")
    if net.tran:
        lines.append(f"tran {_fmt(net.tran.tstep)} {_fmt(net.tran.tstop)}")
    for ac in net.acs:
        lines.append(
            f"ac {name(ac.node)} {_fmt(ac.fstart)} {_fmt(ac.fstop)} points={ac.points}"
            f" input={ac.input}"
        )
    for ns in net.noises:
        lines.append(
            f"noise {name(ns.node)} {_fmt(ns.fstart)} {_fmt(ns.fstop)} points={ns.points}"
            f" input={ns.input}"
        )
    for key in sorted(net.options):
        lines.append(f"option {key}={net.options[key]}")
    for inst in net.instances:
        lines.append(f"instance {inst.path} {inst.subckt}")
    return "\n".join(lines) + "\n"


def _source_text(src: Source) -> str:
    if src.kind == "in":
        return f"in({src.channel})"
    if src.kind == "wav":
        return f'wav("{src.path.rsplit("/", 1)[-1]}")'
    return f"{src.kind}({' '.join(_fmt(a) for a in src.args)})"


def _check_nodes(idx: np.ndarray, n: int, allow_ground: bool = False) -> None:
    low = GROUND if allow_ground else 0
    assert idx.dtype.kind == "i", idx.dtype
    assert np.all((idx >= low) & (idx < n)), "node index out of range"


def _validate(net: FlatNetlist) -> None:
    n = net.n
    assert len(net.node_locs) == n and len(set(net.nodes)) == n
    for letter, table in net.tables().items():
        assert len(table.locs) == len(table.names), letter
    for tab, attrs in [
        (net.masses, ("node", "m", "b", "x0", "v0")),
        (net.springs, ("node", "k")),
        (net.duffings, ("node", "l")),
        (net.couplings, ("i", "j", "k", "a")),
        (net.quads, ("i", "j", "g", "a")),
        (net.dashpots, ("i", "j", "b")),
        (net.forces, ("node", "gain", "source")),
        (net.monomials, ("c",)),
    ]:
        for attr in attrs:
            assert len(getattr(tab, attr)) == len(tab), (type(tab).__name__, attr)
    for tab, attr in [(net.masses, "node"), (net.springs, "node"), (net.duffings, "node"),
                      (net.couplings, "i"), (net.couplings, "j"), (net.quads, "i"),
                      (net.quads, "j"), (net.dashpots, "i"), (net.forces, "node"),
                      (net.monomials, "var")]:
        _check_nodes(getattr(tab, attr), n)
    _check_nodes(net.dashpots.j, n, allow_ground=True)
    p = net.monomials
    assert len(p.ptr) == len(p) + 1 and p.ptr[0] == 0 and p.ptr[-1] == len(p.var)
    assert len(p.exp) == len(p.var)
    assert all(s.kind in SOURCE_KINDS for s in net.forces.source)
    assert all(0 <= pr.node < n and pr.quantity in ("x", "v") for pr in net.probes)


class IRBuilder:
    """Accumulates nodes and elements, then `finish()`es into a `FlatNetlist`.

    Used by the elaborator, and by tests and design tools that build networks in code.
    Nodes are created on first mention; `loc` defaults to a synthetic location."""

    def __init__(self, title: str = "", file: str = "<built>") -> None:
        self.title, self.file = title, file
        # a defaultdict only so that `node_rows` can number new nodes in one pass
        self._nodes: defaultdict[str, int] = defaultdict()
        self._node_locs: list[SourceLoc] = []
        self._rows: dict[str, list[tuple]] = {k: [] for k in "MKDCQBPF"}
        # whole tables' worth of rows of the column letters, in order (see `rows`)
        self._chunks: dict[str, list[tuple[list, list, tuple]]] = {k: [] for k in _COLUMNS}
        self.probes: list[Probe] = []
        self.tran: Tran | None = None
        self.acs: list[AcSpec] = []
        self.noises: list[NoiseSpec] = []
        self.options: dict[str, object] = {}
        self.option_locs: dict[str, SourceLoc] = {}
        self.instances: list[Instance] = []

    def _loc(self, loc: SourceLoc | None) -> SourceLoc:
        return loc if loc is not None else SourceLoc(self.file, 0, 0)

    def node(self, name: str, loc: SourceLoc | None = None) -> int:
        """Index of node `name`, created if new ('0' is ground and returns GROUND)."""
        if name == "0":
            return GROUND
        if name not in self._nodes:
            self._nodes[name] = len(self._nodes)
            self._node_locs.append(self._loc(loc))
        return self._nodes[name]

    def _add(self, letter: str, name: str, loc: SourceLoc | None, *row) -> None:
        self._rows[letter].append((name, self._loc(loc), *row))

    def node_rows(self, columns: list[list[str] | None],
                  locs: list[SourceLoc]) -> tuple[list[np.ndarray], list[str]]:
        """Indices of the nodes named in `columns` (lists of names other than '0', or None for
        ground), met row by row as `node` would meet them one element at a time, a new node
        located at the `locs` entry of the column that first names it; and the new nodes."""
        named = [(c, loc) for c, loc in zip(columns, locs) if c is not None]
        count, width = len(named[0][0]), len(named)
        table = self._nodes
        before = len(table)
        table.default_factory = itertools.count(before).__next__  # numbers in order met
        try:
            flat = np.fromiter(map(table.__getitem__,
                                   itertools.chain.from_iterable(zip(*(c for c, _ in named)))),
                               dtype=np.int64, count=count * width)
        finally:
            table.default_factory = None
        new = list(itertools.islice(table, before, None))
        if new:
            fresh = np.flatnonzero(flat >= before)
            _, first = np.unique(flat[fresh], return_index=True)  # in order of their index
            self._node_locs.extend(named[p % width][1] for p in fresh[first].tolist())
        index = iter(flat[c::width] for c in range(width))
        ground = np.full(count, GROUND, dtype=np.int64)
        return [ground if c is None else next(index) for c in columns], new

    def rows(self, letter: str, names: list[str], locs: list[SourceLoc], *columns) -> None:
        """Many elements of kind `letter` (`M K D C Q B`) at once: their names, locations and
        one array per argument of `mass`, `spring`, ... (node indices from `node_rows`)."""
        self._flush(letter)
        self._chunks[letter].append((names, locs, columns))

    def _flush(self, letter: str) -> None:
        """The rows added one at a time, as a chunk of columns after the earlier chunks."""
        rows = self._rows[letter]
        if rows:
            columns = tuple(np.array([row[2 + c] for row in rows], dtype=kind)
                            for c, kind in enumerate(_COLUMNS[letter]))
            self._chunks[letter].append(([r[0] for r in rows], [r[1] for r in rows], columns))
            self._rows[letter] = []

    def _table(self, letter: str) -> tuple[dict, list[np.ndarray]]:
        """Names and locations (as `Table` keywords) and the columns of kind `letter`."""
        self._flush(letter)
        chunks = self._chunks[letter]
        prov = dict(names=list(itertools.chain.from_iterable(c[0] for c in chunks)),
                    locs=list(itertools.chain.from_iterable(c[1] for c in chunks)))
        columns = [np.concatenate([np.asarray(c[2][k], dtype=kind) for c in chunks])
                   if chunks else np.zeros(0, kind) for k, kind in enumerate(_COLUMNS[letter])]
        return prov, columns

    def mass(self, name, node, m, b=0.0, x0=0.0, v0=0.0, loc=None) -> None:
        self._add("M", name, loc, self.node(node, loc), m, b, x0, v0)

    def spring(self, name, node, k, loc=None) -> None:
        self._add("K", name, loc, self.node(node, loc), k)

    def duffing(self, name, node, l, loc=None) -> None:  # noqa: E741
        self._add("D", name, loc, self.node(node, loc), l)

    def coupling(self, name, ni, nj, k, a=1.0, loc=None) -> None:
        self._add("C", name, loc, self.node(ni, loc), self.node(nj, loc), k, a)

    def quad(self, name, ni, nj, g, a=1.0, loc=None) -> None:
        self._add("Q", name, loc, self.node(ni, loc), self.node(nj, loc), g, a)

    def dashpot(self, name, ni, nj, b, loc=None) -> None:
        self._add("B", name, loc, self.node(ni, loc), self.node(nj, loc), b)

    def monomial(self, name, c, factors: list[tuple[str, int]], loc=None) -> None:
        idx = [(self.node(v, loc), int(e)) for v, e in factors]
        self._add("P", name, loc, c, idx)

    def force(self, name, node, source: Source, gain=1.0, loc=None) -> None:
        self._add("F", name, loc, self.node(node, loc), gain, source)

    def probe(self, quantity: str, node: str, label: str | None = None, loc=None) -> None:
        label = label or f"{quantity}({node})"
        self.probes.append(Probe(quantity, self.node(node, loc), label, self._loc(loc)))

    def finish(self) -> FlatNetlist:
        """The flat netlist built so far."""
        (pm, (mn, mm, mb, mx, mv)), (pk, (kn, kk)), (pd, (dn, dl)) = (
            self._table("M"), self._table("K"), self._table("D"))
        (pc, (ci, cj, ck, ca)), (pq, (qi, qj, qg, qa)), (pb, (bi, bj, bb)) = (
            self._table("C"), self._table("Q"), self._table("B"))
        P, F = self._rows["P"], self._rows["F"]
        prov = lambda rows: dict(names=[x[0] for x in rows], locs=[x[1] for x in rows])  # noqa: E731
        factors = [f for row in P for f in row[3]]
        ptr = np.cumsum([0] + [len(row[3]) for row in P]).astype(np.int64)
        return FlatNetlist(
            title=self.title,
            file=self.file,
            nodes=list(self._nodes),
            node_locs=list(self._node_locs),
            masses=Masses(**pm, node=mn, m=mm, b=mb, x0=mx, v0=mv),
            springs=Springs(**pk, node=kn, k=kk),
            duffings=Duffings(**pd, node=dn, l=dl),
            couplings=Couplings(**pc, i=ci, j=cj, k=ck, a=ca),
            quads=QuadCouplings(**pq, i=qi, j=qj, g=qg, a=qa),
            dashpots=Dashpots(**pb, i=bi, j=bj, b=bb),
            monomials=Monomials(**prov(P), c=np.array([row[2] for row in P], dtype=np.float64),
                                ptr=ptr,
                                var=np.array([f[0] for f in factors], dtype=np.int64),
                                exp=np.array([f[1] for f in factors], dtype=np.int64)),
            forces=Forces(**prov(F), node=np.array([row[2] for row in F], dtype=np.int64),
                          gain=np.array([row[3] for row in F], dtype=np.float64),
                          source=[row[4] for row in F]),
            probes=list(self.probes),
            tran=self.tran,
            acs=list(self.acs),
            options=dict(self.options),
            option_locs=dict(self.option_locs),
            instances=list(self.instances),
            noises=list(self.noises),
        )
