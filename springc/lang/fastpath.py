"""A fast reader for the common, one-line statements; lark reads everything else.

Lark's LALR parser costs tens of microseconds per token in Python, which is seconds for a
10,000-element netlist. Most lines are simple (`C12 n12 n13 k={kc*2}`), so this module reads
them with one regular expression per line and a small precedence-climbing expression parser,
producing exactly the AST that the grammar (`grammar.lark`) and `parser._ToAst` would. It
never reports an error: any line it is not sure about (interpolated names, `.title`, an
unexpected token, a syntax error) returns None and goes to lark, which gives the message.
`tests/test_lang_fastpath.py` checks that both readers agree.
"""

from __future__ import annotations

import re

from springc.errors import SourceLoc
from springc.lang import ast
from springc.lang.expr import bad_number, read_number

_NAME = r"[A-Za-z_][A-Za-z0-9_]*(?:\.[A-Za-z_][A-Za-z0-9_]*)*(?![A-Za-z0-9_.{])"
_NUMBER = r"(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?[A-Za-z0-9_]*"
_LINE_TOKEN = re.compile(
    rf"[ \t\f]*(?:(?P<num>[+-]?{_NUMBER})|(?P<name>{_NAME})|(?P<dir>\.[A-Za-z_]+)"
    r"|(?P<brace>\{[^{}]*\})|(?P<str>\"[^\"]*\"|'[^']*')|(?P<op>[=(),^]))"
)
_EXPR_TOKEN = re.compile(
    rf"[ \t\f]*(?:(?P<num>{_NUMBER})|(?P<name>{_NAME})"
    r"|(?P<op>\*\*|<=|>=|==|!=|[-+*/<>()\[\],]))"
)
_GLUED = re.compile(r"[A-Za-z0-9_.{}]")
_COMPARE = ("<", "<=", ">", ">=", "==", "!=")


class _Bail(Exception):
    """The fast path cannot read this line; lark will."""


def statement(line: str, lineno: int, file: str, problems: list) -> ast.Statement | None:
    """The statement on `line`, or None to leave the line to lark. Malformed numbers are
    appended to `problems` (see `expr.bad_number`), as the lark transformer does."""
    try:
        tokens = _tokens(_LINE_TOKEN, line, 0)
        if not tokens:
            return None
        found: list = []  # kept only if the whole line is read
        stmt = _Line(tokens, lineno, file, found).statement()
    except (_Bail, RecursionError):  # deep parentheses: lark's LALR parser does not recurse
        return None
    problems.extend(found)
    return stmt


_END = ("end", "", 0)  # sentinel after the last token, so look-ahead needs no bounds checks


def _tokens(pattern: re.Pattern, text: str, offset: int) -> list[tuple[str, str, int]]:
    """(kind, text, 1-based column) of every token, then `_END`; _Bail on anything else."""
    out, pos, end = [], 0, len(text.rstrip())
    while pos < end:
        match = pattern.match(text, pos)
        if match is None:
            raise _Bail
        kind = match.lastgroup
        pos = match.end()
        if kind == "brace" and _GLUED.match(text, pos):
            raise _Bail  # `{a}b`, `{a}{b}`: lark reads these as (bad) interpolated names
        out.append((kind, match.group(kind), match.start(kind) + 1 + offset))
    if out:
        out.append(_END)
    return out


