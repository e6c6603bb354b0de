"""`.step` sweeps and `.mc` Monte Carlo: the points of a netlist (docs/language.md, "Sweeps
and Monte Carlo").

    read(tree) -> Variation -> points() -> netlist(point) per point -> PointSet

`read` splices the includes, reads the `.step` and `.mc` lines and checks where random
functions are written (a `.param`, an element's value, a subcircuit parameter: the places a
draw has an owner). A point is one value of every stepped parameter (the cartesian product of
the `.step` lines, the first outermost) and, with `.mc`, one sample index; `netlist(point)`
elaborates the file with the stepped `.param` lines set to the point's values and the random
functions drawing in its sample. A `PointSet` groups the points by `structure`: points whose
netlists differ only in element coefficients can share one kernel with per-run coefficient
arrays (a stepped `.for` bound changes the structure). Where every random call is the whole
value of an element's key (`direct_draws`), the samples of one step point come from one
elaboration: its draws are drawn for all of them at once and written into the coefficients,
bitwise what each sample's own elaboration gives. Checking each point is the check stage's
(`springc.check.points`).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from springc.errors import NetlistError, SourceLoc
from springc.lang import ast, draws
from springc.lang.elaborate import elaborate
from springc.lang.expr import Env, closest, int_value, value
from springc.lang.files import Includes
from springc.lang.ir import FlatNetlist

MAX_POINTS = 10_000_000  # more points than this is surely a mistake in a range
STEP_USAGE = (".step NAME list V1 V2 ..., .step NAME START STOP INCR, or "
              ".step NAME dec|oct START STOP POINTS (LTspice: .step [dec|oct] param NAME ...)")
RANDOM_WHERE = ("random functions are written in .param values, element values and "
                "subcircuit parameters, where each draw has an owner")

# (table attribute, coefficient field) of every element coefficient, in order
COEFFICIENTS = (
    ("masses", "m"), ("masses", "b"), ("masses", "x0"), ("masses", "v0"),
    ("springs", "k"), ("duffings", "l"), ("couplings", "k"), ("couplings", "a"),
    ("quads", "g"), ("quads", "a"), ("dashpots", "b"), ("monomials", "c"),
    ("forces", "gain"),
)


def structure(net: FlatNetlist) -> str:
    """`net`'s text dump with every coefficient left out: netlists with equal structure differ
    in coefficients alone."""
    fields: dict[str, list[str]] = {}
    for table, name in COEFFICIENTS:
        fields.setdefault(table, []).append(name)
    tables = {}
    for table, names in fields.items():
        tab = getattr(net, table)
        tables[table] = replace(tab, **{name: np.zeros(len(tab)) for name in names})
    return replace(net, **tables).text()


@dataclass(frozen=True)
class StepAxis:
    """One `.step` line: the parameter and its values in order."""

    name: str
    values: tuple[float, ...]
    loc: SourceLoc


@dataclass(frozen=True)
class Point:
    """One point: its index, the stepped parameters' values and (with `.mc`) the sample."""

    index: int
    steps: tuple[tuple[str, float], ...] = ()
    sample: int | None = None
    seed: int | None = None

    def describe(self, count: int | None = None) -> str:
        """'point 7 of 12 (w=2, sample 3, seed 1)' for messages and reports."""
        parts = [f"{name}={v:g}" for name, v in self.steps]
        if self.sample is not None:
            parts += [f"sample {self.sample}", f"seed {self.seed}"]
        of = f" of {count}" if count is not None else ""
        return f"point {self.index}{of}" + (f" ({', '.join(parts)})" if parts else "")

    def to_json(self) -> dict:
        return {"index": self.index, "steps": dict(self.steps), "sample": self.sample,
                "seed": self.seed}


@dataclass(frozen=True)
class PointSet:
    """Every point of a netlist with its elaborated netlist, the points grouped by structure
    (indices, in order of first appearance), and once checked (`springc.check.points`) the
    `CheckedNetlist` of each point."""

    points: tuple[Point, ...]
    nets: tuple[FlatNetlist, ...]
    groups: tuple[tuple[int, ...], ...]
    checked: tuple = field(default=(), repr=False)

    def __len__(self) -> int:
        return len(self.points)


