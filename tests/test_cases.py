"""Golden front-end cases: every `tests/cases/ok/*.spr` elaborates to the IR dump beside it
(`*.ir`), and every `tests/cases/err/*.spr` fails with the message and line its header names.

An error case starts with comment lines `* expect: <substring of the formatted error>` and
`* line: N` (the line the error points at), and optionally `* file: <path>` when the error
lies in an included file (relative to the case). After an intended change regenerate the IR
dumps with `python tests/regen_cases.py` and read the diff.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from netlist_cases import ERR

from springc.errors import NetlistError
from springc.lang import load_file

CASES = Path(__file__).resolve().parent / "cases"
OK = sorted((CASES / "ok").glob("*.spr"))
_HEADER = re.compile(r"^\* (expect|line|file): (.*)$")


def _header(path: Path) -> dict[str, str]:
    out = {}
    for line in path.read_text().splitlines():
        match = _HEADER.match(line)
        if not match:
            break
        out[match.group(1)] = match.group(2).strip()
    return out


def test_enough_cases() -> None:
    assert len(OK) >= 8 and len(ERR) >= 25


@pytest.mark.parametrize("case", OK, ids=lambda p: p.stem)
def test_ok_case(case: Path) -> None:
    net = load_file(case)
    net.validate()
    expected = case.with_suffix(".ir").read_text()
    assert net.text() == expected


@pytest.mark.parametrize("case", ERR, ids=lambda p: p.stem)
def test_err_case(case: Path) -> None:
    header = _header(case)
    assert "expect" in header and "line" in header, f"{case.name}: missing header"
    with pytest.raises(NetlistError) as info:
        load_file(case)
    err = info.value
    text = err.format()
    assert header["expect"] in text
    assert err.loc is not None and err.loc.line == int(header["line"]), text
    where = (case.parent / header.get("file", case.name)).resolve()
    assert Path(err.loc.file).resolve() == where, text
    assert "^" in text  # the source line is quoted with a caret