class _Line:
    """Reads one statement from its tokens, mirroring the grammar's `element`/`directive`."""

    def __init__(self, tokens: list, lineno: int, file: str, problems: list) -> None:
        self.tokens, self.i = tokens, 0
        self.lineno, self.file, self.problems = lineno, file, problems

    def loc(self, col: int) -> SourceLoc:
        return SourceLoc(self.file, self.lineno, col)

    def take(self) -> tuple[str, str, int]:
        token = self.tokens[self.i]
        if token is _END:
            raise _Bail
        self.i += 1
        return token

    def statement(self) -> ast.Statement:
        kind, text, col = self.take()
        args = []
        while self.tokens[self.i] is not _END:
            args.append(self.arg())
        loc = SourceLoc(self.file, self.lineno, col)
        if kind == "name":
            return ast.Element(ast.Word((text,), loc), tuple(args), loc)
        if kind == "dir" and text.lower() != ".title":
            return ast.Directive(text[1:].lower(), tuple(args), loc)
        raise _Bail

    def arg(self):
        kind, text, col = self.tokens[self.i]
        after = self.tokens[self.i + 1]
        if kind == "name" and after[0] == "op":
            op = after[1]
            if op == "=":
                self.i += 2
                return ast.Keyword(text, self.value(), SourceLoc(self.file, self.lineno, col))
            if op == "(":
                self.i += 2
                return ast.CallArg(text, self.call_args(), SourceLoc(self.file, self.lineno, col))
            if op == "^":
                self.i += 2
                node = ast.Word((text,), SourceLoc(self.file, self.lineno, col))
                return ast.Factor(node, self.value(), node.loc)
        return self.value()

    def call_args(self) -> tuple:
        args: list = []
        while True:
            kind, text, _ = self.tokens[self.i]
            if kind == "op" and text == ")":
                self.i += 1
                return tuple(args)
            if kind == "op" and text == ",":
                if not args:
                    raise _Bail
                self.i += 1
            args.append(self.value())

    def value(self) -> ast.Value:
        kind, text, col = self.take()
        loc = SourceLoc(self.file, self.lineno, col)
        if kind == "num":
            return _number(text, loc, self.problems)
        if kind == "name":
            return ast.Word((text,), loc)
        if kind == "brace":
            expr = _Expr(_tokens(_EXPR_TOKEN, text[1:-1], col), self).parse()
            return ast.Brace(expr, loc)
        if kind == "str":
            return ast.Str(text[1:-1], loc)
        raise _Bail


def _number(text: str, loc: SourceLoc, problems: list) -> ast.Num:
    value = read_number(text)
    if value is None:
        problems.append(bad_number(text, loc))
        value = 0.0  # never used: parse() raises the problem
    return ast.Num(value, text, loc)


class _Expr:
    """Precedence climbing over the grammar's expression rules (same AST, same positions)."""

    def __init__(self, tokens: list, line: _Line) -> None:
        self.tokens, self.i, self.line = tokens, 0, line

    def parse(self) -> ast.Expr:
        if not self.tokens:
            raise _Bail  # `{}`
        expr = self.compare()
        if self.tokens[self.i] is not _END:
            raise _Bail
        return expr

    def peek_op(self) -> str | None:
        kind, text, _ = self.tokens[self.i]
        return text if kind == "op" else None

    def take(self) -> tuple[str, str, int]:
        token = self.tokens[self.i]
        if token is _END:
            raise _Bail
        self.i += 1
        return token

    def compare(self) -> ast.Expr:
        left = self.sum()
        if self.peek_op() in _COMPARE:
            _, op, col = self.take()
            left = ast.Binary(op, left, self.sum(), self.line.loc(col))
            if self.peek_op() in _COMPARE:
                raise _Bail  # comparisons do not chain in the grammar
        return left

    def sum(self) -> ast.Expr:
        left = self.product()
        while self.peek_op() in ("+", "-"):
            _, op, col = self.take()
            left = ast.Binary(op, left, self.product(), self.line.loc(col))
        return left

    def product(self) -> ast.Expr:
        left = self.unary()
        while self.peek_op() in ("*", "/"):
            _, op, col = self.take()
            left = ast.Binary(op, left, self.unary(), self.line.loc(col))
        return left

    def unary(self) -> ast.Expr:
        if self.peek_op() in ("+", "-"):
            _, op, col = self.take()
            return ast.Unary(op, self.unary(), self.line.loc(col))
        atom = self.atom()
        if self.peek_op() == "**":
            _, op, col = self.take()
            return ast.Binary(op, atom, self.unary(), self.line.loc(col))
        return atom

    def atom(self) -> ast.Expr:
        kind, text, col = self.take()
        loc = self.line.loc(col)
        if kind == "num":
            return _number(text, loc, self.line.problems)
        if kind == "name":
            follow = self.peek_op()
            if follow == "(":
                self.i += 1
                return ast.Call(text, self.items(")", allow_empty=True), loc)
            if follow == "[":
                self.i += 1
                return ast.Index(text, self.items("]", allow_empty=False), loc)
            return ast.Var(text, loc)
        if text == "(":
            inner = self.compare()
            if self.take()[1] != ")":
                raise _Bail
            return inner
        raise _Bail

    def items(self, close: str, allow_empty: bool) -> tuple[ast.Expr, ...]:
        if self.peek_op() == close and allow_empty:
            self.i += 1
            return ()
        out = [self.compare()]
        while self.peek_op() == ",":
            self.i += 1
            out.append(self.compare())
        if self.take()[1] != close:
            raise _Bail
        return tuple(out)
