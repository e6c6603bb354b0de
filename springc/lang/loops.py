"""Regular `.for` loops expanded as arrays, all iterations at once.

A loop (or a nest of loops, each the only statement of the one around it, with bounds that
do not use the outer loop variables) whose innermost body holds only `M K D C Q B` element
lines is regular: every name and value is an expression of the loop variables and of the
parameters around the loop. `expand` evaluates them over the whole iteration space as numpy
arrays and returns one `Rows` per element line; the elaborator resolves the nodes and adds the
rows in the order the general path would (iteration by iteration, line by line).

The values are the general path's to the bit: `+ - * /` and comparisons are IEEE operations
in numpy as in Python, a sub-expression that does not use a loop variable is evaluated once by
`expr.scalar`, and `**` and function calls apply `expr`'s own scalar functions element by
element. Anything else (a call or value that fails, a name that is not a whole number, an
array used as a number, a line that is not an element of those letters, a Monte Carlo sample)
makes `expand` return None: the general path then elaborates the loop and reports any error
at the iteration where it happens.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from springc.errors import NetlistError
from springc.lang import ast, elements
from springc.lang.expr import Env, call, int_value, operate, scalar, value

MAX_LOOP = 10_000_000  # iterations of one .for; more is surely a mistake in the bounds
LETTERS = "MKDCQB"  # elements whose lines are expanded as arrays
_ARITH = {"+": np.add, "-": np.subtract, "*": np.multiply, "/": np.divide}
_COMPARE = {"<": np.less, "<=": np.less_equal, ">": np.greater, ">=": np.greater_equal,
            "==": np.equal, "!=": np.not_equal}
_EXACT_INT = 2.0**53  # beyond this a float's integer text may differ from the array's


class _Irregular(Exception):
    """The loop is left to the general path."""


@dataclass
class Rows:
    """One element line over every iteration: its names as written (interpolated), per node
    the names written (None for ground `0`), and every parameter's value per iteration."""

    stmt: ast.Element
    letter: str
    names: list[str]
    nodes: list[list[str] | None]
    values: dict[str, np.ndarray]


def expand(loop: ast.For, env: Env) -> list[Rows] | None:
    """The element lines of `loop` evaluated over all its iterations in `env`, or None where
    the loop is not regular (the general path must expand it)."""
    try:
        space, body = _space(loop, env)
        count = len(next(iter(space.values())))
        if count == 0:
            return []
        with np.errstate(all="ignore"):  # overflow and the like are found by _finite
            return [_rows(stmt, _Space(space, count, env)) for stmt in body]
    except (_Irregular, NetlistError, ArithmeticError):
        return None


@dataclass(frozen=True)
class _Space:
    """The iteration space: each loop variable's value per iteration (outer loop slowest)."""

    vars: dict[str, np.ndarray]
    count: int
    env: Env


def _space(loop: ast.For, env: Env) -> tuple[dict[str, np.ndarray], tuple]:
    """The loop variables over the nest's iterations, and the innermost body."""
    ranges: dict[str, range] = {}
    stmt = loop
    while True:
        if stmt.var in ranges or _uses_any((stmt.first, stmt.last), ranges):
            raise _Irregular  # a shadowed variable, or bounds that depend on an outer loop
        first = int_value(stmt.first, env, "the first .for bound")
        last = int_value(stmt.last, env, "the last .for bound")
        if last - first + 1 > MAX_LOOP:
            raise _Irregular  # the general path reports it
        ranges[stmt.var] = range(first, max(last + 1, first))
        if len(stmt.body) == 1 and isinstance(stmt.body[0], ast.For):
            stmt = stmt.body[0]
            continue
        break
    if math.prod(len(r) for r in ranges.values()) > MAX_LOOP:
        raise _Irregular
    if not all(isinstance(s, ast.Element) and isinstance(s.name.parts[0], str)
               and s.name.parts[0][0].upper() in LETTERS for s in stmt.body):
        raise _Irregular  # before any work: other lines leave the loop to the general path
    axes = np.meshgrid(*(np.arange(r.start, r.stop, dtype=np.float64) for r in ranges.values()),
                       indexing="ij")
    return {var: axis.ravel() for var, axis in zip(ranges, axes)}, stmt.body


def _rows(stmt: ast.Element, space: _Space) -> Rows:
    letter = stmt.name.parts[0][0].upper()
    spec = elements.SPECS[letter]
    plain, keywords, calls, factors = elements.split_args(stmt.args)
    keys = [kw.key.lower() for kw in keywords]
    if (calls or factors or len(plain) != spec.nodes or len(set(keys)) != len(keys)
            or not set(keys) <= {*spec.required, *spec.optional}
            or not set(spec.required) <= set(keys)):
        raise _Irregular  # the general path names the problem
    values = {key: np.full(space.count, default) for key, default in spec.optional.items()}
    for key, kw in zip(keys, keywords):
        values[key] = np.broadcast_to(_value(kw.value, space), (space.count,))
    return Rows(stmt, letter, _text(stmt.name, space), [_node(v, space) for v in plain],
                values)