@dataclass
class Variation:
    """A parsed netlist (includes spliced in) with its `.step` axes and `.mc` count."""

    file: str
    statements: list
    lib_dirs: list[Path] | None = None
    axes: tuple[StepAxis, ...] = ()
    samples: int | None = None  # `.mc` count (None: no Monte Carlo)
    seed: int | None = None  # `.mc seed=` (None: `.options seed=`, else 0)

    @property
    def varies(self) -> bool:
        """Whether the netlist has `.step` or `.mc` (more than the nominal point)."""
        return bool(self.axes) or self.samples is not None

    @property
    def count(self) -> int:
        """The number of points."""
        return math.prod(len(a.values) for a in self.axes) * (self.samples or 1)

    def nominal(self) -> FlatNetlist:
        """The netlist as written: `.param` values as given, random functions nominal."""
        return elaborate(ast.Netlist(self.file, tuple(self.statements)), self.lib_dirs)

    def points(self, default_seed: int = 0) -> list[Point]:
        """Every point: the steps' product, the first `.step` outermost, then the samples
        (seed: `.mc seed=`, else `default_seed`)."""
        seed = self.seed if self.seed is not None else default_seed
        names = [a.name for a in self.axes]
        samples: list[int | None] = list(range(self.samples)) if self.samples else [None]
        out = []
        for values in itertools.product(*(a.values for a in self.axes)):
            for sample in samples:
                out.append(Point(len(out), tuple(zip(names, values)), sample,
                                 None if sample is None else seed))
        return out

    def netlist(self, point: Point) -> FlatNetlist:
        """The elaborated netlist of `point`; its errors name the point (of `count`)."""
        stmts = set_params(self.statements, dict(point.steps))
        sample = None if point.sample is None else draws.Sample(point.sample, point.seed)
        try:
            return elaborate(ast.Netlist(self.file, tuple(stmts)), self.lib_dirs, sample)
        except NetlistError as err:
            raise NetlistError(f"{err.message} at {point.describe(self.count)}", err.loc,
                               err.diagnostic.hint) from None

    def point_set(self, nominal: FlatNetlist | None = None) -> PointSet:
        """Every point elaborated and grouped by structure (`nominal`: the nominal netlist
        if already elaborated, for `.options seed=`)."""
        if not self.varies:
            net = nominal if nominal is not None else self.nominal()
            return PointSet((Point(0),), (net,), ((0,),))
        if nominal is None:
            nominal = self.nominal()
        points = self.points(int(nominal.options.get("seed", 0)))
        direct = self.samples is not None and direct_draws(self.statements)
        nets: list[FlatNetlist] = []
        groups: dict[str, list[int]] = {}
        for run in _runs(points):
            made = self._population(run) if direct else None
            if made is None:  # each point elaborated alone
                made = [self.netlist(p) for p in run]
                shapes = [structure(net) for net in made]
            else:  # the samples of one elaboration: its structure
                shapes = [structure(made[0])] * len(made)
            for point, net, shape in zip(run, made, shapes):
                nets.append(net)
                groups.setdefault(shape, []).append(point.index)
        return PointSet(tuple(points), tuple(nets), tuple(tuple(g) for g in groups.values()))

    def _population(self, run: list[Point]) -> list[FlatNetlist] | None:
        """The netlists of `run` (the samples of one step point) from one elaboration: the
        first sample elaborated with its draws logged, every logged draw then drawn for all
        the samples at once (`draws.values`, the function a sample's own elaboration calls)
        and written into its coefficient. Only for netlists whose every random call is the
        whole value of an element's key (`direct_draws`), so that a draw is the coefficient;
        None where a draw is not finite (the point's own elaboration says where)."""
        first = run[0]
        log: list = []
        sample = draws.Sample(first.sample, first.seed, log)
        stmts = set_params(self.statements, dict(first.steps))
        try:
            net = elaborate(ast.Netlist(self.file, tuple(stmts)), self.lib_dirs, sample)
        except NetlistError as err:
            raise NetlistError(f"{err.message} at {first.describe(self.count)}", err.loc,
                               err.diagnostic.hint) from None
        samples = np.array([p.sample for p in run], np.int64)
        columns = _drawn_columns(net, log, first.seed, samples)
        if columns is None:
            return None
        return [_with_columns(net, columns, s) for s in range(len(run))]


