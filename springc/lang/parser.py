"""Text to AST: `parse(text, filename) -> ast.Netlist`.

Three steps: `_clean` blanks comments and everything after `.end` without moving any
character, so lark's line and column are the user's; the grammar (`grammar.lark`, read by lark
and mapped to frozen `ast` nodes by `_ToAst`) gives the statements, except for the simple
one-line ones that `fastpath` reads to the same AST much faster; `_nest` groups
`.subckt`/`.ends` and `.for`/`.endfor` into blocks. Syntax errors become `NetlistError`s that
quote the line with a caret and say in words what was expected.
"""

from __future__ import annotations

import re

from lark import Lark, Token, Transformer, v_args
from lark.exceptions import UnexpectedCharacters, UnexpectedEOF, UnexpectedInput, UnexpectedToken

from springc.errors import NetlistError, SourceLoc, register_source
from springc.lang import ast, fastpath
from springc.lang.expr import bad_number, read_number

# cache: lark keeps the analysed grammar in the system's temporary folder, keyed by the
# grammar's hash and lark's version (a third of the parser's import otherwise)
_LARK = Lark.open("grammar.lark", rel_to=__file__, parser="lalr", propagate_positions=True,
                  maybe_placeholders=False, cache=True)

_END = re.compile(r"\s*\.end\s*$", re.IGNORECASE)
_STRING_OR_SEMI = re.compile(r"\"[^\"]*\"|'[^']*'|;")


def parse(text: str, filename: str) -> ast.Netlist:
    """Parse .spr source `text` (named `filename` in messages) into an `ast.Netlist`."""
    register_source(filename, text)
    lines = _clean(text)
    fast, problems = _fast_lines(lines, filename)
    builder = _ToAst(filename)
    # lark parses every line the fast path left (same line numbers: the others are blanked)
    rest = "\n".join("" if i in fast else line for i, line in enumerate(lines)) + "\n"
    try:
        slow = builder.transform(_LARK.parse(rest)).children
    except RecursionError:
        raise NetlistError(f"{filename}: an expression is nested too deeply to read") from None
    except UnexpectedInput as err:
        syntax = _syntax_error(err, filename)
        problems.append((syntax.message, syntax.loc, syntax.diagnostic.hint))
        slow = []
    problems += builder.problems
    if problems:  # the first in the file, whichever reader found it
        message, loc, hint = min(problems, key=lambda p: (p[1].line, p[1].col))
        raise NetlistError(message, loc, hint)
    statements = sorted([*fast.values(), *slow], key=lambda s: (s.loc.line, s.loc.col))
    return ast.Netlist(filename, _nest(statements))


def _fast_lines(lines: list[str], filename: str) -> tuple[dict, list]:
    """Statements of the lines the fast path can read, by line index, and the malformed
    numbers met; continued lines (`+`) and anything unusual are left to lark."""
    fast: dict[int, ast.Statement] = {}
    problems: list[tuple[str, SourceLoc, str]] = []
    continued = False  # whether the line after the current one continues it
    for i in range(len(lines) - 1, -1, -1):
        stripped = lines[i].lstrip()
        if not stripped:
            continue
        if not continued and stripped[0] != "+":
            stmt = fastpath.statement(lines[i], i + 1, filename, problems)
            if stmt is not None:
                fast[i] = stmt
        continued = stripped[0] == "+"
    return fast, problems


def _clean(text: str) -> list[str]:
    """The lines with `*` comment lines and `;` comments blanked and nothing after `.end`;
    every remaining character keeps its line and column."""
    out = []
    for line in text.splitlines():
        if line.lstrip().startswith("*"):
            line = ""
        elif ";" in line:
            line = _cut_comment(line)
        if _END.match(line):
            break
        out.append(line)
    return out


def _cut_comment(line: str) -> str:
    """`line` up to a `;` that is not inside a quoted string."""
    for match in _STRING_OR_SEMI.finditer(line):
        if match.group() == ";":
            return line[: match.start()]
    return line


# --- tree to AST ---------------------------------------------------------------------------


