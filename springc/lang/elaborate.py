"""AST to flat IR: `elaborate(tree, lib_dirs) -> FlatNetlist`.

One pass over the statements, in order, with a scope per subcircuit instance (parameters,
port bindings, visible definitions) and a child scope per `.for` iteration. Includes are
spliced in first, so subcircuits may be used before they are defined. Local nodes and element
names get the instance path as prefix (`X1.X2.a`); a port name resolves to the node the
instance line bound it to. Probes and `.ac` outputs are resolved at the end, once every node
exists. Physics (signs, masses, stability) is left to `springc.checks`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from springc.errors import NetlistError, SourceLoc
from springc.ir import AcSpec, FlatNetlist, Instance, IRBuilder, Source, Tran
from springc.lang import ast
from springc.lang.expr import CONSTANTS, Env, closest, integer, scalar, undefined
from springc.lang.options import KNOWN_OPTIONS, OptionValueError

STDLIB_DIR = Path(__file__).resolve().parents[2] / "netlists" / "lib"
GROUND = "0"
MAX_LOOP = 10_000_000  # iterations of one .for; more is surely a mistake in the bounds


@dataclass(frozen=True)
class _Spec:
    """What an element letter takes: number of nodes, required and optional parameters."""

    what: str
    nodes: int
    required: tuple[str, ...]
    optional: dict[str, float]


SPECS = {
    "M": _Spec("mass", 1, ("m",), {"b": 0.0, "x0": 0.0, "v0": 0.0}),
    "K": _Spec("spring", 1, ("k",), {}),
    "D": _Spec("Duffing spring", 1, ("l",), {}),
    "C": _Spec("coupling", 2, ("k",), {"a": 1.0}),
    "Q": _Spec("quadratic coupling", 2, ("g",), {"a": 1.0}),
    "B": _Spec("dashpot", 2, ("b",), {}),
    "P": _Spec("monomial", 0, ("c",), {}),
    "F": _Spec("force", 1, (), {"gain": 1.0}),
}
LETTERS = "MKDCQBPFX"
DIRECTIVES = ("title", "param", "data", "include", "subckt", "ends", "for", "endfor", "probe",
              "tran", "ac", "options", "end")
# name -> (smallest, largest) number of arguments
SOURCE_ARITY = {"in": (0, 1), "sin": (2, 3), "gauss": (3, 3), "step": (2, 2),
                "pwl": (2, None), "wav": (1, 2)}
_SOURCE_HINTS = {
    "in": "in(k): channel k of the simulator's input signals (default 0)",
    "sin": "sin(amp freq [phase]): amp sin(2 pi freq t + phase)",
    "gauss": "gauss(amp t0 sigma): amp exp(-(t - t0)^2 / (2 sigma^2))",
    "step": "step(amp t0)",
    "pwl": "pwl(t1 v1 t2 v2 ...): pairs with increasing times",
    "wav": 'wav("file.wav" [channel]): a sound file, path relative to the netlist',
}


def search_dirs(lib_dirs: list[Path] | None = None) -> list[Path]:
    """Folders searched for `.include` after the including file's own folder: `lib_dirs`,
    the standard library, then the folders of the SPRINGC_PATH environment variable."""
    extra = [Path(p) for p in os.environ.get("SPRINGC_PATH", "").split(os.pathsep) if p]
    return [Path(p) for p in (lib_dirs or [])] + [STDLIB_DIR] + extra


def elaborate(tree: ast.Netlist, lib_dirs: list[Path] | None = None) -> FlatNetlist:
    """Flatten a parsed netlist (with its includes and subcircuits) into a `FlatNetlist`."""
    return _Elaborator(tree.file, lib_dirs).run(tree)


class _Defs:
    """Subcircuit definitions visible in a scope, and the environment their instances see."""

    __slots__ = ("env", "parent", "table")

    def __init__(self, table: dict[str, ast.Subckt], parent: _Defs | None, env: Env) -> None:
        self.table, self.parent, self.env = table, parent, env

    def find(self, name: str) -> tuple[ast.Subckt, _Defs] | None:
        defs: _Defs | None = self
        while defs is not None:
            if name in defs.table:
                return defs.table[name], defs
            defs = defs.parent
        return None

    def names(self) -> set[str]:
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
    stack: tuple[str, ...]  # subcircuits being instantiated, for recursion errors

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

    def __init__(self, main_file: str, lib_dirs: list[Path] | None) -> None:
        self.main = main_file
        self.dirs = search_dirs(lib_dirs)
        self.b = IRBuilder(title="", file=main_file)
        self.elements: dict[str, SourceLoc] = {}
        self.nodes: set[str] = set()
        self.aliases: dict[str, str] = {}  # `X1.port` -> the node bound to it
        self.deferred: list = []  # probes and .ac, resolved once every node exists
        self.title_loc: SourceLoc | None = None
        self.parsed: dict[str, ast.Netlist] = {}
        self.data: dict[str, np.ndarray] = {}

    def run(self, tree: ast.Netlist) -> FlatNetlist:
        body = self._expand(tree.statements, (self._key(tree.file),), set())
        env = Env()
        scope = _Scope("", {}, env, self._defs(body, None, env), ())
        self._body(body, scope)
        for resolve in self.deferred:
            resolve()
        return self.b.finish()

    # --- includes ------------------------------------------------------------------------

    def _key(self, file: str) -> str:
        path = Path(file)
        return str(path.resolve()) if path.is_file() else file

    def _expand(self, stmts, chain: tuple[str, ...], seen: set[str]) -> list:
        """`stmts` with every `.include` replaced by the included statements (each file once
        per scope), recursing into blocks."""
        out: list = []
        for stmt in stmts:
            match stmt:
                case ast.Directive(name="include"):
                    out.extend(self._include(stmt, chain, seen))
                case ast.Subckt(body=body):
                    out.append(replace(stmt, body=tuple(self._expand(body, chain, set()))))
                case ast.For(body=body):
                    out.append(replace(stmt, body=tuple(self._expand(body, chain, seen))))
                case _:
                    out.append(stmt)
        return out

    def _include(self, stmt: ast.Directive, chain: tuple[str, ...], seen: set[str]) -> list:
        if len(stmt.args) != 1 or not isinstance(stmt.args[0], ast.Str):
            raise NetlistError('.include takes one quoted file name', stmt.loc,
                               'write .include "file.spr"')
        path = self._find_include(stmt.args[0])
        key = str(path)
        if key in chain:
            names = " -> ".join(Path(k).name for k in chain[chain.index(key):] + (key,))
            raise NetlistError(f"include cycle: {names}", stmt.loc,
                               "remove one of the .include lines")
        if key in seen:
            return []
        seen.add(key)
        tree = self._parse_file(path, stmt.args[0])
        return self._expand(tree.statements, chain + (key,), seen)

    def _find_include(self, name: ast.Str) -> Path:
        here = Path(name.loc.file).parent
        candidates = [here] + self.dirs
        for folder in candidates:
            path = folder / name.text
            if path.is_file():
                return path.resolve()
        looked = ", ".join(str(d) for d in candidates)
        raise NetlistError(f"cannot find include file '{name.text}'", name.loc,
                           f"looked in: {looked}")

    def _parse_file(self, path: Path, name: ast.Str) -> ast.Netlist:
        from springc.lang.parser import parse

        key = str(path)
        if key not in self.parsed:
            try:
                text = path.read_text(encoding="utf-8")
            except (OSError, UnicodeDecodeError) as exc:
                raise NetlistError(f"cannot read include file '{path}': {exc}", name.loc) from None
            self.parsed[key] = parse(text, _display(path))
        return self.parsed[key]

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
        for stmt in stmts:
            match stmt:
                case ast.Element():
                    self._element(stmt, scope)
                case ast.Directive():
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
        first = self._int(stmt.first, scope.env, "the first .for bound")
        last = self._int(stmt.last, scope.env, "the last .for bound")
        if last - first + 1 > MAX_LOOP:
            raise NetlistError(f".for {stmt.var} runs {last - first + 1} times "
                               f"(more than {MAX_LOOP})", stmt.loc, "check the bounds")
        for i in range(first, last + 1):
            env = Env({stmt.var: float(i)}, scope.env)
            self._body(stmt.body, _Scope(scope.path, scope.ports, env, scope.defs, scope.stack))

    # --- values and names ----------------------------------------------------------------

    def _value(self, value: ast.Value, env: Env) -> float:
        match value:
            case ast.Num(value=number):
                return number
            case ast.Brace(expr=expr):
                return scalar(expr, env)
            case ast.Word():
                name = self._text(value, env)
                found = env.lookup(name)
                if found is None:
                    raise undefined(name, value.loc, env)
                if isinstance(found, np.ndarray):
                    raise NetlistError(f"'{name}' is an array", value.loc,
                                       f"index it in braces, e.g. {{{name}[0]}}")
                return found
            case ast.Str():
                raise NetlistError(f"expected a number, not the string \"{value.text}\"",
                                   value.loc)
            case _:
                raise NetlistError("expected a number", value.loc)

    def _int(self, value: ast.Value, env: Env, what: str) -> int:
        number = self._value(value, env)
        if not float(number).is_integer():
            raise NetlistError(f"{what} must be an integer, got {number:g}", value.loc)
        return int(number)

    def _text(self, word: ast.Word, env: Env) -> str:
        """The name `word` spells, with its `{expr}` interpolations evaluated."""
        parts = word.parts
        if len(parts) == 1 and parts[0].__class__ is str:
            return parts[0]
        out = []
        for part in word.parts:
            if isinstance(part, str):
                out.append(part)
                continue
            number = integer(part, env, "an interpolation in a name")
            if number < 0:
                raise NetlistError(f"an interpolation in a name gives {number}; names take "
                                   "non-negative integers", part.loc)
            out.append(str(number))
        return "".join(out)

    def _node(self, value: ast.Value, scope: _Scope) -> str:
        """The full name of the node `value` names in `scope` (`0` is ground)."""
        if isinstance(value, ast.Num) and value.text == "0":
            return GROUND
        if not isinstance(value, ast.Word):
            raise NetlistError("expected a node name", value.loc,
                               "node names start with a letter or '_'; 0 is ground")
        name = self._text(value, scope.env)
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

    # --- elements ------------------------------------------------------------------------

    def _element(self, stmt: ast.Element, scope: _Scope) -> None:
        name = self._text(stmt.name, scope.env)
        letter = name[0].upper()
        if letter not in LETTERS:
            raise NetlistError(f"unknown element letter '{name[0]}' in '{name}'", stmt.loc,
                               "elements are M K D C Q B P F X (mass, spring, Duffing, "
                               "coupling, quadratic coupling, dashpot, monomial, force, "
                               "instance)")
        full = scope.prefix + name
        loc = self._loc(stmt.loc, scope)
        self._declare(full, loc)
        if letter == "X":
            self._instance(stmt, full, loc, scope)
            return
        spec = SPECS[letter]
        plain, keywords, calls, factors = _split(stmt.args)
        if calls and letter != "F":
            raise NetlistError(f"a {spec.what} ({letter}) takes no source or call "
                               f"'{calls[0].name}(...)'", calls[0].loc)
        if factors and letter != "P":
            raise NetlistError(f"a {spec.what} ({letter}) takes no factor 'node^n'",
                               factors[0].loc)
        params = self._params(name, spec, keywords, scope.env, stmt.loc)
        self._build(letter, name, full, plain, calls, factors, params, loc, scope, stmt)

    def _params(self, name: str, spec: _Spec, keywords, env: Env, loc: SourceLoc) -> dict:
        """The element's parameter values: defaults, then the `key=value` arguments."""
        values = dict(spec.optional)
        given: set[str] = set()
        for kw in keywords:
            key = kw.key.lower()
            if key not in values and key not in spec.required:
                known = spec.required + tuple(spec.optional)
                guess = closest(key, known)
                hint = f"did you mean '{guess}'?" if guess else f"it takes {', '.join(known)}"
                raise NetlistError(f"{name}: a {spec.what} has no parameter '{kw.key}'",
                                   kw.loc, hint)
            if key in given:
                raise NetlistError(f"{name}: parameter '{key}' given twice", kw.loc)
            given.add(key)
            values[key] = self._value(kw.value, env)
        for key in spec.required:
            if key not in given:
                raise NetlistError(f"{name}: missing parameter '{key}' of the {spec.what}",
                                   loc, f"write {key}=<value>")
        return values

    def _nodes(self, name: str, spec: _Spec, plain: list, count: int, scope: _Scope,
               loc: SourceLoc) -> list[str]:
        if len(plain) != count:
            raise NetlistError(f"{name}: a {spec.what} takes {count} node(s), "
                               f"got {len(plain)}", plain[count].loc if len(plain) > count
                               else loc)
        return [self._node(v, scope) for v in plain]

    def _no_ground(self, nodes: list[str], name: str, spec: _Spec, loc: SourceLoc) -> None:
        if GROUND in nodes:
            raise NetlistError(f"{name}: a {spec.what} cannot connect to ground (0)", loc,
                               "only a dashpot B may have ground as a node")

    def _touch(self, nodes) -> None:
        self.nodes.update(nodes)

    def _build(self, letter, name, full, plain, calls, factors, p, loc, scope, stmt) -> None:
        spec = SPECS[letter]
        b = self.b
        if letter == "P":
            self._monomial(full, plain, factors, p, loc, scope, stmt)
            return
        if letter == "F":
            source = self._source(calls, plain, name, scope.env, stmt.loc)
            plain = plain[:1] if not calls else plain  # a bare `in` is the source, not a node
        nodes = self._nodes(name, spec, plain, spec.nodes, scope, stmt.loc)
        if letter == "B":
            if nodes[0] == GROUND:
                nodes.reverse()  # the dashpot is symmetric; the IR wants ground second
            self._no_ground(nodes[:1], name, spec, stmt.loc)
        else:
            self._no_ground(nodes, name, spec, stmt.loc)
        self._touch(n for n in nodes if n != GROUND)
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
            case "F":
                b.force(full, nodes[0], source, p["gain"], loc=loc)
            case _:
                raise TypeError(letter)

    def _monomial(self, full, plain, factors, p, loc, scope, stmt) -> None:
        if plain:
            raise NetlistError(f"{full}: a monomial takes factors node^n, not "
                               f"'{_shown(plain[0])}'", plain[0].loc, "write e.g. a^2 b^1")
        if not factors:
            raise NetlistError(f"{full}: a monomial needs at least one factor node^n",
                               stmt.loc, "write e.g. P1 c=1 a^2 b^2")
        out = []
        for factor in factors:
            node = self._node(factor.node, scope)
            self._no_ground([node], full, SPECS["P"], factor.loc)
            out.append((node, self._int(factor.exponent, scope.env, "an exponent")))
        self._touch(n for n, _ in out)
        self.b.monomial(full, p["c"], out, loc=loc)

    def _source(self, calls, plain, name: str, env: Env, loc: SourceLoc) -> Source:
        """The force signal of an `F` element: a call like `sin(1 50)` or the bare word `in`."""
        if not calls:
            word = plain[1] if len(plain) == 2 else None
            if isinstance(word, ast.Word) and word.plain and word.parts[0].lower() == "in":
                return Source("in", (), 0)
            raise NetlistError(f"{name}: a force needs a node and a source", loc,
                               "e.g. F1 a in(0) gain=2, or sin(amp freq), gauss(amp t0 sigma), "
                               'step(amp t0), pwl(t1 v1 t2 v2 ...), wav("file.wav")')
        if len(calls) > 1:
            raise NetlistError(f"{name}: a force takes one source", calls[1].loc)
        return self._source_call(calls[0], env)

    def _source_call(self, call: ast.CallArg, env: Env) -> Source:
        kind = call.name.lower()
        if kind not in SOURCE_ARITY:
            guess = closest(kind, SOURCE_ARITY)
            hint = f"did you mean '{guess}'?" if guess else f"known: {', '.join(SOURCE_ARITY)}"
            raise NetlistError(f"unknown source '{call.name}'", call.loc, hint)
        low, high = SOURCE_ARITY[kind]
        n = len(call.args)
        if n < low or (high is not None and n > high):
            want = f"{low}" if low == high else (f"{low} or more" if high is None
                                                 else f"{low} to {high}")
            raise NetlistError(f"{kind}() takes {want} arguments, got {n}", call.loc,
                               _SOURCE_HINTS[kind])
        if kind == "wav":
            return self._wav(call, env)
        if kind == "in":
            channel = self._int(call.args[0], env, "an input channel") if call.args else 0
            if channel < 0:
                raise NetlistError(f"input channel must be >= 0, got {channel}", call.args[0].loc)
            return Source("in", (), channel)
        args = tuple(float(self._value(a, env)) for a in call.args)
        if kind == "sin" and n == 2:
            args += (0.0,)  # phase
        if kind == "pwl":
            self._check_pwl(call, args)
        return Source(kind, args)

    def _check_pwl(self, call: ast.CallArg, args: tuple[float, ...]) -> None:
        if len(args) % 2:
            raise NetlistError(f"pwl() takes pairs (time value), got {len(args)} numbers",
                               call.loc, _SOURCE_HINTS["pwl"])
        times = args[0::2]
        for k in range(1, len(times)):
            if not times[k] > times[k - 1]:
                raise NetlistError(f"pwl() times must increase: {times[k]:g} follows "
                                   f"{times[k - 1]:g}", call.args[2 * k].loc)

    def _wav(self, call: ast.CallArg, env: Env) -> Source:
        name = call.args[0]
        if not isinstance(name, ast.Str):
            raise NetlistError("wav() takes a quoted file name", name.loc,
                               'write wav("file.wav")')
        path = Path(name.text)
        if not path.is_absolute():
            path = Path(name.loc.file).parent / path
        if not path.is_file():
            raise NetlistError(f"wav file '{name.text}' not found (looked for {path})", name.loc)
        channel = self._int(call.args[1], env, "a channel") if len(call.args) > 1 else 0
        return Source("wav", (), channel, str(path.resolve()))

    # --- instances -----------------------------------------------------------------------

    def _instance(self, stmt: ast.Element, full: str, loc: SourceLoc, scope: _Scope) -> None:
        plain, keywords, calls, factors = _split(stmt.args)
        if calls or factors or not plain or not isinstance(plain[-1], ast.Word):
            raise NetlistError(f"{full}: an instance takes nodes, a subcircuit name and "
                               "name=value overrides", stmt.loc, "e.g. X1 in out filt f0=1k")
        sub, defs = self._lookup_subckt(plain[-1], scope)
        if sub.name in scope.stack:
            chain = " -> ".join(scope.stack[scope.stack.index(sub.name):] + (sub.name,))
            raise NetlistError(f"recursive instantiation: {chain}", stmt.loc,
                               "a subcircuit cannot contain itself")
        nodes = [self._node(v, scope) for v in plain[:-1]]
        if len(nodes) != len(sub.ports):
            ports = " ".join(p.parts[0] for p in sub.ports)
            raise NetlistError(f"{full}: subcircuit '{sub.name}' has {len(sub.ports)} port(s) "
                               f"({ports}) but {len(nodes)} node(s) were given", stmt.loc,
                               f"defined at {sub.loc}")
        overrides = self._overrides(full, sub, keywords, scope.env)
        self.b.instances.append(Instance(full, sub.name, loc))
        ports = {p.parts[0]: n for p, n in zip(sub.ports, nodes)}
        self._alias(full, ports, stmt.loc)
        try:
            env = self._instance_env(sub, overrides, defs.env)
            inner = _Scope(full, ports, env, self._defs(sub.body, defs, env),
                           scope.stack + (sub.name,))
            self._body(sub.body, inner)
        except NetlistError as err:
            raise _within(err, full) from None

    def _lookup_subckt(self, word: ast.Word, scope: _Scope) -> tuple[ast.Subckt, _Defs]:
        name = self._text(word, scope.env)
        found = scope.defs.find(name)
        if found is None:
            guess = closest(name, scope.defs.names())
            hint = (f"did you mean '{guess}'?" if guess else
                    'define it with .subckt, or .include the file that does')
            raise NetlistError(f"unknown subcircuit '{name}'", word.loc, hint)
        return found

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
            out[kw.key] = self._value(kw.value, env)
        return out

    def _instance_env(self, sub: ast.Subckt, overrides: dict, parent: Env) -> Env:
        """Parameters of one instance: overrides, else defaults (which may use earlier ones
        and the global parameters)."""
        env = Env({}, parent)
        for param in sub.params:
            value = overrides.get(param.key)
            env.vars[param.key] = value if value is not None else self._value(param.value, env)
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
            "tran": self._tran, "ac": self._ac, "options": self._options,
        }.get(stmt.name)
        if handler is None:
            raise _unknown_directive(stmt)
        if stmt.name in ("tran", "ac", "options") and scope.path:
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
            scope.env.vars[arg.key] = self._value(arg.value, scope.env)

    def _data(self, stmt: ast.Directive, scope: _Scope) -> None:
        args = stmt.args
        if (len(args) != 2 or not isinstance(args[0], ast.Word) or not args[0].plain
                or not isinstance(args[1], ast.Str)):
            raise NetlistError('.data takes a name and a quoted file name', stmt.loc,
                               'write .data W "weights.npy" (or .csv)')
        scope.env.vars[args[0].parts[0]] = self._load_data(args[1])

    def _load_data(self, name: ast.Str) -> np.ndarray:
        path = Path(name.text)
        if not path.is_absolute():
            path = Path(name.loc.file).parent / path
        key = str(path.resolve())
        if key not in self.data:
            self.data[key] = _read_array(path, name.loc)
        return self.data[key]

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
            written = scope.prefix + _shown_node(arg.args[0], self, scope.env)
            node = self._node(arg.args[0], scope)
            label = f"{arg.name}({written})"
            loc = self._loc(arg.loc, scope)
            self.deferred.append(lambda q=quantity, n=node, lb=label, lc=loc, w=written:
                                 self._add_probe(q, n, lb, lc, w))

    def _add_probe(self, quantity: str, node: str, label: str, loc: SourceLoc,
                   written: str) -> None:
        self._known_node(node, written, loc)
        if any(p.label == label for p in self.b.probes):
            raise NetlistError(f"duplicate probe {label}", loc)
        self.b.probe(quantity, node, label, loc=loc)

    def _known_node(self, node: str, written: str, loc: SourceLoc) -> None:
        if node == GROUND:
            raise NetlistError(f"'{written}' is ground, which does not move", loc)
        if node not in self.nodes:
            guess = closest(node, self.nodes)
            hint = f"did you mean '{guess}'?" if guess else "no element names this node"
            raise NetlistError(f"unknown node '{written}'", loc, hint)

    def _tran(self, stmt: ast.Directive, scope: _Scope) -> None:
        if self.b.tran is not None:
            raise NetlistError(f"a second .tran (the first is at {self.b.tran.loc})", stmt.loc)
        if len(stmt.args) != 2 or not all(_is_value(a) for a in stmt.args):
            raise NetlistError(".tran takes a time step and a stop time", stmt.loc,
                               "write .tran TSTEP TSTOP, e.g. .tran 10u 1")
        tstep, tstop = (self._value(a, scope.env) for a in stmt.args)
        for arg, value, what in ((stmt.args[0], tstep, "step"), (stmt.args[1], tstop, "stop")):
            if not value > 0:
                raise NetlistError(f".tran {what} time must be > 0, got {value:g}", arg.loc)
        self.b.tran = Tran(tstep, tstop, stmt.loc)

    def _ac(self, stmt: ast.Directive, scope: _Scope) -> None:
        plain, keywords, calls, factors = _split(stmt.args)
        if len(plain) != 3 or calls or factors:
            raise NetlistError(".ac takes a node, a start and a stop frequency", stmt.loc,
                               "write .ac NODE FSTART FSTOP [points=200] [input=0]")
        written = _shown_node(plain[0], self, scope.env)
        node = self._node(plain[0], scope)
        fstart, fstop = (self._value(v, scope.env) for v in plain[1:])
        if not 0 < fstart <= fstop:
            raise NetlistError(f".ac needs 0 < fstart <= fstop, got {fstart:g} and {fstop:g}",
                               plain[1].loc)
        opts = {"points": 200, "input": 0}
        for kw in keywords:
            if kw.key.lower() not in opts:
                raise NetlistError(f".ac has no parameter '{kw.key}'", kw.loc,
                                   "it takes points= and input=")
            low = 1 if kw.key.lower() == "points" else 0
            opts[kw.key.lower()] = value = self._int(kw.value, scope.env, kw.key)
            if value < low:
                raise NetlistError(f".ac {kw.key} must be >= {low}, got {value}", kw.value.loc)

        def resolve() -> None:
            self._known_node(node, written, plain[0].loc)
            self.b.acs.append(AcSpec(self.b.node(node), fstart, fstop, opts["points"],
                                     opts["input"], stmt.loc))

        self.deferred.append(resolve)

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
            self.b.options[key] = self._option_value(spec, arg, scope.env)
            self.b.option_locs[key] = arg.loc

    def _option_value(self, spec, arg: ast.Keyword, env: Env) -> object:
        value = arg.value
        if spec.word:
            if not (isinstance(value, ast.Word) and value.plain) and not isinstance(value, ast.Str):
                raise NetlistError(f"option '{spec.name}' takes a word", value.loc,
                                   spec.description)
            raw: object = value.text
        else:
            raw = self._value(value, env)
        try:
            return spec.convert(raw)
        except OptionValueError as exc:
            raise NetlistError(str(exc), value.loc) from None


