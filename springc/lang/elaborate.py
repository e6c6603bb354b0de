"""AST to flat IR: `elaborate(tree, lib_dirs) -> FlatNetlist`.

One pass over the statements, in order, with a scope per subcircuit instance (parameters,
port bindings, visible definitions) and a child scope per `.for` iteration; a regular loop
of element lines is expanded over all its iterations at once (`loops`). Includes are
spliced in first (`files.Includes`), so subcircuits may be used before they are defined. Local
nodes and element names get the instance path as prefix (`X1.X2.a`); a port name resolves to
the node the instance line bound it to. Probes and `.ac` outputs are resolved at the end, once
every node exists. Physics (signs, masses, stability) is left to `springc.check.checks`.
"""

from __future__ import annotations

import itertools
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from springc.errors import NetlistError, SourceLoc
from springc.lang.ir import AcSpec, FlatNetlist, Instance, IRBuilder, NoiseSpec, Tran
from springc.lang import ast, draws, elements, loops
from springc.lang.elements import SPECS
from springc.lang.expr import CONSTANTS, Env, closest, int_value, keyed, name_text, value
from springc.lang.files import Includes, beside, read_array
from springc.lang.options import KNOWN_OPTIONS, OptionSpec, OptionValueError

GROUND = "0"
MAX_LOOP = loops.MAX_LOOP
SHOW_PROGRESS_AFTER = 3.0  # s: a general .for running longer shows a progress bar
DIRECTIVES = ("title", "param", "data", "include", "subckt", "ends", "for", "endfor", "probe",
              "tran", "ac", "noise", "options", "step", "mc", "end")
TOP_ONLY = ("tran", "ac", "noise", "options", "step", "mc")
_FIRST = ("param", "data")  # directives run before the other statements of their scope


def elaborate(tree: ast.Netlist, lib_dirs: list[Path] | None = None,
              sample: draws.Sample | None = None) -> FlatNetlist:
    """Flatten a parsed netlist (with its includes and subcircuits) into a `FlatNetlist`;
    random functions take their nominal values, or their draws in Monte Carlo `sample`.
    `.step` and `.mc` are read by `springc.lang.variation`, which calls this per point."""
    _check_directive_names(tree.statements)
    try:
        return _Elaborator(tree.file, lib_dirs, sample).run(tree)
    except RecursionError:
        raise NetlistError(f"{tree.file}: subcircuits or expressions are nested too deeply "
                           "to elaborate") from None


class _Defs:
    """Subcircuit definitions visible in a scope, and the environment their instances see."""

    __slots__ = ("env", "parent", "table")

    def __init__(self, table: dict[str, ast.Subckt], parent: _Defs | None, env: Env) -> None:
        self.table, self.parent, self.env = table, parent, env

    def find(self, name: str) -> tuple[ast.Subckt, _Defs] | None:
        """The definition of `name` nearest to this scope, and the scope that holds it."""
        defs: _Defs | None = self
        while defs is not None:
            if name in defs.table:
                return defs.table[name], defs
            defs = defs.parent
        return None

    def names(self) -> set[str]:
        """Every subcircuit name visible here (for suggestions)."""
        out, defs = set(), self
        while defs is not None:
            out.update(defs.table)
            defs = defs.parent
        return out


@dataclass(frozen=True, slots=True)
class _Scope:
    """Where statements are elaborated: instance path, port bindings, names in scope."""

    path: str
    ports: dict[str, str]
    env: Env
    defs: _Defs
    stack: tuple[ast.Subckt, ...]  # subcircuits being instantiated, for recursion errors

    @property
    def prefix(self) -> str:
        return self.path + "." if self.path else ""


def _within(err: NetlistError, path: str) -> NetlistError:
    """`err` with the instance path added to its location, unless it already has one."""
    if err.loc is None or err.loc.instance or not path:
        return err
    return NetlistError(err.message, replace(err.loc, instance=path), err.diagnostic.hint)