@v_args(inline=True)
class _ToAst(Transformer):
    """Builds `ast` nodes from lark's tree. Positions only: no checks here (lark would wrap
    any exception in VisitError); malformed numbers are collected in `problems`."""

    def __init__(self, filename: str) -> None:
        super().__init__()
        self.file = filename
        self.problems: list[tuple[str, SourceLoc, str]] = []

    def _loc(self, token: Token) -> SourceLoc:
        return SourceLoc(self.file, token.line, token.column)

    def element(self, name: ast.Word, *args) -> ast.Element:
        return ast.Element(name, args, name.loc)

    def directive(self, token: Token, *args) -> ast.Directive:
        return ast.Directive(token[1:].lower(), args, self._loc(token))

    def title(self, token: Token) -> ast.Title:
        return ast.Title(token[len(".title"):].strip(), self._loc(token))

    def keyword(self, key: Token, value) -> ast.Keyword:
        return ast.Keyword(str(key), value, self._loc(key))

    def call(self, name: Token, *args) -> ast.CallArg:
        return ast.CallArg(str(name), tuple(a for a in args if a is not None), self._loc(name))

    def factor(self, node: ast.Word, exponent) -> ast.Factor:
        return ast.Factor(node, exponent, node.loc)

    def number(self, token: Token) -> ast.Num:
        value = read_number(token)
        loc = self._loc(token)
        if value is None:
            self.problems.append(bad_number(str(token), loc))
            value = 0.0  # never used: parse() raises the problem
        return ast.Num(value, str(token), loc)

    def string(self, token: Token) -> ast.Str:
        return ast.Str(token[1:-1], self._loc(token))

    def brace(self, lbrace: Token, expr) -> ast.Brace:
        return ast.Brace(expr, self._loc(lbrace))

    def word(self, token: Token) -> ast.Word:
        return ast.Word((str(token),), self._loc(token))

    def iword(self, first: Token, *rest) -> ast.Word:
        # Tokens carry the literal text around the braces: `n{` expr `}_` expr `}`.
        parts: list = [first[:-1]] if len(first) > 1 else []
        for item in rest:
            if isinstance(item, Token):
                text = item[1:].rstrip("{")
                if text:
                    parts.append(text)
            else:
                parts.append(item)
        return ast.Word(tuple(parts), self._loc(first))

    def var(self, token: Token) -> ast.Var:
        return ast.Var(str(token), self._loc(token))

    def func(self, name: Token, *args) -> ast.Call:
        return ast.Call(str(name), tuple(a for a in args if a is not None), self._loc(name))

    def index(self, name: Token, *indices) -> ast.Index:
        return ast.Index(str(name), indices, self._loc(name))

    def binary(self, left, op: Token, right) -> ast.Binary:
        return ast.Binary(str(op), left, right, self._loc(op))

    compare = binary

    def unary(self, op: Token, operand) -> ast.Unary:
        return ast.Unary(str(op), operand, self._loc(op))


# --- blocks --------------------------------------------------------------------------------


def _nest(statements: list) -> tuple[ast.Statement, ...]:
    """Group `.subckt` ... `.ends` and `.for` ... `.endfor` into `Subckt` and `For` blocks."""
    stack: list[tuple[ast.Directive, list]] = [(None, [])]
    for stmt in statements:
        name = stmt.name if isinstance(stmt, ast.Directive) else None
        if name in ("subckt", "for"):
            if name == "subckt" and any(d.name == "for" for d, _ in stack[1:]):
                raise NetlistError("a .subckt definition cannot be inside a .for loop", stmt.loc,
                                   "define the subcircuit outside and instantiate it in the loop")
            stack.append((stmt, []))
        elif name in ("ends", "endfor"):
            opener, body = stack.pop() if len(stack) > 1 else (None, None)
            stack[-1][1].append(_close(opener, body, stmt))
        else:
            stack[-1][1].append(stmt)
    if len(stack) > 1:
        opener = stack[-1][0]
        closer = "ends" if opener.name == "subckt" else "endfor"
        raise NetlistError(f"missing .{closer} for the .{opener.name} opened here", opener.loc,
                           f"end the block with .{closer}")
    return tuple(stack[0][1])


def _close(opener: ast.Directive | None, body: list | None, closer: ast.Directive):
    """The block that `closer` (.ends or .endfor) ends."""
    want = "subckt" if closer.name == "ends" else "for"
    if opener is None:
        raise NetlistError(f".{closer.name} without a matching .{want}", closer.loc)
    if opener.name != want:
        raise NetlistError(
            f".{closer.name} cannot close the .{opener.name} opened at line {opener.loc.line}",
            closer.loc, f"close the .{opener.name} with "
                        f".{'ends' if opener.name == 'subckt' else 'endfor'} first")
    if want == "subckt":
        return _subckt(opener, tuple(body), closer)
    return _for(opener, tuple(body), closer)