def _runs(points: list[Point]) -> Iterator[list[Point]]:
    """The points in runs of equal step values (the samples of one step point)."""
    for _, run in itertools.groupby(points, key=lambda p: p.steps):
        yield list(run)


# element letter -> FlatNetlist table attribute
_TABLES = {"M": "masses", "K": "springs", "D": "duffings", "C": "couplings", "Q": "quads",
           "B": "dashpots", "P": "monomials", "F": "forces"}


def _drawn_columns(net: FlatNetlist, log: list, seed: int,
                   samples: np.ndarray) -> dict | None:
    """(table, field) -> (samples, elements) coefficients with every logged draw drawn for
    all `samples`; None where a draw is not finite (an overflow error of that sample)."""
    rows: dict[str, dict[str, int]] = {}
    columns: dict[tuple[str, str], np.ndarray] = {}
    for path, key, n, func, args in log:
        letter = path.rsplit(".", 1)[-1][0].upper()
        table = _TABLES[letter]
        tab = getattr(net, table)
        if table not in rows:
            rows[table] = {name: e for e, name in enumerate(tab.names)}
        if (table, key) not in columns:
            columns[table, key] = np.repeat(getattr(tab, key)[None, :], len(samples), 0)
        drawn = draws.values(func, list(args), seed, samples, path, key, n)
        if not np.isfinite(drawn).all():
            return None
        columns[table, key][:, rows[table][path]] = drawn
    return columns


def _with_columns(net: FlatNetlist, columns: dict, s: int) -> FlatNetlist:
    """`net` with sample `s`'s row of every drawn coefficient column."""
    tables: dict[str, dict[str, np.ndarray]] = {}
    for (table, key), values in columns.items():
        tables.setdefault(table, {})[key] = values[s]
    return replace(net, **{table: replace(getattr(net, table), **fields)
                           for table, fields in tables.items()})


def direct_draws(statements) -> bool:
    """Whether every random call is the whole `{...}` value of an element's key (not of an
    instance, a `.param` or a subcircuit parameter) with no random call in its arguments:
    then each draw is an element coefficient and nothing else depends on it."""
    for stmt in statements:
        match stmt:
            case ast.Element():
                if not all(_direct(arg, stmt) for arg in stmt.args):
                    return False
            case ast.Subckt():
                if _has_random(stmt.params) or not direct_draws(stmt.body):
                    return False
            case ast.For():
                if not direct_draws(stmt.body):
                    return False
            case ast.Directive():
                if _has_random(stmt.args):
                    return False
            case ast.Title():
                pass
            case _:
                raise TypeError(f"unknown statement {stmt!r}")
    return True


def _direct(arg, element: ast.Element) -> bool:
    """An element argument without random calls, or `key={f(...)}` of a non-instance with a
    random function `f` whose arguments have none."""
    if _plain(arg) or not _has_random([arg]):
        return True
    first = element.name.parts[0] if element.name.parts else ""
    if not isinstance(first, str) or not first or first[0].upper() == "X":
        return False
    if arg.__class__ is not ast.Keyword or arg.value.__class__ is not ast.Brace:
        return False
    call = arg.value.expr
    return (call.__class__ is ast.Call and call.func in draws.FUNCTIONS
            and not _has_random(call.args))


def _has_random(nodes) -> bool:
    return any(True for node in nodes if not _plain(node) for _ in _random_calls(node))


