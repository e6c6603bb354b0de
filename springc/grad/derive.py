"""Forward-mode derivatives of a netlist's expressions, written as netlist expressions.

`tangent_tree(tree, seed, prefix)` returns a netlist whose elaboration puts, in every
element coefficient (m b x0 v0 k l a g c gain), the derivative of that coefficient with
respect to the top-level `.param` `seed` instead of its value. Every parameter `q` (top level,
subcircuit, instance override, `.for` variable) gets a companion `<prefix>q` holding dq/dseed,
defined beside it, so the companions follow the language's own scoping. The compiler's own
evaluator then computes the derivatives: exact to rounding, no step size, no second evaluator.

The rules are the calculus of each operator and function of the expression language:
comparisons, `floor` and `ceil` have derivative 0; `abs`, `min`, `max` that of the branch
they take (the same branch the value took); a random function, its draw nom + scale * u
(`springc.lang.draws.values`) with the unit deviate u of its site held fixed: d nom +
u d scale, u written as an `ast.Deviate` naming the call's site (the value's key and the
call's place in evaluation order), so that the tangent's elaboration in the same Monte Carlo
sample reads the value's own u (0 outside a sample: the nominal value's derivative).
"""

from __future__ import annotations

import math
from dataclasses import replace

from springc.errors import SourceLoc
from springc.lang import ast, draws
from springc.lang.expr import CONSTANTS
from springc.lang.elements import SPECS

# every element keyword that becomes a coefficient in the IR (not `X` overrides)
COEFFICIENT_KEYS = frozenset(k for s in SPECS.values() for k in (*s.required, *s.optional))

Zero = None  # a derivative that is identically zero (pruned, so no log(0) or 0/0 appears)


def tangent_tree(statements: list, file: str, seed: str, prefix: str) -> ast.Netlist:
    """The tangent netlist of `statements` (includes already spliced in) for `.param seed`."""
    d = _Tangent(seed, prefix)
    loc = SourceLoc(file, 0, 0)
    consts = ast.Directive("param", tuple(
        ast.Keyword(prefix + name, _num(0.0, loc), loc) for name in CONSTANTS), loc)
    return ast.Netlist(file, (consts, *d.statements(statements, top=True)))


def _num(value: float, loc: SourceLoc) -> ast.Num:
    return ast.Num(float(value), repr(float(value)), loc)