def _split(args) -> tuple[list, list, list, list]:
    """Arguments by kind: plain values, key=value, calls, factors."""
    plain, keywords, calls, factors = [], [], [], []
    for arg in args:
        match arg:
            case ast.Keyword():
                keywords.append(arg)
            case ast.CallArg():
                calls.append(arg)
            case ast.Factor():
                factors.append(arg)
            case ast.Num() | ast.Word() | ast.Brace() | ast.Str():
                plain.append(arg)
            case _:
                raise TypeError(f"unknown argument {arg!r}")
    return plain, keywords, calls, factors


def _is_value(arg) -> bool:
    return isinstance(arg, (ast.Num, ast.Word, ast.Brace))


def _shown(value) -> str:
    match value:
        case ast.Num(text=text):
            return text
        case ast.Word():
            return value.text
        case ast.Str(text=text):
            return f'"{text}"'
        case _:
            return "{...}"


def _shown_node(value, elab: _Elaborator, env: Env) -> str:
    """A node as written (with interpolations evaluated), for labels and messages."""
    if isinstance(value, ast.Word):
        return elab._text(value, env)
    return _shown(value)


def _unknown_directive(stmt: ast.Directive) -> NetlistError:
    if stmt.name in ("include", "ends", "endfor", "subckt", "for"):
        return NetlistError(f"misplaced .{stmt.name}", stmt.loc)  # handled by parse/expand
    guess = closest(stmt.name, DIRECTIVES)
    hint = f"did you mean '.{guess}'?" if guess else f"known: .{', .'.join(DIRECTIVES)}"
    return NetlistError(f"unknown directive '.{stmt.name}'", stmt.loc, hint)


