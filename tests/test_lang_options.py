"""The `.options` keys (springc/lang/options.py) and their values."""

from __future__ import annotations

import pytest

from springc.errors import NetlistError
from springc.kernels.expint import SCHEMES
from springc.kernels.integrators import TABLEAUX
from springc.lang import load_text
from springc.lang.options import KNOWN_OPTIONS, OptionValueError, known_methods


def test_known_keys() -> None:
    assert set(KNOWN_OPTIONS) == {"method", "substeps", "precision", "outrate", "temp", "seed"}
    assert KNOWN_OPTIONS["method"].word and KNOWN_OPTIONS["precision"].word
    assert not KNOWN_OPTIONS["substeps"].word and not KNOWN_OPTIONS["outrate"].word
    assert not KNOWN_OPTIONS["temp"].word and not KNOWN_OPTIONS["seed"].word


@pytest.mark.parametrize("name", sorted(TABLEAUX))
def test_every_integrator_is_a_method(name: str) -> None:
    assert KNOWN_OPTIONS["method"].convert(name.upper()) == name


@pytest.mark.parametrize(
    ("key", "raw", "value"),
    [("substeps", 3.0, 3), ("precision", "Float32", "float32"), ("precision", "float64", "float64"),
     ("outrate", 16000.0, 16000.0)],
)
def test_values(key: str, raw, value) -> None:
    converted = KNOWN_OPTIONS[key].convert(raw)
    assert converted == value and type(converted) is type(value)


@pytest.mark.parametrize(
    ("key", "raw", "message"),
    [("method", "euler", "unknown integration method 'euler'; known: "),
     ("substeps", 0.0, "substeps must be an integer >= 1, not 0"),
     ("substeps", 2.5, "substeps must be an integer >= 1, not 2.5"),
     ("precision", "float16", "precision must be float32 or float64, not 'float16'"),
     ("outrate", 0.0, "outrate must be a positive rate in Hz, not 0"),
     ("outrate", -5.0, "outrate must be a positive rate in Hz, not -5")],
)
def test_bad_values(key: str, raw, message: str) -> None:
    with pytest.raises(OptionValueError) as info:
        KNOWN_OPTIONS[key].convert(raw)
    assert str(info.value).startswith(message)


def test_known_methods_are_the_tableaux_then_the_split_schemes() -> None:
    assert known_methods() == [*TABLEAUX, *SCHEMES]
    assert {"exp-rk4", "strang-rk4"} <= set(known_methods())


@pytest.mark.parametrize("name", sorted(SCHEMES))
def test_split_schemes_are_methods_in_both_spellings(name: str) -> None:
    """Names have no '-' (spec: [A-Za-z_][A-Za-z0-9_]*): a netlist writes exp_rk4."""
    convert = KNOWN_OPTIONS["method"].convert
    assert convert(name) == convert(name.upper()) == convert(name.replace("-", "_")) == name


def test_unknown_method_lists_every_method() -> None:
    with pytest.raises(OptionValueError) as info:
        KNOWN_OPTIONS["method"].convert("exp_rk5")
    assert str(info.value) == (
        "unknown integration method 'exp_rk5'; known: rk4, rk38, ssprk3, heun3, midpoint, "
        "strang-rk4, exp-rk4, exp-heun3 (write strang_rk4, exp_rk4, exp_heun3 or quote the "
        "name in .options)")


SPLIT = "M1 a m=1\nK1 a k=1\nF1 a in(0)\n.options method={}\n.tran 1m 1\n"


@pytest.mark.parametrize(("written", "method"), [("exp_rk4", "exp-rk4"),
                                                 ('"strang-rk4"', "strang-rk4"),
                                                 ("'EXP-RK4'", "exp-rk4"), ("Rk38", "rk38")])
def test_options_method_in_a_netlist(written: str, method: str) -> None:
    assert load_text(SPLIT.format(written), "net.spr").options["method"] == method


def test_options_unknown_method_is_an_error_at_its_value() -> None:
    with pytest.raises(NetlistError) as info:
        load_text(SPLIT.format("exp_rk5"), "net.spr")
    assert (info.value.loc.line, info.value.loc.col) == (4, 17)
    assert "known: rk4, rk38, ssprk3, heun3, midpoint, strang-rk4, exp-rk4" in str(info.value)


def test_bare_hyphenated_method_is_not_a_name() -> None:
    """`method=exp-rk4` is outside the spec's grammar: a syntax error at the '-'."""
    with pytest.raises(NetlistError) as info:
        load_text(SPLIT.format("exp-rk4"), "net.spr")
    assert (info.value.loc.line, info.value.loc.col) == (4, 20)