class _Tangent:
    """The statement and expression rules for one seed parameter."""

    def __init__(self, seed: str, prefix: str) -> None:
        self.seed, self.prefix = seed, prefix
        self.key = ""  # the key whose value is being differentiated (its draws' site)
        self.order: dict[int, int] = {}  # id of each random call of that value -> its n

    # --- statements ----------------------------------------------------------------------

    def statements(self, stmts, top: bool) -> tuple:
        return tuple(self.statement(s, top) for s in stmts)

    def statement(self, stmt, top: bool):
        match stmt:
            case ast.Directive(name="param"):
                return replace(stmt, args=tuple(a for kw in stmt.args
                                                for a in self.param(kw, top)))
            case ast.Directive() | ast.Title():
                return stmt
            case ast.Element():
                return self.element(stmt)
            case ast.Subckt():
                params = tuple(a for kw in stmt.params for a in self.pair(kw))
                return replace(stmt, params=params, body=self.statements(stmt.body, False))
            case ast.For():
                zero = ast.Directive("param", (ast.Keyword(self.prefix + stmt.var,
                                                           _num(0.0, stmt.loc), stmt.loc),),
                                     stmt.loc)
                return replace(stmt, body=(zero, *self.statements(stmt.body, False)))
            case _:
                raise TypeError(f"unknown statement {stmt!r}")

    def param(self, kw, top: bool) -> tuple:
        """`.param q=E` -> `q=E <prefix>q=dE` (the seed's own top-level definition: 1)."""
        if not isinstance(kw, ast.Keyword):
            return (kw,)  # the elaborator reports it
        if top and kw.key == self.seed:
            return (kw, ast.Keyword(self.prefix + kw.key, _num(1.0, kw.loc), kw.loc))
        return self.pair(kw)

    def pair(self, kw: ast.Keyword) -> tuple:
        return (kw, ast.Keyword(self.prefix + kw.key, self.value(kw.value, kw.key), kw.loc))

    def element(self, stmt: ast.Element) -> ast.Element:
        letter = stmt.name.parts[0][:1].upper()
        args, given = [], set()
        for arg in stmt.args:
            if not isinstance(arg, ast.Keyword):
                args.append(arg)
            elif letter == "X":
                args.extend(self.pair(arg))
            elif arg.key.lower() in COEFFICIENT_KEYS:
                args.append(replace(arg, value=self.value(arg.value, arg.key.lower())))
                given.add(arg.key.lower())
            else:
                args.append(arg)  # an unknown key: the elaborator reports it
        # a default (a=1, gain=1) is a constant: its derivative is 0, not the default
        for key in SPECS[letter].optional if letter in SPECS else ():
            if key not in given:
                args.append(ast.Keyword(key, _num(0.0, stmt.loc), stmt.loc))
        return replace(stmt, args=tuple(args))

    # --- values and expressions ----------------------------------------------------------

    def value(self, arg, key: str) -> ast.Value:
        """The derivative of a value argument given to `key` (a parameter or element key:
        where its random calls draw), as a value argument."""
        match arg:
            case ast.Num():
                return _num(0.0, arg.loc)
            case ast.Word():
                parts = (self.prefix + arg.parts[0], *arg.parts[1:])
                return replace(arg, parts=parts)
            case ast.Brace(expr=expr):
                self.key, self.order = key, _draw_order(expr)
                d = self.expr(expr)
                return _num(0.0, arg.loc) if d is Zero else replace(arg, expr=d)
            case _:
                return arg  # a string where a number belongs: the elaborator reports it

    def expr(self, e):
        """d e / d seed as an expression, or `Zero`."""
        match e:
            case ast.Num() | ast.Index():
                return Zero
            case ast.Var(name=name, loc=loc):
                return ast.Var(self.prefix + name, loc)
            case ast.Unary(op=op, operand=u):
                du = self.expr(u)
                return du if op == "+" or du is Zero else ast.Unary("-", du, e.loc)
            case ast.Binary():
                return self.binary(e)
            case ast.Call():
                return self.call(e)
            case _:
                raise TypeError(f"not an expression node: {e!r}")

    def binary(self, e: ast.Binary):
        u, v, loc = e.left, e.right, e.loc
        du, dv = self.expr(u), self.expr(v)
        match e.op:
            case "+":
                return _add(du, dv, loc)
            case "-":
                return _add(du, _neg(dv, loc), loc)
            case "*":
                return _add(_mul(du, v, loc), _mul(u, dv, loc), loc)
            case "/":  # du/v - u dv / v^2
                first = _div(du, v, loc)
                second = _div(_mul(u, dv, loc), ast.Binary("*", v, v, loc), loc)
                return _add(first, _neg(second, loc), loc)
            case "**":
                return self.power(u, v, du, dv, loc)
            case "<" | "<=" | ">" | ">=" | "==" | "!=":
                return Zero
            case _:
                raise TypeError(f"unknown operator {e.op!r}")

    def power(self, u, v, du, dv, loc: SourceLoc):
        """d(u^v) = v u^(v-1) du + u^v log(u) dv; the second term only where the exponent
        depends on the seed (u > 0 there, else u^v has no real derivative in v)."""
        one = _num(1.0, loc)
        first = _mul(_mul(v, ast.Binary("**", u, ast.Binary("-", v, one, loc), loc), loc),
                     du, loc)
        if dv is Zero:
            return first
        second = _mul(ast.Binary("**", u, v, loc), ast.Call("log", (u,), loc), loc)
        return _add(first, _mul(second, dv, loc), loc)

    def call(self, e: ast.Call):
        args, loc = e.args, e.loc
        if e.func in ("min", "max"):
            return self.extremum(e)
        if e.func in draws.FUNCTIONS:
            return self.draw(e)
        if e.func in ("floor", "ceil") or len(args) != 1:
            return Zero  # a wrong arity is the elaborator's error to report
        u = args[0]
        du = self.expr(u)
        if du is Zero:
            return Zero
        return _mul(_outer(e.func, u, loc), du, loc)

    def draw(self, e: ast.Call):
        """d(nom + scale u) = d nom + u d scale, u the call's unit deviate (fixed)."""
        if len(e.args) < 2:
            return self.expr(e.args[0]) if e.args else Zero  # the elaborator reports it
        nom, spread, loc = e.args[0], e.args[1], e.loc
        scale = (ast.Binary("*", ast.Call("abs", (nom,), loc), spread, loc)
                 if e.func in ("gauss", "unif") else spread)
        if len(e.args) == 3:  # sigma (gauss, agauss)
            scale = ast.Binary("/", scale, e.args[2], loc)
        unit = ast.Deviate(e.func, self.key, self.order[id(e)], loc)
        return _add(self.expr(nom), _mul(unit, self.expr(scale), loc), loc)

    def extremum(self, e: ast.Call):
        """The derivative of the argument `min`/`max` returns (Python's: the first of equal
        ones): arg k is taken when it beats every earlier one strictly and ties no later one."""
        strict, loose = ("<", "<=") if e.func == "min" else (">", ">=")
        total = Zero
        for k, ak in enumerate(e.args):
            dk = self.expr(ak)
            if dk is Zero:
                continue
            term = dk
            for j, aj in enumerate(e.args):
                if j != k:
                    term = _mul(term, ast.Binary(strict if j < k else loose, ak, aj, e.loc),
                                e.loc)
            total = _add(total, term, e.loc)
        return total