def read(tree: ast.Netlist, lib_dirs: list[Path] | None = None) -> Variation:
    """The netlist's variation: includes spliced in, `.step` and `.mc` read, random functions
    checked to be where a draw has an owner. Every misuse is a located `NetlistError`."""
    statements = Includes(lib_dirs).expand(tree)
    _check_placement(statements, "")
    top, nested = _declared_params(statements)
    var = Variation(tree.file, statements, lib_dirs)
    last = None
    for stmt in statements:
        if isinstance(stmt, ast.Directive) and stmt.name == "step":
            axis = _step(stmt, top, nested)
            if any(a.name == axis.name for a in var.axes):
                first = next(a for a in var.axes if a.name == axis.name)
                raise NetlistError(f".step {axis.name} given twice (first at {first.loc})",
                                   stmt.loc, "one .step line per parameter")
            var.axes += (axis,)
            last = stmt
        elif isinstance(stmt, ast.Directive) and stmt.name == "mc":
            if var.samples is not None:
                raise NetlistError("a second .mc", stmt.loc, "one .mc line per netlist")
            var.samples, var.seed = _mc(stmt)
            last = stmt
    if last is not None and var.count > MAX_POINTS:
        raise NetlistError(f"{var.count} points (more than {MAX_POINTS})", last.loc,
                           "fewer step values or samples")
    return var


# --- where random functions and .step/.mc may be written ----------------------------------


def _random_calls(node) -> Iterator[ast.Call]:
    """Every call of a random function in an AST subtree."""
    match node:
        case ast.Call(func=func, args=args):
            if func in draws.FUNCTIONS:
                yield node
            for arg in args:
                yield from _random_calls(arg)
        case ast.Num() | ast.Var() | ast.Str() | ast.Deviate() | str() | None:
            return
        case ast.Unary(operand=operand):
            yield from _random_calls(operand)
        case ast.Binary(left=left, right=right):
            yield from _random_calls(left)
            yield from _random_calls(right)
        case ast.Index(indices=items) | ast.Word(parts=items) | ast.CallArg(args=items):
            for item in items:
                yield from _random_calls(item)
        case ast.Brace(expr=expr) | ast.Keyword(value=expr):
            yield from _random_calls(expr)
        case ast.Factor(node=word, exponent=exponent):
            yield from _random_calls(word)
            yield from _random_calls(exponent)
        case _:
            raise TypeError(f"not an argument or expression: {node!r}")


def _plain(node) -> bool:
    """A number, string or plain name: nothing to walk (most arguments, checked quickly)."""
    cls = node.__class__
    return cls is ast.Num or cls is ast.Str or (
        cls is ast.Word and len(node.parts) == 1 and node.parts[0].__class__ is str)


def _refuse_random(nodes, what: str, hint: str = RANDOM_WHERE) -> None:
    for node in nodes:
        if _plain(node):
            continue
        for call in _random_calls(node):
            raise NetlistError(f"{call.func}() cannot be used in {what}", call.loc, hint)


def _check_placement(statements, where: str) -> None:
    """Random calls only in values that own a draw; `.step`/`.mc` only at the top level.
    `where`: '' (top level), 'subckt' or 'for' (the innermost enclosing block)."""
    for stmt in statements:
        match stmt:
            case ast.Directive(name="step" | "mc"):
                if where:
                    inside = "a subcircuit" if where == "subckt" else "a .for loop"
                    hint = ("step a top-level .param; it reaches every instance"
                            if stmt.name == "step" else "write .mc at the top level")
                    raise NetlistError(f".{stmt.name} is only allowed at the top level, not "
                                       f"inside {inside}", stmt.loc, hint)
                _refuse_random(stmt.args, f"a .{stmt.name} line", "step values are numbers")
            case ast.Directive(name="param") if where == "for":
                _refuse_random(stmt.args, "a .param inside a .for loop",
                               "write it in the element's value (one draw per element) or in "
                               "a .param outside the loop")
            case ast.Directive(name="param"):
                _refuse_random([a for a in stmt.args if not isinstance(a, ast.Keyword)],
                               "a .param line")
            case ast.Directive():
                _refuse_random(stmt.args, f"a .{stmt.name} line")
            case ast.Element():
                _refuse_random([stmt.name], "an element name")
                for arg in stmt.args:
                    if arg.__class__ is ast.CallArg:
                        _refuse_random([arg], "a source's arguments",
                                       "sources are not values: vary the force's gain= instead")
                    elif arg.__class__ is not ast.Keyword:
                        _refuse_random([arg], "a node, exponent or subcircuit name")
            case ast.Subckt():
                _check_placement(stmt.body, "subckt")
            case ast.For():
                _refuse_random([stmt.first, stmt.last], "a .for bound")
                _check_placement(stmt.body, "for")
            case ast.Title():
                pass
            case _:
                raise TypeError(f"unknown statement {stmt!r}")


