"""Mutation test of the whole front end (issue 2): broken variants of valid netlists.

Each operator below turns one statement of a valid example netlist into one that is certainly
invalid (deleted required token, bad suffix, wrong sign, truncated line, undefined name, ...).
For every variant `springc build` must exit 1 with a `file:line:col: error:` message whose line
is a real line of the file, and must not print a traceback. Over 200 variants are derived.
"""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest
from click.testing import CliRunner

from springc_cli.main import main

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "netlists" / "examples"
OK_CASES = ROOT / "tests" / "cases" / "ok"
SOURCES = sorted(EXAMPLES.glob("*.spr")) + sorted(OK_CASES.glob("*.spr"))
LOCATED = re.compile(r"^(?P<file>[^\s:]+\.spr):(?P<line>\d+):(?P<col>\d+): error: ", re.M)
KEY_NUMBER = re.compile(r"\b(m|k|l|g|b)=(\d+(\.\d+)?)\b")


def _statements(lines: list[str]) -> list[int]:
    """Indices of element lines (not comments, directives or continuations), leaving out the
    bodies of loops that run zero times (never elaborated, so a wrong value there is legal)."""
    out, stack = [], []
    for i, s in enumerate(lines):
        words = s.split()
        if words[:1] and words[0].lower() == ".end":
            break  # nothing after .end is read
        if words[:1] == [".for"]:
            first, last = words[2:4]
            stack.append(first.isdigit() and last.isdigit() and int(last) < int(first))
        elif words[:1] == [".endfor"]:
            stack.pop()
        elif s[:1].isalpha() and not any(stack):
            out.append(i)
    return out


def _neg_value(line: str) -> str | None:
    """Wrong sign: a mass, stiffness or damping literal made negative (physics check)."""
    m = re.search(r"\b(m|k|l|b)=(\d[\w.]*)", line)
    if not m or line[0].upper() not in "MKDB":
        return None
    return line[: m.start(2)] + "-" + line[m.start(2):]


def _bad_suffix(line: str) -> str | None:
    """A digit after a scale suffix (`1k5`) is an error, never 1000."""
    m = KEY_NUMBER.search(line)
    return None if not m else line[: m.end(2)] + "k5" + line[m.end(2):]


def _truncate_value(line: str) -> str | None:
    """Truncated line: cut right after the first `key=`."""
    m = re.search(r"\b\w+=", line)
    return None if not m else line[: m.end()]


def _delete_key(line: str) -> str | None:
    """Deleted required parameter (`m=` of a mass, `k=` of a spring, ...)."""
    required = {"M": "m", "K": "k", "D": "l", "C": "k", "Q": "g", "B": "b"}.get(line[0].upper())
    if required is None:
        return None
    m = re.search(rf"\b{required}=(\{{[^}}]*\}}|\S+)", line)
    return None if not m else (line[: m.start()] + line[m.end():]).rstrip()


def _unknown_letter(line: str) -> str | None:
    """An unknown element letter."""
    return "Z" + line[1:]


def _undefined_name(line: str) -> str | None:
    """A value that names an undefined parameter."""
    m = re.search(r"\b(m|k|l|g|b|gain)=(\S+)", line)
    return None if not m else line[: m.start(2)] + "{nosuchparam * 2}" + line[m.end(2):]


def _divide_by_zero(line: str) -> str | None:
    """Division by zero in an expression."""
    m = re.search(r"\b(m|k|l|g|b|gain)=(\S+)", line)
    return None if not m else line[: m.start(2)] + "{1/0}" + line[m.end(2):]


def _massless_node(line: str) -> str | None:
    """A spring or coupling that names a node without mass."""
    parts = line.split()
    if line[0].upper() not in "KDCQ" or len(parts) < 3:
        return None
    parts[1] = "massless_node_zz"
    return " ".join(parts)


def _unclosed(line: str) -> str | None:
    """A missing closing parenthesis or brace."""
    for closer in (")", "}"):
        idx = line.rfind(closer)
        if idx >= 0:
            return line[:idx] + line[idx + 1:]
    return None


def _directive(line: str) -> str | None:
    """A misspelt directive on an element line's place."""
    return ".frobnicate " + line


OPERATORS = [_directive, _neg_value, _bad_suffix, _truncate_value, _delete_key, _unknown_letter,
             _undefined_name, _divide_by_zero, _massless_node, _unclosed]


def _variants() -> list[tuple[str, Path, str]]:
    out = []
    for path in SOURCES:
        lines = path.read_text().splitlines()
        for idx in _statements(lines):
            for op in OPERATORS:
                new = op(lines[idx])
                if new is not None and new != lines[idx]:
                    text = "\n".join(lines[:idx] + [new] + lines[idx + 1:]) + "\n"
                    name = f"{path.parent.name}-{path.stem}-L{idx + 1}-{op.__name__[1:]}"
                    out.append((name, path, text))
    return out


VARIANTS = _variants()


def test_enough_variants():
    assert len(VARIANTS) >= 200, len(VARIANTS)


@pytest.mark.parametrize("name,original,text", VARIANTS, ids=[v[0] for v in VARIANTS])
def test_broken_variant_is_a_located_user_error(tmp_path, name, original, text):
    # A copy of the original's folder, so relative .include and .data paths still resolve.
    folder = tmp_path / "src"
    shutil.copytree(original.parent, folder)
    path = folder / f"{name}.spr"
    path.write_text(text)
    result = CliRunner().invoke(main, ["build", str(path)])
    output = result.output + (result.stderr if result.stderr_bytes is not None else "")
    assert result.exit_code == 1, output
    assert "Traceback" not in output and "INTERNAL ERROR" not in output, output
    hit = LOCATED.search(output)
    assert hit, output
    assert 1 <= int(hit["line"]) <= len(text.splitlines())
