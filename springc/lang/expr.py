"""Numbers with SPICE suffixes and the evaluator of parameter expressions.

The evaluator walks `ast` expression nodes itself (never Python's `eval`). Values are floats,
or numpy arrays for `.data` names, which may only be indexed. Every failure is a
`NetlistError` at the position of the offending name, operator or call.
"""

from __future__ import annotations

import difflib
import math
import re
from decimal import Decimal

import numpy as np

from springc.errors import NetlistError, SourceLoc
from springc.lang import ast, draws

# scale suffix -> power of ten (applied exactly, so that 20u is the double nearest 2e-5)
SUFFIXES = {"t": 12, "g": 9, "meg": 6, "k": 3, "m": -3, "u": -6, "n": -9, "p": -12, "f": -15}
_NUMBER = re.compile(r"([+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)(meg|[tgkmunpf])?(.*)",
                     re.IGNORECASE | re.DOTALL)
_UNIT = re.compile(r"[A-Za-z]*")

CONSTANTS = {"pi": math.pi, "e": math.e}


def read_number(text: str) -> float | None:
    """The value of a number literal with an optional scale suffix and unit letters
    (`1k` = 1000, `1M` = 1e-3, `1meg` = 1e6, `50Hz` = 50, `10ms` = 0.01); None if malformed
    (`1k5`: a digit after the suffix) or beyond the range of a double (`1e400`)."""
    value = _literal(text)
    return value if value is not None and math.isfinite(value) else None


def _literal(text: str) -> float | None:
    match = _NUMBER.fullmatch(text)
    if match is None:
        return None
    mantissa, suffix, unit = match.groups()
    if not _UNIT.fullmatch(unit):
        return None
    if not suffix:
        return float(mantissa)
    return float(Decimal(mantissa).scaleb(SUFFIXES[suffix.lower()]))


def bad_number(text: str, loc: SourceLoc) -> tuple[str, SourceLoc, str]:
    """(message, loc, hint) for a number literal `read_number` rejects."""
    if _literal(text) is not None:
        return (f"number '{text}' is beyond the range of a double", loc,
                "the largest finite value is about 1.8e308")
    hint = ("a number may end in one scale suffix (t g meg k m u n p f) and unit letters, "
            "not digits: write 1.5k for 1500")
    return f"malformed number '{text}'", loc, hint


class Env:
    """A scope of named values (floats or arrays) with a parent scope to fall back on, and
    where a Monte Carlo sample's random calls draw (`site`, the nearest one up the chain;
    none: nominal values)."""

    __slots__ = ("parent", "site", "vars")

    def __init__(self, vars: dict[str, object] | None = None, parent: Env | None = None,
                 site: draws.Site | None = None) -> None:
        self.vars = vars if vars is not None else {}
        self.parent = parent
        self.site = site

    def lookup(self, name: str) -> object | None:
        """The value bound to `name` here or in an enclosing scope, or None."""
        env: Env | None = self
        while env is not None:
            value = env.vars.get(name)
            if value is not None:
                return value
            env = env.parent
        return CONSTANTS.get(name)

    def draw(self, func: str, args: list[float], loc: SourceLoc) -> float:
        """A random call's value: drawn at the nearest site, else nominal."""
        env: Env | None = self
        while env is not None:
            if env.site is not None:
                return env.site.draw(func, args, loc)
            env = env.parent
        return draws.nominal(func, args, loc)

    def deviate(self, node: ast.Deviate) -> float:
        """A `Deviate` node's value at the nearest site (0 without one: nominal values)."""
        env: Env | None = self
        while env is not None:
            if env.site is not None:
                return env.site.deviate(node.func, node.key, node.n)
            env = env.parent
        return 0.0

    def names(self) -> set[str]:
        """Every name visible from here (for suggestions)."""
        out = set(CONSTANTS)
        env: Env | None = self
        while env is not None:
            out.update(env.vars)
            env = env.parent
        return out


def keyed(env: Env, key: str) -> Env:
    """The scope for the value of parameter or element key `key` in `env`: where `env` has a
    site of its own (a Monte Carlo sample, see `draws`), its random calls draw at `key`."""
    site = env.site
    return env if site is None else Env({}, env, site.keyed(key))


def closest(name: str, candidates) -> str | None:
    """The candidate most similar to `name`, for 'did you mean' hints (a candidate that
    differs only in case first: names are case-sensitive, people often are not)."""
    candidates = sorted(candidates)
    for candidate in candidates:
        if candidate.lower() == name.lower():
            return candidate
    found = difflib.get_close_matches(name, candidates, n=1, cutoff=0.6)
    return found[0] if found else None