def _declared_params(statements) -> tuple[set[str], dict[str, SourceLoc]]:
    """Names of the top-level `.param`s, and where every other parameter or loop variable
    is declared (subcircuit parameters, `.param` in bodies, `.for` variables)."""
    top = {kw.key for stmt in statements if isinstance(stmt, ast.Directive)
           and stmt.name == "param" for kw in stmt.args if isinstance(kw, ast.Keyword)}
    nested: dict[str, SourceLoc] = {}

    def walk(stmts) -> None:
        for stmt in stmts:
            match stmt:
                case ast.Directive(name="param"):
                    nested.update((kw.key, kw.loc) for kw in stmt.args
                                  if isinstance(kw, ast.Keyword))
                case ast.Subckt():
                    nested.update((kw.key, kw.loc) for kw in stmt.params)
                    walk(stmt.body)
                case ast.For():
                    nested.setdefault(stmt.var, stmt.loc)
                    walk(stmt.body)

    for stmt in statements:
        if isinstance(stmt, (ast.Subckt, ast.For)):
            walk([stmt])
    return top, nested


# --- .step and .mc ------------------------------------------------------------------------


def _word(arg) -> str | None:
    """A plain word argument in lower case, else None."""
    return arg.parts[0].lower() if isinstance(arg, ast.Word) and arg.plain else None


def _step(stmt: ast.Directive, top: set[str], nested: dict[str, SourceLoc]) -> StepAxis:
    """One `.step` line in any of its spellings."""
    args, scale = list(stmt.args), None
    if len(args) > 1 and _word(args[0]) in ("dec", "oct") and _word(args[1]) == "param":
        scale, args = _word(args[0]), args[2:]
    elif len(args) > 1 and _word(args[0]) == "param" and isinstance(args[1], ast.Word):
        args = args[1:]
    if not args or _word(args[0]) is None:
        raise NetlistError(".step needs a parameter name", stmt.loc, STEP_USAGE)
    for arg in args:
        if not isinstance(arg, (ast.Num, ast.Word, ast.Brace)):
            raise NetlistError(".step takes a name and numbers", arg.loc, STEP_USAGE)
    name = _param_name(args[0], top, nested)
    rest = args[1:]
    if scale is None and _word(rest[0] if rest else None) in ("list", "dec", "oct"):
        scale, rest = _word(rest[0]), rest[1:]
    if scale == "list":
        if not rest:
            raise NetlistError(f".step {name} list has no values", stmt.loc,
                               f"write .step {name} list V1 V2 ...")
        values = tuple(_number(a) for a in rest)
    elif scale in ("dec", "oct"):
        values = _logarithmic(name, scale, rest, stmt.loc)
    else:
        values = _linear(name, rest, stmt.loc)
    if len(values) > MAX_POINTS:
        raise NetlistError(f".step {name} has {len(values)} values (more than {MAX_POINTS})",
                           stmt.loc, "check the range and increment")
    return StepAxis(name, values, stmt.loc)


def _param_name(arg: ast.Word, top: set[str], nested: dict[str, SourceLoc]) -> str:
    name = arg.parts[0]
    if name in top:
        return name
    if name in nested:
        raise NetlistError(f".step {name}: '{name}' is not a top-level parameter (it is "
                           f"declared at {nested[name]})", arg.loc,
                           "step a top-level .param and pass it to the instances")
    guess = closest(name, top)
    hint = f"did you mean '{guess}'?" if guess else "define it with a top-level .param"
    raise NetlistError(f".step {name}: unknown parameter '{name}'", arg.loc, hint)


def _number(arg: ast.Value) -> float:
    """A step value: a number or an expression of constants."""
    return float(value(arg, Env()))


