"""Text to AST (springc/lang/parser.py): positions, lexical rules, blocks, syntax errors."""

from __future__ import annotations

import pytest

from springc.errors import NetlistError
from springc.lang import ast, parse


def _one(text: str):
    (stmt,) = parse(text, "t.spr").statements
    return stmt


def _syntax(text: str) -> NetlistError:
    with pytest.raises(NetlistError) as info:
        parse(text, "t.spr")
    return info.value


def test_element_positions() -> None:
    stmt = _one("  K1 node_a k={w ** 2}\n")
    assert isinstance(stmt, ast.Element)
    assert (stmt.loc.line, stmt.loc.col) == (1, 3)
    node, kw = stmt.args
    assert node == ast.Word(("node_a",), node.loc) and node.loc.col == 6
    assert kw.key == "k" and kw.loc.col == 13
    power = kw.value.expr
    assert isinstance(power, ast.Binary) and power.op == "**" and power.loc.col == 18
    assert power.left == ast.Var("w", power.left.loc) and power.left.loc.col == 16


def test_continuation_keeps_line_and_column() -> None:
    stmt = _one("M1 a m=1\n* comment inside\n\n+   b=2 ; trailing\n  + x0={x}\n")
    assert [a.key for a in stmt.args[1:]] == ["m", "b", "x0"]
    assert (stmt.args[2].loc.line, stmt.args[2].loc.col) == (4, 5)
    assert (stmt.args[3].value.loc.line, stmt.args[3].value.loc.col) == (5, 8)


def test_comments_and_end() -> None:
    tree = parse("* title-like comment\nM1 a m=1 ; c\n;only comment\n.END\nK1 a k=1\n", "t")
    assert [s.name.parts[0] for s in tree.statements] == ["M1"]
    tree = parse("M1 a m=1\n  .end ; done\nK1 a k=1\n", "t")
    assert len(tree.statements) == 1


def test_semicolon_inside_string_is_not_a_comment() -> None:
    stmt = _one('.data W "a;b.csv" ; comment\n')
    assert stmt.args[1] == ast.Str("a;b.csv", stmt.args[1].loc)


def test_directives_are_case_insensitive_names_are_not() -> None:
    stmt = _one(".PaRaM Abc=1\n")
    assert isinstance(stmt, ast.Directive) and stmt.name == "param"
    assert stmt.args[0].key == "Abc"


def test_title_takes_the_rest_of_the_line() -> None:
    stmt = _one(".TITLE  A two-mode (band-pass) filter: 1k-2k ; comment\n")
    assert stmt == ast.Title("A two-mode (band-pass) filter: 1k-2k", stmt.loc)


def test_argument_kinds() -> None:
    stmt = _one('F1 a sin(1, 50Hz {p}) gain=-2k wav("x.wav") in\n')
    node, call, gain, wav, bare = stmt.args
    assert node.parts == ("a",)
    assert isinstance(call, ast.CallArg) and call.name == "sin" and len(call.args) == 3
    assert call.args[1].value == 50.0 and call.args[1].text == "50Hz"
    assert gain.value.value == -2000.0
    assert wav.args[0].text == "x.wav" and bare.parts == ("in",)


def test_factors() -> None:
    stmt = _one("P1 c=1 a^2 X1.b^{n}\n")
    f1, f2 = stmt.args[1:]
    assert isinstance(f1, ast.Factor) and f1.node.parts == ("a",) and f1.exponent.value == 2
    assert f2.node.parts == ("X1.b",) and isinstance(f2.exponent, ast.Brace)


def test_interpolated_names() -> None:
    stmt = _one("C{i}_{j} n{i} X{i}.out{j+1} k=1\n")
    name, (a, b, _) = stmt.name, stmt.args
    assert [p if isinstance(p, str) else "?" for p in name.parts] == ["C", "?", "_", "?"]
    assert [p if isinstance(p, str) else "?" for p in a.parts] == ["n", "?"]
    assert [p if isinstance(p, str) else "?" for p in b.parts] == ["X", "?", ".out", "?"]
    assert b.parts[3].op == "+" and b.parts[1].loc.col == 17


