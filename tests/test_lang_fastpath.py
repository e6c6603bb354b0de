"""The fast one-line reader (springc/lang/fastpath.py) must agree with lark exactly: where it
reads a line, the AST (positions included) equals the grammar's, and it never accepts a line
that the grammar rejects."""

from __future__ import annotations

from unittest import mock

from hypothesis import given, settings
from hypothesis import strategies as st
from lark.exceptions import UnexpectedInput

from springc.errors import NetlistError
from springc.lang import fastpath, parse
from springc.lang.parser import _LARK, _ToAst

EXPRS = ["a", "2", "1k", "-x", "(-2)**3", "-2**2", "a*b+c/d-e", "2**3**2", "sqrt(a)",
         "max(a, 2, b)", "W[1, 2]", "V[i+1]", "a <= b", "a == b != c", "pi*e", "f()",
         "(a", "a +", "1k5", "x.y", "a[]", "-(-(1))", "1e-3*2", "2 > 1 + 1"]
VALUES = ["1", "-2.5k", "50Hz", "1k5", ".5", "a", "X1.out", '"f.wav"', "'g.csv'", "n{i}",
          "{a}b"] + [f"{{{e}}}" for e in EXPRS]
HEADS = ["M1", "k2", "X{i}", "C1_2", ".param", ".PROBE", ".title", ".tran", "1", "=", "("]


@st.composite
def args(draw) -> str:
    kind = draw(st.sampled_from(["value", "key", "call", "factor", "junk"]))
    value = draw(st.sampled_from(VALUES))
    if kind == "key":
        key = draw(st.sampled_from(['m', 'k', 'gain', 'x0']))
        return f"{key}{draw(st.sampled_from(['=', ' = ']))}{value}"
    if kind == "call":
        inner = draw(st.lists(st.sampled_from(VALUES), max_size=3))
        sep = draw(st.sampled_from([" ", ", ", ","]))
        return f"{draw(st.sampled_from(['sin', 'in', 'x', 'wav']))}({sep.join(inner)})"
    if kind == "factor":
        return f"{draw(st.sampled_from(['a', 'X1.b']))}^{value}"
    if kind == "junk":
        return draw(st.sampled_from(["@", ",", ")", "^", "=", "{", "}", "+", "-", "**"]))
    return value


@st.composite
def lines(draw) -> str:
    head = draw(st.sampled_from(HEADS))
    rest = draw(st.lists(args(), max_size=5))
    pad = draw(st.sampled_from(["", " ", "\t"]))
    return pad + " ".join([head, *rest])


def _lark(line: str):
    """(statement, problems) from the grammar, or None if it rejects the line."""
    builder = _ToAst("f")
    try:
        tree = _LARK.parse(line + "\n")
    except UnexpectedInput:
        return None
    (stmt,) = builder.transform(tree).children
    return stmt, builder.problems


@settings(max_examples=400, deadline=None)
@given(lines())
def test_fast_path_agrees_with_the_grammar(line: str) -> None:
    problems: list = []
    fast = fastpath.statement(line, 1, "f", problems)
    if fast is None:
        return  # lark reads it
    slow = _lark(line)
    assert slow is not None, f"fast path accepted a line the grammar rejects: {line!r}"
    assert fast == slow[0]
    assert problems == slow[1]


def test_fast_path_reads_the_common_lines() -> None:
    common = ["M1 a m=1 b={alpha}", "Cab xa xb k={(delta**2 - 1) * wa**2 / 2}",
              "Fa xa in(0) gain={alpha * (1 + delta**2) * wa**2}", ".probe x(xa) v(X1.b)",
              ".tran {1/64000} 1", "P1 c=1 a^2 b^2", "X1 a b filt f0=1k", ".param a=1 b={a}",
              '.include "delayline.spr"', "B1 a 0 b=0.5", "F2 a pwl(0 0, 1m 1)"]
    for line in common:
        fast = fastpath.statement(line, 1, "f", [])
        assert fast is not None, line
        assert fast == _lark(line)[0]


def test_fast_path_leaves_unusual_lines_to_lark() -> None:
    problems: list = []
    for line in [".title x", "M{i} n{i} m=1", "+ m=1", "K1 a k={a}b", "K1 a k=(1)",
                 "M1 a m={1 < 2 < 3}", "K1 a k=@", "M1 a m=1k5 (", "M1 a m={2k2 + [}"]:
        assert fastpath.statement(line, 1, "f", problems) is None, line
    assert problems == []  # a line left to lark leaves its problems to lark too


def _outcome(text: str) -> object:
    """The parsed netlist, or the error's (message, line, col)."""
    try:
        return parse(text, "f")
    except NetlistError as err:
        return (err.message, err.loc.line, err.loc.col)


@settings(max_examples=150, deadline=None)
@given(st.lists(st.one_of(lines(), st.sampled_from(["", "* comment", "+ m=1", "  + k={a}"])),
                max_size=8))
def test_whole_files_parse_the_same_with_and_without_the_fast_path(body: list[str]) -> None:
    text = "\n".join(body) + "\n"
    with mock.patch.object(fastpath, "statement", lambda *args: None):
        reference = _outcome(text)
    outcome = _outcome(text)
    if isinstance(reference, tuple):
        # both fail; the fast path may find a malformed number before lark's syntax error
        assert isinstance(outcome, tuple) and outcome[1:] <= reference[1:]
    else:
        assert outcome == reference
