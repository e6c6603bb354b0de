"""docs/language.md, the language reference, against the compiler: every ```spr example builds
(`springc.check.compiler.build`, what `springc build` runs), every ```spr-error example is
refused by `springc build` with a located error and exit status 1, and the page names every
element letter, directive, source, option, integrator, function and suffix the code defines.

Fenced blocks with `file=NAME` in their info string (```csv file=weights.csv) are files the
examples read: they are written beside every example first.
"""

from __future__ import annotations

import json
import math
import re
import struct
import wave
from pathlib import Path

import pytest
from click.testing import CliRunner
from springc_cli.main import main

from springc.check import compiler
from springc.lang import draws, elements, expr
from springc.lang.elaborate import DIRECTIVES
from springc.lang.options import KNOWN_OPTIONS, known_methods

PAGE = Path(__file__).resolve().parents[1] / "docs" / "language.md"
TEXT = PAGE.read_text(encoding="utf-8")
_FENCE = re.compile(r"^```([^\n`]*)\n(.*?)^```$", re.MULTILINE | re.DOTALL)


def _blocks() -> list[tuple[str, str | None, str, int]]:
    """(language, file name or None, body, line of the opening fence) of every fenced block."""
    out = []
    for match in _FENCE.finditer(TEXT):
        words = match.group(1).split()
        lang = words[0] if words else ""
        files = [w[len("file="):] for w in words[1:] if w.startswith("file=")]
        line = TEXT.count("\n", 0, match.start()) + 1
        out.append((lang, files[0] if files else None, match.group(2), line))
    return out


BLOCKS = _blocks()
FILES = {name: body for _, name, body, _ in BLOCKS if name is not None}


def _examples(lang: str) -> list:
    return [pytest.param(body, id=f"language.md:{line}")
            for kind, name, body, line in BLOCKS if kind == lang and name is None]


def _write_tone(path: Path, seconds: float = 0.1, rate: int = 8000) -> None:
    """A mono 16-bit sound file of a 440 Hz tone (for the `wav` source example)."""
    samples = [int(8000 * math.sin(2 * math.pi * 440 * k / rate))
               for k in range(int(seconds * rate))]
    with wave.open(str(path), "wb") as out:
        out.setnchannels(1)
        out.setsampwidth(2)
        out.setframerate(rate)
        out.writeframes(struct.pack(f"<{len(samples)}h", *samples))


def _example(tmp_path: Path, body: str) -> Path:
    """`body` as a netlist file in `tmp_path`, with the files the page's examples read."""
    for name, content in FILES.items():
        (tmp_path / name).write_text(content, encoding="utf-8")
    _write_tone(tmp_path / "tone.wav")
    path = tmp_path / "example.spr"
    path.write_text(body, encoding="utf-8")
    return path


def test_every_example_is_found() -> None:
    # counted by their opening fences, so that a fence the reader misses is not skipped
    for lang in ("spr", "spr-error"):
        fences = len(re.findall(rf"^```{lang}$", TEXT, re.MULTILINE))
        assert len(_examples(lang)) == fences > 5


@pytest.mark.parametrize("body", _examples("spr"))
def test_example_builds(tmp_path, body: str) -> None:
    report = compiler.build(_example(tmp_path, body))
    assert isinstance(report, (compiler.BuildReport, compiler.LibraryReport))
    if isinstance(report, compiler.BuildReport):
        assert report.dofs >= 1


@pytest.mark.parametrize("body", _examples("spr-error"))
def test_error_example_is_refused(tmp_path, body: str) -> None:
    # each error example opens with the comment `* error: <the message, or its start>`
    expected = re.match(r"\* error: (.+)\n", body)
    assert expected is not None, "an error example starts with '* error: <message>'"
    path = _example(tmp_path, body)
    res = CliRunner().invoke(main, ["build", str(path)], catch_exceptions=False)
    assert res.exit_code == 1, res.output
    located = re.search(rf"^{re.escape(str(path))}:(\d+):(\d+): error: (.*)$", res.output,
                        re.MULTILINE)
    assert located is not None, res.output
    assert 2 <= int(located.group(1)) <= body.count("\n")
    assert expected.group(1) in located.group(3), res.output
    assert "Traceback" not in res.output


def test_cli_builds_the_first_example(tmp_path) -> None:
    body = _examples("spr")[0].values[0]
    res = CliRunner().invoke(main, ["build", str(_example(tmp_path, body)), "--json"],
                             catch_exceptions=False)
    assert res.exit_code == 0, res.output
    assert json.loads(res.output)["elements"] == {"M": 2, "K": 2, "C": 1, "F": 2}


def _missing(words) -> list[str]:
    """The words that no inline code span of the page contains as a whole word."""
    def found(word: str) -> bool:
        end = r"(?!\w)" if re.match(r"\w", word[-1]) else ""
        return re.search(rf"`[^`\n]*(?<![\w.]){re.escape(word)}{end}[^`\n]*`", TEXT) is not None
    return [w for w in words if not found(w)]


def test_page_names_every_element_and_directive() -> None:
    assert _missing(elements.LETTERS) == []
    for letter in elements.LETTERS:
        assert f"### `{letter}`" in TEXT, letter
    assert _missing(f".{d}" for d in DIRECTIVES) == []


def test_page_names_every_source_option_method_function_and_suffix() -> None:
    assert _missing(f"{s}(" for s in elements.SOURCES) == []
    assert _missing(f"{k}" for k in KNOWN_OPTIONS) == []
    assert _missing(known_methods()) == []
    assert _missing(expr.FUNCTIONS) == [] and _missing(expr.CONSTANTS) == []
    assert _missing(f"{f}(" for f in draws.FUNCTIONS) == []
    assert [s for s in expr.SUFFIXES if f"| `{s}` |" not in TEXT] == []  # the suffix table
    for spec in elements.SPECS.values():
        assert _missing(f"{key}=" for key in (*spec.required, *spec.optional)) == []