class _Elaborator:
    """The state of one elaboration: the IR being built and the names declared so far."""

    def __init__(self, main_file: str, lib_dirs: list[Path] | None,
                 sample: draws.Sample | None = None) -> None:
        self.main = main_file
        # where random calls draw: a site per element and instance, keyed per value (None
        # outside a sample, so that a nominal elaboration makes no extra scopes)
        self.site = draws.Site(sample, "") if sample is not None else None
        self.includes = Includes(lib_dirs)
        self.b = IRBuilder(title="", file=main_file)
        self.elements: dict[str, SourceLoc] = {}
        self.nodes: set[str] = set()
        self.aliases: dict[str, str] = {}  # `X1.port` -> the node bound to it
        self.deferred: list = []  # probes and .ac, resolved once every node exists
        self.title_loc: SourceLoc | None = None
        self.data: dict[str, np.ndarray] = {}
        self.progress: _Progress | None = None  # of the outermost general .for running

    def run(self, tree: ast.Netlist) -> FlatNetlist:
        body = self.includes.expand(tree)
        env = Env(site=self.site)
        self._body(body, _Scope("", {}, env, self._defs(body, None, env), ()))
        for resolve in self.deferred:
            resolve()
        return self.b.finish()

    # --- statements ----------------------------------------------------------------------

    def _defs(self, body, parent: _Defs | None, env: Env) -> _Defs:
        """The definitions visible in `body`: its own `.subckt`s, then the enclosing ones."""
        table: dict[str, ast.Subckt] = {}
        for stmt in body:
            if isinstance(stmt, ast.Subckt):
                if stmt.name in table:
                    first = table[stmt.name].loc
                    raise NetlistError(f"duplicate subcircuit '{stmt.name}' (first defined at "
                                       f"{first})", stmt.loc, "rename one of them")
                table[stmt.name] = stmt
        if not table and parent is not None:
            return parent
        return _Defs(table, parent, env)

    def _body(self, stmts, scope: _Scope) -> None:
        # parameters and data first (in their order), as in SPICE: an element may use a
        # parameter defined below it in the same scope
        for stmt in stmts:
            if isinstance(stmt, ast.Directive) and stmt.name in _FIRST:
                self._directive(stmt, scope)
        for stmt in stmts:
            match stmt:
                case ast.Element():
                    self._element(stmt, scope)
                case ast.Directive():
                    if stmt.name not in _FIRST:
                        self._directive(stmt, scope)
                case ast.For():
                    self._loop(stmt, scope)
                case ast.Subckt():
                    pass  # collected by _defs before the body runs
                case ast.Title():
                    self._title(stmt, scope)
                case _:
                    raise TypeError(f"unknown statement {stmt!r}")

    def _loc(self, loc: SourceLoc, scope: _Scope) -> SourceLoc:
        return SourceLoc(loc.file, loc.line, loc.col, scope.path) if scope.path else loc

    def _title(self, stmt: ast.Title, scope: _Scope) -> None:
        if stmt.loc.file != self.main:
            return  # a library file's title does not name the netlist including it
        if scope.path or self.title_loc is not None:
            where = "inside a subcircuit" if scope.path else f"twice (first at {self.title_loc})"
            raise NetlistError(f".title given {where}", stmt.loc)
        self.title_loc = stmt.loc
        self.b.title = stmt.text

    def _loop(self, stmt: ast.For, scope: _Scope) -> None:
        first = int_value(stmt.first, scope.env, "the first .for bound")
        last = int_value(stmt.last, scope.env, "the last .for bound")
        if last - first + 1 > MAX_LOOP:
            raise NetlistError(f".for {stmt.var} runs {last - first + 1} times "
                               f"(more than {MAX_LOOP})", stmt.loc, "check the bounds")
        if self.site is None and self._loop_rows(stmt, scope):
            return  # a Monte Carlo sample draws per element: only the general path does that
        progress = None if self.progress else _Progress(stmt, last - first + 1)
        self.progress = self.progress or progress
        try:
            for i in range(first, last + 1):  # last < first: no iteration (libraries rely on it)
                env = Env({stmt.var: float(i)}, scope.env)
                self._body(stmt.body,
                           _Scope(scope.path, scope.ports, env, scope.defs, scope.stack))
                if progress is not None:
                    progress.update(i - first + 1)
        finally:
            if progress is not None:
                progress.close()
                self.progress = None

    def _loop_rows(self, stmt: ast.For, scope: _Scope) -> bool:
        """Elaborate a regular loop as arrays (`loops.expand`): False, with nothing changed,
        where the general path must do it (irregular, or an error to report)."""
        block = loops.expand(stmt, scope.env)
        if block is None:
            return False
        if not block:
            return True  # no iteration
        full, columns = [], []
        for rows in block:
            nodes = [None if c is None else self._resolve(c, scope) for c in rows.nodes]
            if rows.letter == "B" and nodes[0] is None:
                nodes.reverse()  # the dashpot is symmetric; the IR wants ground second
            for k, column in enumerate(nodes):
                # ground where it is not allowed (the general path says so), or a port bound
                # to ground (rare: left to the general path, as `node_rows` takes no '0')
                if (column is None and (rows.letter != "B" or k == 0)
                        or column is not None and "0" in column):
                    return False
            full.append([scope.prefix + n for n in rows.names] if scope.path else rows.names)
            columns.append(nodes)
        locs = [self._loc(rows.stmt.loc, scope) for rows in block]
        if not self._declare_rows(full, locs):
            return False
        self._add_rows(block, full, columns, locs)
        return True

    def _declare_rows(self, full: list[list[str]], locs: list[SourceLoc]) -> bool:
        """`_declare` for a loop's elements; False, with nothing declared, for a duplicate
        name (the general path reports the first one)."""
        before = len(self.elements)
        if not all(self.elements.keys().isdisjoint(names) for names in full):
            return False
        for names, loc in zip(full, locs):
            self.elements.update(zip(names, itertools.repeat(loc)))
        if len(self.elements) == before + sum(map(len, full)):
            return True
        for name in itertools.chain.from_iterable(full):  # each new: they were disjoint
            self.elements.pop(name, None)
        return False

    def _resolve(self, names: list[str], scope: _Scope) -> list[str]:
        """`_node` of each name written in `scope`."""
        ports, prefix, aliases = scope.ports, scope.prefix, self.aliases
        if not ports and not aliases:
            return [prefix + n for n in names] if prefix else names
        out = []
        for name in names:
            bound = ports.get(name)
            if bound is None:
                bound = aliases.get(prefix + name, prefix + name)
            out.append(bound)
        return out

    def _add_rows(self, block: list[loops.Rows], full: list[list[str]], columns: list[list],
                  locs: list[SourceLoc]) -> None:
        """Add a loop's rows as the general path would: nodes met iteration by iteration,
        and within each kind the lines of one iteration after those of the one before."""
        flat = [c for nodes in columns for c in nodes]
        indices, new = self.b.node_rows(flat, [loc for loc, nodes in zip(locs, columns)
                                               for _ in nodes])
        self.nodes.update(new)
        index = iter(indices)
        tables: dict[str, list] = {}
        for rows, names, loc, nodes in zip(block, full, locs, columns):
            spec = SPECS[rows.letter]
            values = [rows.values[key] for key in (*spec.required, *spec.optional)]
            tables.setdefault(rows.letter, []).append(
                (names, loc, [next(index) for _ in nodes] + values))
        for letter, lines in tables.items():
            names = (lines[0][0] if len(lines) == 1 else
                     list(itertools.chain.from_iterable(zip(*(line[0] for line in lines)))))
            lineloc = [line[1] for line in lines]
            arrays = [np.stack(c, axis=1).ravel() for c in zip(*(line[2] for line in lines))]
            self.b.rows(letter, names, lineloc * len(lines[0][0]), *arrays)

    # --- names ---------------------------------------------------------------------------

    def _node(self, arg: ast.Value, scope: _Scope) -> str:
        """The full name of the node `arg` names in `scope` (`0` is ground)."""
        if isinstance(arg, ast.Num) and arg.text == "0":
            return GROUND
        if not isinstance(arg, ast.Word):
            raise NetlistError("expected a node name", arg.loc,
                               "node names start with a letter or '_'; 0 is ground")
        name = name_text(arg, scope.env)
        bound = scope.ports.get(name)
        if bound is not None:
            return bound
        full = scope.prefix + name
        return self.aliases.get(full, full)

    def _declare(self, full: str, loc: SourceLoc) -> None:
        first = self.elements.get(full)
        if first is not None:
            raise NetlistError(f"duplicate element name '{full}' (first defined at {first})",
                               loc, "element names must be unique within a (sub)circuit")
        self.elements[full] = loc

    def _no_ground(self, nodes: list[str], name: str, letter: str, loc: SourceLoc) -> None:
        if GROUND in nodes:
            raise NetlistError(f"{name}: a {SPECS[letter].what} cannot connect to ground (0)",
                               loc, "only a dashpot B may have ground as a node")

    # --- elements ------------------------------------------------------------------------

    def _element(self, stmt: ast.Element, scope: _Scope) -> None:
        name = name_text(stmt.name, scope.env)
        letter = name[0].upper()
        if letter not in elements.LETTERS:
            raise NetlistError(f"unknown element letter '{name[0]}' in '{name}'", stmt.loc,
                               elements.LETTERS_HINT)
        full = scope.prefix + name
        loc = self._loc(stmt.loc, scope)
        self._declare(full, loc)
        if letter == "X":
            self._instance(stmt, full, loc, scope)
            return
        plain, keywords, calls, factors = elements.split_args(stmt.args)
        elements.check_kinds(name, letter, calls, factors)
        p = elements.params(name, SPECS[letter], keywords, self._sited(scope.env, full),
                            stmt.loc)
        if letter == "P":
            self._monomial(full, plain, factors, p["c"], loc, scope, stmt.loc)
        elif letter == "F":
            src = elements.force_source(name, plain, calls, scope.env, stmt.loc)
            (node,) = self._nodes(name, letter, plain[:1] if not calls else plain, scope, stmt)
            self.b.force(full, node, src, p["gain"], loc=loc)
        else:
            self._potential(letter, full, self._nodes(name, letter, plain, scope, stmt), p, loc)

    def _nodes(self, name: str, letter: str, plain: list, scope: _Scope,
               stmt: ast.Element) -> list[str]:
        """The element's nodes: checked in number, resolved, ground only where allowed."""
        elements.node_count(name, SPECS[letter], plain, SPECS[letter].nodes, stmt.loc)
        nodes = [self._node(v, scope) for v in plain]
        if letter == "B" and nodes[0] == GROUND:
            nodes.reverse()  # the dashpot is symmetric; the IR wants ground second
        self._no_ground(nodes[:1] if letter == "B" else nodes, name, letter, stmt.loc)
        self.nodes.update(n for n in nodes if n != GROUND)
        return nodes

    def _potential(self, letter: str, full: str, nodes: list[str], p: dict,
                   loc: SourceLoc) -> None:
        b = self.b
        match letter:
            case "M":
                b.mass(full, nodes[0], p["m"], p["b"], p["x0"], p["v0"], loc=loc)
            case "K":
                b.spring(full, nodes[0], p["k"], loc=loc)
            case "D":
                b.duffing(full, nodes[0], p["l"], loc=loc)
            case "C":
                b.coupling(full, nodes[0], nodes[1], p["k"], p["a"], loc=loc)
            case "Q":
                b.quad(full, nodes[0], nodes[1], p["g"], p["a"], loc=loc)
            case "B":
                b.dashpot(full, nodes[0], nodes[1], p["b"], loc=loc)
            case _:
                raise TypeError(f"not a two-terminal letter: {letter}")

    def _monomial(self, full: str, plain: list, factors: list, c: float, loc: SourceLoc,
                  scope: _Scope, at: SourceLoc) -> None:
        if plain:
            raise NetlistError(f"{full}: a monomial takes factors node^n, not a bare value",
                               plain[0].loc, "write e.g. a^2 b^1")
        if not factors:
            raise NetlistError(f"{full}: a monomial needs at least one factor node^n", at,
                               "write e.g. P1 c=1 a^2 b^2")
        out = []
        for factor in factors:
            node = self._node(factor.node, scope)
            self._no_ground([node], full, "P", factor.loc)
            out.append((node, int_value(factor.exponent, scope.env, "an exponent")))
        self.nodes.update(n for n, _ in out)
        self.b.monomial(full, c, out, loc=loc)

    # --- instances -----------------------------------------------------------------------

    def _instance(self, stmt: ast.Element, full: str, loc: SourceLoc, scope: _Scope) -> None:
        plain, keywords, calls, factors = elements.split_args(stmt.args)
        if calls or factors or not plain or not isinstance(plain[-1], ast.Word):
            raise NetlistError(f"{full}: an instance takes nodes, a subcircuit name and "
                               "name=value overrides", stmt.loc, "e.g. X1 in out filt f0=1k")
        sub, defs = self._lookup_subckt(plain[-1], scope)
        self._no_recursion(sub, scope, stmt.loc)
        nodes = [self._node(v, scope) for v in plain[:-1]]
        if len(nodes) != len(sub.ports):
            ports = " ".join(p.parts[0] for p in sub.ports)
            raise NetlistError(f"{full}: subcircuit '{sub.name}' has {len(sub.ports)} port(s) "
                               f"({ports}) but {len(nodes)} node(s) were given", stmt.loc,
                               f"defined at {sub.loc}")
        overrides = self._overrides(full, sub, keywords, self._sited(scope.env, full))
        self.b.instances.append(Instance(full, sub.name, loc))
        ports = {p.parts[0]: n for p, n in zip(sub.ports, nodes)}
        self._alias(full, ports, stmt.loc)
        try:
            env = self._instance_env(sub, overrides, self._sited(defs.env, full))
            inner = _Scope(full, ports, env, self._defs(sub.body, defs, env),
                           scope.stack + (sub,))
            self._body(sub.body, inner)
        except NetlistError as err:
            raise _within(err, full) from None

    def _sited(self, env: Env, path: str) -> Env:
        """`env` with a site of its own at `path` in a Monte Carlo sample (random calls in
        the values of that element or instance draw there), else `env` itself."""
        return env if self.site is None else Env({}, env, self.site.keyed(None, path))

    def _lookup_subckt(self, word: ast.Word, scope: _Scope) -> tuple[ast.Subckt, _Defs]:
        name = name_text(word, scope.env)
        found = scope.defs.find(name)
        if found is None:
            guess = closest(name, scope.defs.names())
            hint = (f"did you mean '{guess}'?" if guess else
                    "define it with .subckt, or .include the file that does")
            raise NetlistError(f"unknown subcircuit '{name}'", word.loc, hint)
        return found

    def _no_recursion(self, sub: ast.Subckt, scope: _Scope, loc: SourceLoc) -> None:
        # by identity: a nested definition may reuse an outer subcircuit's name
        seen = [s is sub for s in scope.stack]
        if any(seen):
            names = [s.name for s in scope.stack[seen.index(True):]] + [sub.name]
            raise NetlistError(f"recursive instantiation: {' -> '.join(names)}", loc,
                               "a subcircuit cannot contain itself")

    def _overrides(self, full: str, sub: ast.Subckt, keywords, env: Env) -> dict[str, float]:
        """Instance parameters, evaluated in the caller's scope."""
        declared = [p.key for p in sub.params]
        out: dict[str, float] = {}
        for kw in keywords:
            if kw.key not in declared:
                guess = closest(kw.key, declared)
                hint = (f"did you mean '{guess}'?" if guess else
                        f"its parameters: {', '.join(declared) or 'none'}")
                raise NetlistError(f"{full}: subcircuit '{sub.name}' has no parameter "
                                   f"'{kw.key}'", kw.loc, hint)
            if kw.key in out:
                raise NetlistError(f"{full}: parameter '{kw.key}' given twice", kw.loc)
            out[kw.key] = value(kw.value, keyed(env, kw.key))
        return out

    def _instance_env(self, sub: ast.Subckt, overrides: dict, parent: Env) -> Env:
        """Parameters of one instance: overrides, else defaults (which may use earlier ones
        and the global parameters)."""
        env = Env({}, parent, parent.site)  # a default draws at the instance's site
        for param in sub.params:
            given = overrides.get(param.key)
            env.vars[param.key] = (given if given is not None
                                   else value(param.value, keyed(env, param.key)))
        return env

    def _alias(self, full: str, ports: dict[str, str], loc: SourceLoc) -> None:
        for port, node in ports.items():
            key = f"{full}.{port}"
            if key in self.nodes:
                raise NetlistError(f"node '{key}' was used before {full} was instantiated, but "
                                   f"'{port}' is a port of it", loc,
                                   "name the node connected to the port instead")
            self.aliases[key] = node

    # --- directives ----------------------------------------------------------------------

    def _directive(self, stmt: ast.Directive, scope: _Scope) -> None:
        handler = {
            "param": self._param, "data": self._data, "probe": self._probe,
            "tran": self._tran, "ac": self._ac, "noise": self._noise,
            "options": self._options, "step": _variation, "mc": _variation,
        }.get(stmt.name)
        if handler is None:
            raise _unknown_directive(stmt)
        if stmt.name in TOP_ONLY and scope.path:
            raise NetlistError(f".{stmt.name} is only allowed at the top level, not inside a "
                               "subcircuit", stmt.loc)
        handler(stmt, scope)

    def _param(self, stmt: ast.Directive, scope: _Scope) -> None:
        if not stmt.args:
            raise NetlistError(".param needs name=value", stmt.loc)
        for arg in stmt.args:
            if not isinstance(arg, ast.Keyword):
                raise NetlistError(".param takes name=value pairs", arg.loc,
                                   "e.g. .param f0=1k w={2*pi*f0}")
            if arg.key in CONSTANTS:
                raise NetlistError(f"'{arg.key}' is a built-in constant and cannot be "
                                   "redefined", arg.loc)
            scope.env.vars[arg.key] = value(arg.value, keyed(scope.env, arg.key))

    def _data(self, stmt: ast.Directive, scope: _Scope) -> None:
        args = stmt.args
        if (len(args) != 2 or not isinstance(args[0], ast.Word) or not args[0].plain
                or not isinstance(args[1], ast.Str)):
            raise NetlistError(".data takes a name and a quoted file name", stmt.loc,
                               'write .data W "weights.npy" (or .csv)')
        path = beside(args[1])
        key = str(path.resolve())
        if key not in self.data:
            self.data[key] = read_array(path, args[1].loc)
        scope.env.vars[args[0].parts[0]] = self.data[key]

    def _probe(self, stmt: ast.Directive, scope: _Scope) -> None:
        if not stmt.args:
            raise NetlistError(".probe needs x(node) or v(node)", stmt.loc)
        for arg in stmt.args:
            if not isinstance(arg, ast.CallArg):
                raise NetlistError("a probe is written x(node) or v(node)", arg.loc)
            quantity = arg.name.lower()
            if quantity not in ("x", "v"):
                raise NetlistError(f"unknown probe quantity '{arg.name}'", arg.loc,
                                   "probe x(node) (position) or v(node) (velocity)")
            if len(arg.args) != 1:
                raise NetlistError(f"{arg.name}() takes one node", arg.loc)
            written = self._written(arg.args[0], scope.env)
            node = self._node(arg.args[0], scope)
            loc = self._loc(arg.loc, scope)
            label = f"{arg.name}({scope.prefix}{written})"
            self.deferred.append(lambda q=quantity, n=node, lb=label, lc=loc, w=written:
                                 self._add_probe(q, n, lb, lc, w))

    def _written(self, arg: ast.Value, env: Env) -> str:
        """A node as written (interpolations evaluated), for labels and messages."""
        if isinstance(arg, ast.Word):
            return name_text(arg, env)
        return arg.text if isinstance(arg, ast.Num) else "{...}"

    def _add_probe(self, quantity: str, node: str, label: str, loc: SourceLoc,
                   written: str) -> None:
        self._known_node(node, written, loc)
        if any(p.label == label for p in self.b.probes):
            raise NetlistError(f"duplicate probe {label}", loc)
        self.b.probe(quantity, node, label, loc=loc)

    def _known_node(self, node: str, written: str, loc: SourceLoc) -> None:
        """An error for ground, and for a hierarchical name (`X1.a`) that names no node of
        the instance. A plain name that no element names still becomes a node (the checks
        report that it has no mass)."""
        if node == GROUND:
            raise NetlistError(f"'{written}' is ground, which does not move", loc)
        if node not in self.nodes and "." in written:
            guess = closest(node, self.nodes)
            hint = (f"did you mean '{guess}'?" if guess else
                    f"no element of {written.rsplit('.', 1)[0]} names a node "
                    f"'{written.rsplit('.', 1)[1]}'")
            raise NetlistError(f"unknown node '{written}'", loc, hint)

    def _tran(self, stmt: ast.Directive, scope: _Scope) -> None:
        if self.b.tran is not None:
            raise NetlistError(f"a second .tran (the first is at {self.b.tran.loc})", stmt.loc)
        if len(stmt.args) != 2 or not all(_is_value(a) for a in stmt.args):
            raise NetlistError(".tran takes a time step and a stop time", stmt.loc,
                               "write .tran TSTEP TSTOP, e.g. .tran 10u 1")
        tstep, tstop = (value(a, scope.env) for a in stmt.args)
        for arg, number, what in ((stmt.args[0], tstep, "step"), (stmt.args[1], tstop, "stop")):
            if not number > 0:
                raise NetlistError(f".tran {what} time must be > 0, got {number:g}", arg.loc)
        self.b.tran = Tran(tstep, tstop, stmt.loc)

    def _ac(self, stmt: ast.Directive, scope: _Scope) -> None:
        self._sweep(stmt, scope, AcSpec, self.b.acs)

    def _noise(self, stmt: ast.Directive, scope: _Scope) -> None:
        self._sweep(stmt, scope, NoiseSpec, self.b.noises)

    def _sweep(self, stmt: ast.Directive, scope: _Scope, kind: type, into: list) -> None:
        """`.ac` or `.noise`: NODE FSTART FSTOP [points=] [input=], the node resolved once
        every node exists."""
        what = f".{stmt.name}"
        plain, keywords, calls, factors = elements.split_args(stmt.args)
        if len(plain) != 3 or calls or factors:
            raise NetlistError(f"{what} takes a node, a start and a stop frequency", stmt.loc,
                               f"write {what} NODE FSTART FSTOP [points=200] [input=0]")
        written, node = self._written(plain[0], scope.env), self._node(plain[0], scope)
        fstart, fstop = (value(v, scope.env) for v in plain[1:])
        if not 0 < fstart <= fstop:
            raise NetlistError(f"{what} needs 0 < fstart <= fstop, got {fstart:g} and "
                               f"{fstop:g}", plain[1].loc)
        opts = self._sweep_options(what, keywords, scope.env)
        if fstart < fstop and opts["points"] < 2:  # a band has two ends
            raise NetlistError(f"{what} from {fstart:g} to {fstop:g} Hz needs points >= 2, got "
                               f"{opts['points']}", stmt.loc,
                               "a single frequency is written with fstart = fstop")

        def resolve() -> None:
            self._known_node(node, written, plain[0].loc)
            into.append(kind(self.b.node(node, plain[0].loc), fstart, fstop, opts["points"],
                             opts["input"], stmt.loc))

        self.deferred.append(resolve)

    def _sweep_options(self, what: str, keywords: list, env: Env) -> dict[str, int]:
        opts = {"points": 200, "input": 0}
        for kw in keywords:
            key = kw.key.lower()
            if key not in opts:
                raise NetlistError(f"{what} has no parameter '{kw.key}'", kw.loc,
                                   "it takes points= and input=")
            low = 1 if key == "points" else 0
            opts[key] = number = int_value(kw.value, env, kw.key)
            if number < low:
                raise NetlistError(f"{what} {kw.key} must be >= {low}, got {number}",
                                   kw.value.loc)
        return opts

    def _options(self, stmt: ast.Directive, scope: _Scope) -> None:
        for arg in stmt.args:
            if not isinstance(arg, ast.Keyword):
                raise NetlistError(".options takes key=value pairs", arg.loc)
            key = arg.key.lower()
            spec = KNOWN_OPTIONS.get(key)
            if spec is None:
                guess = closest(key, KNOWN_OPTIONS)
                hint = (f"did you mean '{guess}'? " if guess else "") + \
                    f"known options: {', '.join(KNOWN_OPTIONS)}"
                raise NetlistError(f"unknown option '{arg.key}'", arg.loc, hint)
            if key in self.b.option_locs:
                raise NetlistError(f"option '{key}' set twice (first at "
                                   f"{self.b.option_locs[key]})", arg.loc)
            self.b.options[key] = _option_value(spec, arg.value, scope.env)
            self.b.option_locs[key] = arg.loc


