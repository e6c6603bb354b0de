"""Numbers with SPICE suffixes and the expression evaluator (springc/lang/expr.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from springc.errors import NetlistError
from springc.lang import parse
from springc.lang.expr import Env, evaluate, read_number


@pytest.mark.parametrize(
    ("text", "value"),
    [
        ("12", 12.0), ("-3.5", -3.5), ("1e-3", 1e-3), (".5", 0.5), ("+2", 2.0),
        ("1t", 1e12), ("1G", 1e9), ("1meg", 1e6), ("1MEG", 1e6), ("2Meg", 2e6),
        ("1k", 1e3), ("1K", 1e3), ("1m", 1e-3), ("1M", 1e-3), ("1u", 1e-6), ("1n", 1e-9),
        ("1p", 1e-12), ("1f", 1e-15), ("1F", 1e-15),
        ("50Hz", 50.0), ("10ms", 0.01), ("20us", 2e-5), ("1megHz", 1e6), ("3V", 3.0),
        ("2.5e3k", 2.5e6), ("1e", 1.0),
    ],
)
def test_read_number(text: str, value: float) -> None:
    assert read_number(text) == value


@pytest.mark.parametrize("text", ["1k5", "1m2s", "2x3", "1_0"])
def test_read_number_rejects_digits_after_suffix(text: str) -> None:
    assert read_number(text) is None


def _eval(src: str, **names) -> float:
    tree = parse(f".param zz={{{src}}}\n", "<expr>")
    expr = tree.statements[0].args[0].value.expr
    return evaluate(expr, Env(dict(names)))


@pytest.mark.parametrize(
    ("src", "value"),
    [
        ("(-2)**3", -8.0), ("-2**2", -4.0), ("2**3**2", 512.0), ("2**-1", 0.5),
        ("(-2)**2", 4.0), ("-(-3)", 3.0), ("1 + 2 * 3 - 4 / 2", 5.0), ("(1 + 2) * 3", 9.0),
        ("8 / 4 / 2", 1.0), ("10 - 4 - 3", 3.0), ("3 > 2", 1.0), ("3 <= 2", 0.0),
        ("2 == 2", 1.0), ("2 != 2", 0.0), ("1 + 1 < 3", 1.0), ("2 >= 2", 1.0), ("1 < 0", 0.0),
        ("pi", math.pi), ("e", math.e), ("sqrt(2)", math.sqrt(2)), ("exp(1)", math.e),
        ("log(e**2)", 2.0), ("log10(1k)", 3.0), ("sin(pi/6)", math.sin(math.pi / 6)),
        ("cos(pi)", -1.0), ("tan(pi/4)", math.tan(math.pi / 4)), ("abs(-2.5)", 2.5),
        ("floor(-1.5)", -2.0), ("ceil(-1.5)", -1.0), ("min(3, 1, 2)", 1.0),
        ("max(3, 1, 2)", 3.0), ("2*pi*1k", 2 * math.pi * 1000), ("1meg/1k", 1000.0),
    ],
)
def test_evaluate(src: str, value: float) -> None:
    assert _eval(src) == pytest.approx(value, rel=1e-15)


def test_names_and_arrays() -> None:
    w = np.arange(6.0).reshape(2, 3)
    assert _eval("a * b + 1", a=2.0, b=3.0) == 7.0
    assert _eval("W[1, 2] + W[0, 1]", W=w) == 6.0
    assert _eval("V[2]", V=np.array([1.0, 2.0, 3.0])) == 3.0
    assert _eval("V[i + 1]", V=np.array([1.0, 2.0, 3.0]), i=1.0) == 3.0


@pytest.mark.parametrize(
    ("src", "message", "col"),
    [
        ("1 / (2 - 2)", "division by zero", 14),
        ("0 ** -1", "division by zero", 14),
        ("sqrt(-1)", "sqrt() needs a non-negative argument, got -1", 12),
        ("log(0)", "log() needs a positive argument, got 0", 12),
        ("log10(-1)", "log10() needs a positive argument", 12),
        ("(-8) ** (1/3)", "a negative number (-8) to a fractional power", 17),
        ("sqrt(1, 2)", "sqrt() takes 1 argument, got 2", 12),
        ("max(1)", "max() takes 2 or more arguments, got 1", 12),
        ("sqr(2)", "unknown function 'sqr'", 12),
        ("exp(1000)", "overflow in exp(1000)", 12),
        ("1e200 * 1e200", "overflow in '*': the result is inf", 18),
        ("-1e308 - 1e308", "overflow in '-': the result is -inf", 19),
        ("alpah * 2", "undefined parameter 'alpah'", 12),
        ("V[3]", "index 3 out of range for axis 0 of 'V' (size 3, indices 0..2)", 12),
        ("V[0.5]", "index 0.5 out of range", 12),
        ("V[0, 1]", "'V' has 1 dimension(s) but 2 index(es)", 12),
        ("alpha[0]", "'alpha' is a number, not a .data array", 12),
        ("V + 1", "'V' is an array of shape (3,)", 12),
    ],
)
def test_errors(src: str, message: str, col: int) -> None:
    with pytest.raises(NetlistError) as info:
        _eval(src, alpha=1.0, V=np.array([1.0, 2.0, 3.0]))
    assert message in info.value.message
    assert (info.value.loc.line, info.value.loc.col) == (1, col)


def test_a_literal_beyond_double_range_is_a_located_error() -> None:
    assert read_number("1e308") == 1e308 and read_number("1e400") is None
    with pytest.raises(NetlistError) as info:
        parse("M1 a m=1e400\n", "net.spr")
    assert info.value.message == "number '1e400' is beyond the range of a double"
    assert (info.value.loc.line, info.value.loc.col) == (1, 8)


def test_undefined_suggests_closest_name() -> None:
    with pytest.raises(NetlistError) as info:
        _eval("alpah * 2", alpha=1.0)
    assert info.value.diagnostic.hint == "did you mean 'alpha'?"


def test_env_scopes_shadow() -> None:
    outer = Env({"a": 1.0, "b": 2.0})
    inner = Env({"a": 10.0}, outer)
    assert inner.lookup("a") == 10.0 and inner.lookup("b") == 2.0
    assert inner.lookup("pi") == math.pi and inner.lookup("nope") is None
    assert {"a", "b", "pi", "e"} <= inner.names()