def undefined(name: str, loc: SourceLoc, env: Env, what: str = "parameter") -> NetlistError:
    """The error for an undefined name, suggesting the closest defined one."""
    guess = closest(name, env.names())
    hint = f"did you mean '{guess}'?" if guess else "define it with .param"
    return NetlistError(f"undefined {what} '{name}'", loc, hint)


def evaluate(expr: ast.Expr, env: Env) -> float | np.ndarray:
    """The value of `expr` in `env` (a float, or an array for a bare `.data` name)."""
    match expr:
        case ast.Num(value=value):
            return value
        case ast.Var(name=name, loc=loc):
            value = env.lookup(name)
            if value is None:
                raise undefined(name, loc, env)
            return value
        case ast.Binary(op=op, left=left, right=right, loc=loc):
            return _finite(_binary(op, scalar(left, env), scalar(right, env), loc), op, loc)
        case ast.Unary(op=op, operand=operand):
            value = scalar(operand, env)
            return -value if op == "-" else value
        case ast.Call(func=func, args=args, loc=loc) if func in draws.FUNCTIONS:
            return _finite(env.draw(func, [scalar(a, env) for a in args], loc), f"{func}()", loc)
        case ast.Call(func=func, args=args, loc=loc):
            return _finite(_call(func, [scalar(a, env) for a in args], loc), f"{func}()", loc)
        case ast.Index(name=name, indices=indices, loc=loc):
            return _index(name, [scalar(i, env) for i in indices], env, loc)
        case ast.Deviate():
            return env.deviate(expr)
        case _:
            raise TypeError(f"not an expression node: {expr!r}")


def operate(op: str, a: float, b: float, loc: SourceLoc) -> float:
    """`a op b` as a binary expression evaluates it (errors and overflow checked)."""
    return _finite(_binary(op, a, b, loc), op, loc)


def call(func: str, args: list[float], env: Env, loc: SourceLoc) -> float:
    """`func(args)` as a call expression evaluates it in `env` (random functions draw there)."""
    if func in draws.FUNCTIONS:
        return _finite(env.draw(func, args, loc), f"{func}()", loc)
    return _finite(_call(func, args, loc), f"{func}()", loc)


def _finite(value: float, what: str, loc: SourceLoc) -> float:
    # float arithmetic overflows to inf silently (1e200*1e200); inf would reach the kernels
    if not math.isfinite(value):
        raise NetlistError(f"overflow in '{what}': the result is {value}", loc,
                           "the largest finite value is about 1.8e308")
    return value


def scalar(expr: ast.Expr, env: Env) -> float:
    """The value of `expr`, which must be a number (not a whole array)."""
    value = evaluate(expr, env)
    if isinstance(value, np.ndarray):
        raise NetlistError(f"'{expr.name}' is an array of shape {value.shape}",
                           expr.loc, f"index it, e.g. {expr.name}[0]")
    return value


def integer(expr: ast.Expr, env: Env, what: str) -> int:
    """The value of `expr` as an int; an error unless it is a whole number."""
    value = scalar(expr, env)
    if not float(value).is_integer():
        raise NetlistError(f"{what} must be an integer, got {value:g}", expr.loc)
    return int(value)


def _binary(op: str, a: float, b: float, loc: SourceLoc) -> float:
    try:
        match op:
            case "+":
                return a + b
            case "-":
                return a - b
            case "*":
                return a * b
            case "/":
                return a / b
            case "**":
                return _power(a, b, loc)
            case "<":
                return float(a < b)
            case "<=":
                return float(a <= b)
            case ">":
                return float(a > b)
            case ">=":
                return float(a >= b)
            case "==":
                return float(a == b)
            case "!=":
                return float(a != b)
            case _:
                raise TypeError(f"unknown operator {op!r}")
    except ZeroDivisionError:
        raise NetlistError("division by zero", loc) from None
    except OverflowError:
        raise NetlistError(f"overflow in '{op}'", loc) from None


def _power(a: float, b: float, loc: SourceLoc) -> float:
    # Python's float power gives a complex number for a negative base and a fractional
    # exponent; mathematically there is no real value, so that is a domain error.
    if a < 0 and not float(b).is_integer():
        raise NetlistError(f"a negative number ({a:g}) to a fractional power ({b:g}) is not real",
                           loc)
    if a == 0 and b < 0:
        raise NetlistError("division by zero (0 to a negative power)", loc)
    return float(a) ** b


def _domain(pred, message: str):
    """A check on a one-argument function's input: (predicate, message)."""
    return (pred, message)


