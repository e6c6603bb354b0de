"""Derivatives of the force templates of `springc.kernels.terms`, as expressions.

A template is a Python expression over fields written `{name}`: sums, differences,
products, quotients, unary signs, numbers and integer powers. `derivative` differentiates
one with respect to a field and `free` lists its fields; the results are Python syntax
trees, simplified only where a factor is 0 or 1 (so no term the rules produce is lost and
none is invented), and `text` writes one back with the fields as a renderer names them.
"""

from __future__ import annotations

import ast
import re

_FIELD = re.compile(r"\{(\w+)\}")
ZERO = ast.Constant(0.0)
ONE = ast.Constant(1.0)


def parse(template: str) -> ast.expr:
    """A template's expression, its fields as names (a unary plus dropped)."""
    return _Plain().visit(ast.parse(_FIELD.sub(r"\1", template.strip()), mode="eval").body)


def free(expr: ast.expr) -> set[str]:
    """The fields an expression reads."""
    return {n.id for n in ast.walk(expr) if isinstance(n, ast.Name)}


def text(expr: ast.expr, names: dict[str, str]) -> str:
    """The expression as code, each field as `names` has it (fields not in it unchanged)."""
    return ast.unparse(_Rename(names).visit(_copy(expr)))


def is_zero(expr: ast.expr) -> bool:
    return isinstance(expr, ast.Constant) and expr.value == 0


def _is_one(expr: ast.expr) -> bool:
    return isinstance(expr, ast.Constant) and expr.value == 1


def add(a: ast.expr, b: ast.expr) -> ast.expr:
    return b if is_zero(a) else a if is_zero(b) else ast.BinOp(a, ast.Add(), b)


def sub(a: ast.expr, b: ast.expr) -> ast.expr:
    return a if is_zero(b) else neg(b) if is_zero(a) else ast.BinOp(a, ast.Sub(), b)


def neg(a: ast.expr) -> ast.expr:
    if isinstance(a, ast.Constant):
        return ast.Constant(-a.value)
    if isinstance(a, ast.UnaryOp) and isinstance(a.op, ast.USub):
        return a.operand
    return ast.UnaryOp(ast.USub(), a)


def mul(a: ast.expr, b: ast.expr) -> ast.expr:
    if is_zero(a) or is_zero(b):
        return ZERO
    if isinstance(b, ast.Constant) and b.value == -1:
        return neg(a)
    if isinstance(a, ast.Constant) and a.value == -1:
        return neg(b)
    return b if _is_one(a) else a if _is_one(b) else ast.BinOp(a, ast.Mult(), b)


def div(a: ast.expr, b: ast.expr) -> ast.expr:
    return ZERO if is_zero(a) else a if _is_one(b) else ast.BinOp(a, ast.Div(), b)


def derivative(expr: ast.expr, field: str) -> ast.expr:
    """d expr / d field, by the sum, product, quotient and power rules."""
    if isinstance(expr, ast.Constant):
        return ZERO
    if isinstance(expr, ast.Name):
        return ONE if expr.id == field else ZERO
    if isinstance(expr, ast.UnaryOp) and isinstance(expr.op, (ast.USub, ast.UAdd)):
        inner = derivative(expr.operand, field)
        return neg(inner) if isinstance(expr.op, ast.USub) else inner
    if isinstance(expr, ast.BinOp):
        return _binop(expr, field)
    raise ValueError(f"a force template may not use {ast.unparse(expr)!r}")


def _binop(expr: ast.BinOp, field: str) -> ast.expr:
    a, b, op = expr.left, expr.right, expr.op
    da, db = derivative(a, field), derivative(b, field)
    if isinstance(op, ast.Add):
        return add(da, db)
    if isinstance(op, ast.Sub):
        return sub(da, db)
    if isinstance(op, ast.Mult):
        return add(mul(da, b), mul(a, db))
    if isinstance(op, ast.Div):  # (a/b)' = a'/b - a b' / (b b)
        return sub(div(da, b), div(mul(a, db), mul(b, b)))
    if isinstance(op, ast.Pow) and isinstance(b, ast.Constant) and field not in free(b):
        power = ast.BinOp(a, ast.Pow(), ast.Constant(b.value - 1)) if b.value != 2 else a
        return mul(mul(ast.Constant(float(b.value)), power), da)
    raise ValueError(f"a force template may not use {ast.unparse(expr)!r}")


class _Plain(ast.NodeTransformer):
    def visit_UnaryOp(self, node: ast.UnaryOp):
        self.generic_visit(node)
        return node.operand if isinstance(node.op, ast.UAdd) else node


class _Rename(ast.NodeTransformer):
    def __init__(self, names: dict[str, str]) -> None:
        self.names = names

    def visit_Name(self, node: ast.Name):
        if node.id in self.names:
            return ast.parse(self.names[node.id], mode="eval").body
        return node


def _copy(expr: ast.expr) -> ast.expr:
    return ast.parse(ast.unparse(expr), mode="eval").body
