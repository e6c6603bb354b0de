"""springc.design.emit: .spr text that reads back to the same numbers, written atomically."""

from __future__ import annotations

import os

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from springc.design.emit import SprWriter, num, params_text, write_atomic
from springc.errors import DataError
from springc.lang import load_text

FLOATS = st.floats(min_value=1e-300, max_value=1e300, allow_nan=False, allow_infinity=False)


@given(FLOATS)
@settings(max_examples=60, deadline=None)
def test_numbers_read_back_bit_for_bit_through_the_parser(x):
    """A mass written with num() elaborates to exactly the same float64."""
    net = load_text(f"M1 a m={num(x)}\n")
    assert net.masses.m[0] == x


@pytest.mark.parametrize("x,text", [(0.0, "0"), (12.0, "12"), (-3.5, "-3.5"), (1e-6, "1e-6"),
                                    (2.5e12, "2.5e12"), (1e16, "1e16"),
                                    (1000.0, "1000"), (1e5, "1e5"), (1e-3, "0.001")])
def test_number_text(x, text):
    assert num(x) == text


def test_non_finite_numbers_are_refused():
    with pytest.raises(ValueError):
        num(float("nan"))


def test_long_statements_wrap_with_continuations_that_parse_back():
    w = SprWriter()
    w.subckt("wide", [f"port{i}" for i in range(40)])
    for i in range(40):
        w.statement(f"M{i}", f"port{i}", "m=1")
    w.ends("wide")
    w.statement("Xw", *[f"n{i}" for i in range(40)], "wide")
    text = w.text()
    assert max(len(line) for line in text.splitlines()) <= 100
    assert sum(line.startswith("+") for line in text.splitlines()) >= 2
    net = load_text(text)
    assert net.nodes == [f"n{i}" for i in range(40)]


def test_params_file_defines_its_parameters():
    text = params_text("dl", {"m": 1e-3, "kc": 10.0}, "title", "Xd a b delayline")
    net = load_text(text + "M1 a m={dl_m * dl_kc}\n")
    assert net.masses.m[0] == pytest.approx(1e-2)


def test_write_atomic_leaves_no_temporary_file(tmp_path):
    path = write_atomic(tmp_path / "a.spr", "* hello\n")
    assert path.read_text() == "* hello\n"
    assert os.listdir(tmp_path) == ["a.spr"]
    assert oct(path.stat().st_mode & 0o777) == oct(0o644)


def test_write_atomic_keeps_the_old_file_when_writing_fails(tmp_path):
    (tmp_path / "a.spr").write_text("old\n")
    with pytest.raises(TypeError):
        write_atomic(tmp_path / "a.spr", None)  # not text: fails while writing
    assert (tmp_path / "a.spr").read_text() == "old\n"
    assert os.listdir(tmp_path) == ["a.spr"]


def test_write_into_a_missing_folder_is_a_data_error(tmp_path):
    with pytest.raises(DataError, match="does not exist"):
        write_atomic(tmp_path / "nope" / "a.spr", "x")