def _node(arg: ast.Value, space: _Space) -> list[str] | None:
    if isinstance(arg, ast.Num) and arg.text == "0":
        return None
    if not isinstance(arg, ast.Word):
        raise _Irregular
    return _text(arg, space)


def _text(word: ast.Word, space: _Space) -> list[str]:
    """The name `word` spells at every iteration (`expr.name_text` over the space)."""
    numbers = []
    for part in word.parts:
        if isinstance(part, str):
            continue
        number = np.broadcast_to(_vector(part, space), (space.count,))
        if not (np.all(np.isfinite(number)) and np.all(number == np.floor(number))
                and np.all(number >= 0) and np.all(number < _EXACT_INT)):
            raise _Irregular  # not a name: the general path says why
        numbers.append(number.astype(np.int64))
    if not numbers:
        return [word.parts[0]] * space.count
    # one %-format of the whole loop: names hold no newline ('%' in a name is doubled)
    line = "".join(p.replace("%", "%%") if isinstance(p, str) else "%d" for p in word.parts)
    values = np.stack(numbers, axis=1).ravel().tolist()
    return ((line + "\n") * space.count % tuple(values)).split("\n")[:-1]


def _value(arg: ast.Value, space: _Space) -> float | np.ndarray:
    """`expr.value` over the space."""
    if isinstance(arg, ast.Brace):
        return _vector(arg.expr, space)
    if isinstance(arg, ast.Word) and arg.plain and arg.parts[0] in space.vars:
        return space.vars[arg.parts[0]]
    if isinstance(arg, ast.Word) and not arg.plain:
        raise _Irregular
    return value(arg, space.env)


def _vector(expr: ast.Expr, space: _Space) -> float | np.ndarray:
    """`expr.evaluate` over the space: a float where `expr` uses no loop variable."""
    if not _uses(expr, space.vars):
        return scalar(expr, space.env)
    match expr:
        case ast.Var(name=name):
            return space.vars[name]
        case ast.Unary(op=op, operand=operand):
            number = _vector(operand, space)
            return -number if op == "-" else number
        case ast.Binary(op=op, left=left, right=right, loc=loc):
            a, b = _vector(left, space), _vector(right, space)
            if op in _ARITH:
                if op == "/" and np.any(np.asarray(b) == 0):
                    raise _Irregular  # division by zero, reported by the general path
                return _finite(_ARITH[op](a, b))
            if op in _COMPARE:
                return _COMPARE[op](a, b).astype(np.float64)
            return _each(lambda x, y: operate(op, x, y, loc), a, b, space=space)
        case ast.Call(func=func, args=args, loc=loc):
            env = space.env
            return _each(lambda *xs: call(func, list(xs), env, loc),
                         *(_vector(a, space) for a in args), space=space)
        case ast.Index(name=name, indices=indices, loc=loc):
            return _gather(name, [_vector(i, space) for i in indices], space, loc)
        case _:
            raise TypeError(f"not an expression node: {expr!r}")


def _finite(number: np.ndarray) -> np.ndarray:
    if not np.all(np.isfinite(number)):
        raise _Irregular  # an overflow, reported by the general path
    return number


def _each(func, *args, space: _Space) -> np.ndarray:
    """`func` (a scalar function of `expr`) applied per iteration, on Python floats."""
    columns = [np.broadcast_to(a, (space.count,)).tolist() for a in args]
    return _finite(np.array([func(*xs) for xs in zip(*columns)], dtype=np.float64))


def _gather(name: str, indices: list, space: _Space, loc) -> np.ndarray:
    """`name[indices]` per iteration; the general path reports a bad index or name."""
    array = space.env.lookup(name)
    if not isinstance(array, np.ndarray) or array.ndim != len(indices):
        raise _Irregular
    where = []
    for index, size in zip(indices, array.shape):
        index = np.broadcast_to(index, (space.count,))
        if not (np.all(index == np.floor(index)) and np.all(index >= 0)
                and np.all(index < size)):
            raise _Irregular
        where.append(index.astype(np.int64))
    return array[tuple(where)].astype(np.float64)


def _uses(expr: ast.Expr, names) -> bool:
    """True if `expr` reads one of `names`."""
    match expr:
        case ast.Num() | ast.Deviate():
            return False
        case ast.Var(name=name):
            return name in names
        case ast.Unary(operand=operand):
            return _uses(operand, names)
        case ast.Binary(left=left, right=right):
            return _uses(left, names) or _uses(right, names)
        case ast.Call(args=args):
            return any(_uses(a, names) for a in args)
        case ast.Index(name=name, indices=indices):
            return name in names or any(_uses(i, names) for i in indices)
        case _:
            raise TypeError(f"not an expression node: {expr!r}")


def _uses_any(args, names) -> bool:
    """True if one of the values `args` (numbers, names, braces) reads one of `names`."""
    for arg in args:
        if isinstance(arg, ast.Brace) and _uses(arg.expr, names):
            return True
        if isinstance(arg, ast.Word) and any(
                (p in names) if isinstance(p, str) else _uses(p, names) for p in arg.parts):
            return True
    return False
