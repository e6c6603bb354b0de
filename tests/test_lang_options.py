"""The `.options` keys (springc/lang/options.py) and their values."""

from __future__ import annotations

import pytest

from springc.integrators import TABLEAUX
from springc.lang.options import KNOWN_OPTIONS, OptionValueError


def test_known_keys() -> None:
    assert set(KNOWN_OPTIONS) == {"method", "substeps", "precision", "outrate"}
    assert KNOWN_OPTIONS["method"].word and KNOWN_OPTIONS["precision"].word
    assert not KNOWN_OPTIONS["substeps"].word and not KNOWN_OPTIONS["outrate"].word


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