def _plain_word(arg, what: str, loc: SourceLoc) -> str:
    if not isinstance(arg, ast.Word) or not arg.plain:
        raise NetlistError(f"expected {what}", getattr(arg, "loc", loc))
    return arg.parts[0]


def _subckt(head: ast.Directive, body: tuple, closer: ast.Directive) -> ast.Subckt:
    if not head.args:
        raise NetlistError(".subckt needs a name", head.loc, "write .subckt NAME PORT... p=v")
    name = _plain_word(head.args[0], "a subcircuit name", head.loc)
    ports, params = [], []
    for arg in head.args[1:]:
        if isinstance(arg, ast.Keyword):
            params.append(arg)
        elif params:
            raise NetlistError("ports must come before the parameters", arg.loc)
        else:
            _plain_word(arg, "a port name", head.loc)
            ports.append(arg)
    _closing_name(closer, name, head)
    return ast.Subckt(name, tuple(ports), tuple(params), body, head.loc)


def _closing_name(closer: ast.Directive, name: str, head: ast.Directive) -> None:
    if not closer.args:
        return
    given = _plain_word(closer.args[0], "the subcircuit name", closer.loc)
    if given != name or len(closer.args) > 1:
        raise NetlistError(f".ends {given} does not match .subckt {name} "
                           f"(line {head.loc.line})", closer.args[0].loc)


def _for(head: ast.Directive, body: tuple, closer: ast.Directive) -> ast.For:
    args = head.args
    if len(args) != 3 or any(isinstance(a, (ast.Keyword, ast.CallArg, ast.Factor, ast.Str))
                             for a in args):
        raise NetlistError(".for needs a variable and two bounds", head.loc,
                           "write .for i FIRST LAST (bounds may be {expressions})")
    var = _plain_word(args[0], "a loop variable name", head.loc)
    if closer.args:
        raise NetlistError(".endfor takes no arguments", closer.args[0].loc)
    return ast.For(var, args[1], args[2], body, head.loc)


# --- syntax errors -------------------------------------------------------------------------

_READABLE = {
    "NAME": "a name", "NAME_OPEN": "a name", "SNUMBER": "a number", "ENUMBER": "a number",
    "STRING": "a quoted string", "DIRECTIVE": "a directive", "TITLE": ".title",
    "_NL": "end of line", "$END": "end of file", "COMPARE": "a comparison",
    "ADD_OP": "'+' or '-'", "MUL_OP": "'*' or '/'", "POW": "'**'", "RBRACE": "'}'",
    "CLOSE_MORE": "'}'", "CLOSE_END": "'}'", "LBRACE": "'{'",
}


def _readable(terminal: str) -> str:
    if terminal in _READABLE:
        return _READABLE[terminal]
    try:
        pattern = _LARK.get_terminal(terminal).pattern
    except KeyError:
        return terminal.lower()
    return f"'{pattern.value}'"


def _expected_words(names) -> str:
    words = sorted({_readable(n) for n in names if n not in ("WS", "_CONT")})
    if not words:
        return ""
    if len(words) == 1:
        return words[0]
    return ", ".join(words[:-1]) + " or " + words[-1]


def _syntax_error(err: UnexpectedInput, filename: str) -> NetlistError:
    loc = SourceLoc(filename, err.line if err.line > 0 else 1, max(err.column, 1))
    if isinstance(err, UnexpectedToken):
        token = err.token
        found = "end of line" if token.type == "_NL" else (
            "end of file" if token.type == "$END" else f"'{token}'")
        expected = err.accepts or err.expected
    elif isinstance(err, UnexpectedCharacters):
        found = f"character '{err.char}'"
        expected = err.allowed or set()
    elif isinstance(err, UnexpectedEOF):
        found, expected = "end of file", err.expected
    else:
        found, expected = "input", set()
    words = _expected_words(expected)
    hint = f"expected {words}" if words else None
    start = "a statement must start with an element name or a directive"
    if words and ("a directive" in words and "a name" in words):
        hint = f"{start}, e.g. 'M1 a m=1' or '.param'"
    return NetlistError(f"syntax error: unexpected {found}", loc, hint)