def _draw_order(expr) -> dict[int, int]:
    """Each random call of `expr` (by id) -> its place n among the value's random calls in
    the order `springc.lang.expr.evaluate` makes them: operands left to right, a call's
    arguments before the call."""
    order: dict[int, int] = {}

    def walk(e) -> None:
        match e:
            case ast.Unary(operand=u):
                walk(u)
            case ast.Binary(left=u, right=v):
                walk(u)
                walk(v)
            case ast.Call(func=func, args=args):
                for a in args:
                    walk(a)
                if func in draws.FUNCTIONS:
                    order[id(e)] = len(order)
            case ast.Index(indices=items):
                for item in items:
                    walk(item)

    walk(expr)
    return order


def _outer(func: str, u, loc: SourceLoc):
    """f'(u) for the one-argument functions of the language."""
    call = lambda name, arg: ast.Call(name, (arg,), loc)  # noqa: E731
    num = lambda x: _num(x, loc)  # noqa: E731
    match func:
        case "sqrt":
            return ast.Binary("/", num(0.5), call("sqrt", u), loc)
        case "exp":
            return call("exp", u)
        case "log":
            return ast.Binary("/", num(1.0), u, loc)
        case "log10":
            return ast.Binary("/", num(1.0 / math.log(10.0)), u, loc)
        case "sin":
            return call("cos", u)
        case "cos":
            return ast.Unary("-", call("sin", u), loc)
        case "tan":
            return ast.Binary("/", num(1.0), ast.Binary("**", call("cos", u), num(2.0), loc),
                              loc)
        case "abs":  # sign(u); 0 at u = 0
            return ast.Binary("-", ast.Binary(">", u, num(0.0), loc),
                              ast.Binary("<", u, num(0.0), loc), loc)
        case _:
            return num(0.0)  # an unknown function: the elaborator reports it


def _add(a, b, loc):
    if a is Zero:
        return b
    return a if b is Zero else ast.Binary("+", a, b, loc)


def _neg(a, loc):
    return Zero if a is Zero else ast.Unary("-", a, loc)


def _mul(a, b, loc):
    return Zero if a is Zero or b is Zero else ast.Binary("*", a, b, loc)


def _div(a, b, loc):
    return Zero if a is Zero else ast.Binary("/", a, b, loc)