def _linear(name: str, args: list, loc: SourceLoc) -> tuple[float, ...]:
    """START STOP INCR, both ends included."""
    if len(args) != 3:
        raise NetlistError(f".step {name} takes START STOP INCR, got {len(args)} values", loc,
                           STEP_USAGE)
    start, stop, incr = (_number(a) for a in args)
    if incr == 0:
        raise NetlistError(f".step {name}: the increment is zero", args[2].loc,
                           "a linear step needs an increment != 0")
    span = (stop - start) / incr
    if span < 0:
        raise NetlistError(f".step {name}: an increment of {incr:g} never reaches {stop:g} "
                           f"from {start:g}", args[2].loc, f"write {-incr:g} or swap the ends")
    count = math.floor(span * (1 + 1e-12) + 1e-9) + 1  # the stop despite rounding
    _no_flood(name, count, args[2].loc)
    values = [start + k * incr for k in range(count)]
    if abs(values[-1] - stop) <= 1e-9 * abs(incr):
        values[-1] = stop  # the end as written, not as rounding leaves it
    return tuple(values)


def _logarithmic(name: str, scale: str, args: list, loc: SourceLoc) -> tuple[float, ...]:
    """START STOP POINTS per decade or octave, both ends included where the grid hits."""
    if len(args) != 3:
        raise NetlistError(f".step {name} {scale} takes START STOP POINTS, got {len(args)} "
                           "values", loc, STEP_USAGE)
    start, stop = _number(args[0]), _number(args[1])
    per = int_value(args[2], Env(), f".step {scale} points")
    if per < 1:
        raise NetlistError(f".step {name} {scale}: points must be >= 1, got {per}",
                           args[2].loc)
    if not start > 0:
        raise NetlistError(f".step {name} {scale}: the start must be > 0, got {start:g}",
                           args[0].loc, "a logarithmic range starts above zero")
    if stop < start:
        raise NetlistError(f".step {name} {scale}: the stop {stop:g} is below the start "
                           f"{start:g}", args[1].loc, "swap the ends")
    base = 10.0 if scale == "dec" else 2.0
    count = math.floor(per * math.log(stop / start, base) * (1 + 1e-12) + 1e-9) + 1
    _no_flood(name, count, args[2].loc)
    values = [start * base ** (k / per) for k in range(count)]
    if abs(values[-1] - stop) <= 1e-9 * stop:
        values[-1] = stop
    return tuple(values)


def _no_flood(name: str, count: int, loc: SourceLoc) -> None:
    if count > MAX_POINTS:
        raise NetlistError(f".step {name} has {count} values (more than {MAX_POINTS})", loc,
                           "check the range and increment")


def _mc(stmt: ast.Directive) -> tuple[int, int | None]:
    """`.mc N [seed=S]`: the sample count and the seed (None: not given)."""
    plain = [a for a in stmt.args if not isinstance(a, ast.Keyword)]
    keywords = [a for a in stmt.args if isinstance(a, ast.Keyword)]
    usage = "write .mc N [seed=S]: N samples (an integer >= 1), seed an integer >= 0"
    if len(plain) != 1 or not isinstance(plain[0], (ast.Num, ast.Word, ast.Brace)):
        raise NetlistError(".mc takes the number of samples", stmt.loc, usage)
    count = int_value(plain[0], Env(), "the .mc count")
    if count < 1:
        raise NetlistError(f"the .mc count must be >= 1, got {count}", plain[0].loc, usage)
    seed = None
    for kw in keywords:
        if kw.key.lower() != "seed":
            raise NetlistError(f".mc has no parameter '{kw.key}'", kw.loc, usage)
        if seed is not None:
            raise NetlistError(".mc seed given twice", kw.loc)
        seed = int_value(kw.value, Env(), "the .mc seed")
        if not 0 <= seed < draws.MAX_SEED:
            raise NetlistError(f"the .mc seed must be an integer >= 0, got {seed}",
                               kw.value.loc, usage)
    return count, seed


def set_params(statements: list, values: dict[str, float]) -> list:
    """`statements` with each top-level `.param name=...` of `values` set to the number."""
    if not values:
        return statements
    out = []
    for stmt in statements:
        if isinstance(stmt, ast.Directive) and stmt.name == "param":
            args = tuple(_set_keyword(a, values) for a in stmt.args)
            stmt = replace(stmt, args=args)
        out.append(stmt)
    return out


def _set_keyword(arg, values: dict[str, float]):
    if isinstance(arg, ast.Keyword) and arg.key in values:
        number = float(values[arg.key])
        return replace(arg, value=ast.Num(number, repr(number), arg.value.loc))
    return arg