def _read_array(path: Path, loc: SourceLoc) -> np.ndarray:
    """A numeric array from a .npy or .csv file; errors name the file and the reason."""
    suffix = path.suffix.lower()
    if suffix not in (".npy", ".csv"):
        raise NetlistError(f"data file '{path}': unsupported type '{suffix}'", loc,
                           "use a .npy or .csv file")
    if not path.is_file():
        raise NetlistError(f"data file '{path}' not found", loc)
    try:
        if suffix == ".npy":
            array = np.load(path, allow_pickle=False)
        else:
            array = np.loadtxt(path, delimiter=",", ndmin=1, comments="#")
    except Exception as exc:  # noqa: BLE001 - numpy raises many types for bad files
        raise NetlistError(f"data file '{path}' cannot be read: {exc}", loc) from None
    if array.dtype.kind not in "biuf" or array.ndim == 0 or array.size == 0:
        raise NetlistError(f"data file '{path}' does not hold a non-empty numeric array "
                           f"(dtype {array.dtype}, shape {array.shape})", loc)
    return np.ascontiguousarray(array, dtype=np.float64)


def _display(path: Path) -> str:
    """`path` relative to the working directory when it lies below it (shorter messages)."""
    try:
        return str(path.relative_to(Path.cwd()))
    except ValueError:
        return str(path)