class _Progress:
    """A tqdm bar on stderr (iterations per second, time left) for a general `.for` that has
    run `SHOW_PROGRESS_AFTER` seconds; nothing for a shorter one."""

    def __init__(self, loop: ast.For, total: int) -> None:
        self.loop, self.total = loop, total
        self.start = time.monotonic()
        self.bar = None

    def update(self, done: int) -> None:
        if self.bar is not None:
            self.bar.update(done - self.bar.n)
        elif time.monotonic() - self.start > SHOW_PROGRESS_AFTER:
            from tqdm import tqdm

            self.bar = tqdm(total=self.total, initial=done, file=sys.stderr, unit="it",
                            desc=f"elaborating .for {self.loop.var} ({self.loop.loc})",
                            leave=False)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _variation(stmt: ast.Directive, scope: _Scope) -> None:
    """`.step` and `.mc` define the points (`springc.lang.variation`); one elaboration is one
    point, so they set nothing here."""


def _option_value(spec: OptionSpec, arg: ast.Value, env: Env) -> object:
    if spec.word:
        if not (isinstance(arg, ast.Word) and arg.plain) and not isinstance(arg, ast.Str):
            raise NetlistError(f"option '{spec.name}' takes a word", arg.loc, spec.description)
        raw: object = arg.text
    else:
        raw = value(arg, env)
    try:
        return spec.convert(raw)
    except OptionValueError as exc:
        raise NetlistError(str(exc), arg.loc) from None


def _is_value(arg) -> bool:
    return isinstance(arg, (ast.Num, ast.Word, ast.Brace))


def _check_directive_names(statements) -> None:
    """Reject unknown directives everywhere, also in bodies never elaborated (a loop that runs
    zero times, a subcircuit never instantiated): a misspelt directive is always a mistake."""
    for stmt in statements:
        if isinstance(stmt, ast.Directive) and stmt.name not in DIRECTIVES:
            raise _unknown_directive(stmt)
        if isinstance(stmt, (ast.For, ast.Subckt)):
            _check_directive_names(stmt.body)


def _unknown_directive(stmt: ast.Directive) -> NetlistError:
    guess = closest(stmt.name, DIRECTIVES)
    hint = f"did you mean '.{guess}'?" if guess else f"known: .{', .'.join(DIRECTIVES)}"
    return NetlistError(f"unknown directive '.{stmt.name}'", stmt.loc, hint)