def test_blocks_nest() -> None:
    tree = parse(".subckt s a b k=1\n.for i 1 2\nM{i} n{i} m=1\n.endfor\n.ENDS s\nX1 p q s\n", "t")
    sub, inst = tree.statements
    assert isinstance(sub, ast.Subckt) and sub.name == "s"
    assert [p.parts[0] for p in sub.ports] == ["a", "b"] and sub.params[0].key == "k"
    (loop,) = sub.body
    assert isinstance(loop, ast.For) and loop.var == "i" and len(loop.body) == 1
    assert isinstance(inst, ast.Element)


@pytest.mark.parametrize(
    ("text", "message", "where", "hint"),
    [
        ("M1 a m=(1)\n", "syntax error: unexpected '('", (1, 8),
         "expected '{', a name, a number or a quoted string"),
        ("M1 a m={1+}\n", "syntax error: unexpected '}'", (1, 11), "a name or a number"),
        ("M1 a\n+ m={2*(3}\n", "syntax error: unexpected '}'", (2, 10), "expected ')'"),
        ("1 2 3\n", "syntax error: unexpected '1'", (1, 1), "element name or a directive"),
        ("M1 a m=1 @\n", "syntax error: unexpected character '@'", (1, 10), None),
        ("M1 a m={1\n", "syntax error: unexpected end of line", (1, 10), "'}'"),
        (".param a=1k5\n", "malformed number '1k5'", (1, 10), "1.5k"),
        ("M1 a m={2 + 1m5}\n", "malformed number '1m5'", (1, 13), None),
    ],
)
def test_syntax_errors(text: str, message: str, where: tuple, hint: str | None) -> None:
    err = _syntax(text)
    assert err.message == message
    assert (err.loc.line, err.loc.col) == where
    if hint:
        assert hint in err.diagnostic.hint
    shown = err.format()
    assert shown.startswith(f"t.spr:{where[0]}:{where[1]}: error: {message}")
    caret_line = shown.splitlines()[2]
    assert caret_line.index("^") - caret_line.index("|") - 2 == where[1] - 1


@pytest.mark.parametrize(
    ("text", "message", "line"),
    [
        (".ends\n", ".ends without a matching .subckt", 1),
        (".endfor\n", ".endfor without a matching .for", 1),
        ("M1 a m=1\n.subckt s a\n", "missing .ends for the .subckt opened here", 2),
        (".for i 1 2\n", "missing .endfor for the .for opened here", 1),
        (".subckt s a\n.endfor\n", ".endfor cannot close the .subckt opened at line 1", 2),
        (".subckt s a\n.ends t\n", ".ends t does not match .subckt s (line 1)", 2),
        (".subckt\n.ends\n", ".subckt needs a name", 1),
        (".subckt s a k=1 b\n.ends\n", "ports must come before the parameters", 1),
        (".for i 1 2 3\n.endfor\n", ".for needs a variable and two bounds", 1),
        (".for {i} 1 2\n.endfor\n", "expected a loop variable name", 1),
        (".for i 1 2\n.subckt s a\n.ends\n.endfor\n", "cannot be inside a .for loop", 2),
    ],
)
def test_block_errors(text: str, message: str, line: int) -> None:
    err = _syntax(text)
    assert message in err.message and err.loc.line == line


def test_the_first_error_in_the_file_is_reported() -> None:
    # a malformed number (found by the fast path) before a syntax error (found by lark)
    err = _syntax("M1 a m=1\nK1 a k=2k2\nK2 a k=(1)\n")
    assert err.message == "malformed number '2k2'" and err.loc.line == 2
    err = _syntax("K2 a k=(1)\nK1 a k=2k2\n")
    assert err.message == "syntax error: unexpected '('" and err.loc.line == 1


def test_deep_nesting_is_read_or_a_user_error() -> None:
    deep = "M1 a m={" + "(" * 1000 + "1" + ")" * 1000 + "}\n"
    assert parse(deep, "t.spr").statements[0].args[1].value.expr.value == 1.0
    err = _syntax("M1 a m={" + "-" * 5000 + "1}\n")
    assert err.message == "t.spr: an expression is nested too deeply to read"
