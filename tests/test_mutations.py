"""Mutation test of the whole front end (issue 2): broken variants of valid netlists.

Each operator (`netlist_cases.OPERATORS`) turns one statement of a valid example netlist into
one that is certainly invalid (deleted required token, bad suffix, wrong sign, truncated line,
undefined name, ...).
For every variant `springc build` must exit 1 with a `file:line:col: error:` message whose line
is a real line of the mutated file, and must not print a traceback. The sources are the example
netlists, the ok cases and the library files of `netlists/lib` (each mutated in a copy of the
library and instantiated from a small top file, `LIB_TOPS`, so that every statement of it is
elaborated). Over 500 variants are derived; `tests/test_robustness.py` runs them through every
netlist-reading command.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from click.testing import CliRunner
from netlist_cases import LIB, LIB_TOPS, VARIANTS, materialise

from springc_cli.main import main

LOCATED = re.compile(r"^(?P<file>[^\s:]+\.spr):(?P<line>\d+):(?P<col>\d+): error: ", re.M)


def test_enough_variants():
    assert len(VARIANTS) >= 500, len(VARIANTS)
    assert sum(v[1].parent == LIB for v in VARIANTS) >= 100


@pytest.mark.parametrize("stem", sorted(LIB_TOPS))
def test_library_tops_build(tmp_path, stem):
    """The unmutated library files build from their top files (so a variant's error is its own)."""
    original = LIB / f"{stem}.spr"
    top = materialise(tmp_path / "lib", "orig", original, original.read_text())
    result = CliRunner().invoke(main, ["build", str(top)])
    assert result.exit_code == 0, result.output


def located_error(output: str, mutated: Path) -> re.Match:
    """The first `file:line:col: error:` of `output`, asserted to name a real line of the file
    it points at (the mutated file, or one it includes)."""
    hit = LOCATED.search(output)
    assert hit, output
    where = Path(hit["file"])
    assert where.is_file(), output
    assert 1 <= int(hit["line"]) <= len(where.read_text().splitlines()), output
    assert where.resolve().parent == mutated.resolve().parent, output
    return hit


@pytest.fixture(scope="module")
def variant_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("variants")


@pytest.mark.parametrize("name,original,text", VARIANTS, ids=[v[0] for v in VARIANTS])
def test_broken_variant_is_a_located_user_error(variant_dir, name, original, text):
    # a library variant changes a shared file: a folder each; the rest share their source's
    # copy (a copy per variant was a third of this module's time)
    folder = variant_dir / (name if original.parent == LIB else original.parent.name)
    path = materialise(folder, name, original, text)
    result = CliRunner().invoke(main, ["build", str(path)])
    output = result.output + (result.stderr if result.stderr_bytes is not None else "")
    assert result.exit_code == 1, output
    assert "Traceback" not in output and "INTERNAL ERROR" not in output, output
    located_error(output, path)