_POSITIVE = _domain(lambda x: x > 0, "needs a positive argument")
# name -> (implementation, number of arguments or None for 2 or more, domain check or None)
FUNCTIONS = {
    "sqrt": (math.sqrt, 1, _domain(lambda x: x >= 0, "needs a non-negative argument")),
    "exp": (math.exp, 1, None),
    "log": (math.log, 1, _POSITIVE),
    "log10": (math.log10, 1, _POSITIVE),
    "sin": (math.sin, 1, None),
    "cos": (math.cos, 1, None),
    "tan": (math.tan, 1, None),
    "abs": (abs, 1, None),
    "floor": (lambda x: float(math.floor(x)), 1, None),
    "ceil": (lambda x: float(math.ceil(x)), 1, None),
    "min": (min, None, None),
    "max": (max, None, None),
}


def _call(func: str, args: list[float], loc: SourceLoc) -> float:
    entry = FUNCTIONS.get(func)
    if entry is None:
        guess = closest(func, [*FUNCTIONS, *draws.FUNCTIONS])
        hint = f"did you mean '{guess}'?" if guess else f"known: {', '.join(FUNCTIONS)}"
        raise NetlistError(f"unknown function '{func}'", loc, hint)
    impl, arity, domain = entry
    if arity is None and len(args) < 2:
        raise NetlistError(f"{func}() takes 2 or more arguments, got {len(args)}", loc)
    if arity is not None and len(args) != arity:
        raise NetlistError(f"{func}() takes {arity} argument, got {len(args)}", loc)
    if domain is not None and not domain[0](args[0]):
        raise NetlistError(f"{func}() {domain[1]}, got {args[0]:g}", loc)
    try:
        return float(impl(*args))
    except OverflowError:
        raise NetlistError(f"overflow in {func}({', '.join(f'{a:g}' for a in args)})",
                           loc) from None
    except ValueError as exc:  # e.g. floor(inf)
        raise NetlistError(f"{func}() failed: {exc}", loc) from None


def _index(name: str, indices: list[float], env: Env, loc: SourceLoc) -> float:
    array = env.lookup(name)
    if array is None:
        raise undefined(name, loc, env, "array")
    if not isinstance(array, np.ndarray):
        raise NetlistError(f"'{name}' is a number, not a .data array; it cannot be indexed", loc)
    if len(indices) != array.ndim:
        raise NetlistError(f"'{name}' has {array.ndim} dimension(s) but {len(indices)} "
                           f"index(es) were given", loc)
    for axis, (i, size) in enumerate(zip(indices, array.shape)):
        if not float(i).is_integer() or not 0 <= i < size:
            raise NetlistError(f"index {i:g} out of range for axis {axis} of '{name}' "
                               f"(size {size}, indices 0..{size - 1})", loc)
    return float(array[tuple(int(i) for i in indices)])


# --- values of arguments (a number, a parameter name or a brace expression) ---------------


def value(arg: ast.Value, env: Env) -> float:
    """The number an argument stands for: a literal, a parameter or a `{...}` expression."""
    match arg:
        case ast.Num(value=number):
            return number
        case ast.Brace(expr=expr):
            return scalar(expr, env)
        case ast.Word():
            name = name_text(arg, env)
            found = env.lookup(name)
            if found is None:
                raise undefined(name, arg.loc, env)
            if isinstance(found, np.ndarray):
                raise NetlistError(f"'{name}' is an array", arg.loc,
                                   f"index it in braces, e.g. {{{name}[0]}}")
            return found
        case ast.Str():
            raise NetlistError(f"expected a number, not the string \"{arg.text}\"", arg.loc)
        case _:
            raise NetlistError("expected a number", arg.loc)


def int_value(arg: ast.Value, env: Env, what: str) -> int:
    """`value(arg)` as an int; an error naming `what` unless it is a whole number."""
    number = value(arg, env)
    if not float(number).is_integer():
        raise NetlistError(f"{what} must be an integer, got {number:g}", arg.loc)
    return int(number)


def name_text(word: ast.Word, env: Env) -> str:
    """The name `word` spells, with its `{expr}` interpolations evaluated (`n{i}` -> `n3`)."""
    parts = word.parts
    if len(parts) == 1 and parts[0].__class__ is str:
        return parts[0]
    out = []
    for part in parts:
        if isinstance(part, str):
            out.append(part)
            continue
        number = integer(part, env, "an interpolation in a name")
        if number < 0:
            raise NetlistError(f"an interpolation in a name gives {number}; names take "
                               "non-negative integers", part.loc)
        out.append(str(number))
    return "".join(out)
