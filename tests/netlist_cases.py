"""The broken netlists shared by the front-end tests: the golden error cases `ERR`
(`tests/cases/err/*.spr`) of test_cases, and the mutation variants `VARIANTS` of valid
netlists (the operators that derive them, `materialise` to write one out and the library top
files `LIB_TOPS`) of test_mutations; test_robustness runs both through every netlist-reading
command."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "netlists" / "examples"
OK_CASES = ROOT / "tests" / "cases" / "ok"
# the golden front-end error cases: test_cases checks their messages, test_robustness
# runs them through every netlist-reading command
ERR = sorted((ROOT / "tests" / "cases" / "err").glob("*.spr"))
LIB = ROOT / "netlists" / "lib"
SOURCES = [*sorted(EXAMPLES.glob("*.spr")), *sorted(OK_CASES.glob("*.spr")),
           *sorted(LIB.glob("*.spr"))]
# A top file per library file that instantiates each of its subcircuits so that every statement
# runs (the delay line twice: its .for bodies run for n = 2 or for n = 10, never both).
_TAIL = ".tran 0.1ms 10ms\n.probe x(a)\n"
LIB_TOPS = {
    "compressor": "M1 a m=1 b=1\nK1 a k=1\nX1 a b compressor\n",
    "delayline": "X1 a b delayline n=10 term=1 term_in=1\nX2 c d delayline n=2 term=1 term_in=1\n",
    "featurechain": "X1 a featurechain\n",
    "lowpass": "X1 a lowpass\n",
    "melfilter": "X1 a melfilter\nX2 b melfilter1\nX3 c d routedfilter\n",
    "readout": "X1 a readout\n",
    "squarer": "M1 a m=1 b=1\nK1 a k=1\nX1 a b squarer\nM2 b m=1 b=1\nK2 b k=1\n",
    "summer": "M1 a m=1 b=1\nK1 a k=1\nM2 c m=1 b=1\nK2 c k=1\nX1 a c b summer2 w1=-2\n",
}
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


def _extra_param(line: str) -> str | None:
    """A parameter the element (or subcircuit) does not have (before a `;` comment)."""
    code, sep, comment = line.partition(";")
    return code.rstrip() + " zzparam=1" + (" " + sep + comment if sep else "")


def _duplicate(line: str) -> str | None:
    """The statement written twice: a duplicate element name."""
    return line + "\n" + line


def _overflow(line: str) -> str | None:
    """A value beyond the range of a double, as a literal or computed."""
    m = re.search(r"\b(m|k|l|g|b|gain)=(\S+)", line)
    if not m:
        return None
    value = "1e400" if len(line) % 2 else "{1e300*1e300}"  # both kinds over the variants
    return line[: m.start(2)] + value + line[m.end(2):]


def _unterminated_quote(line: str) -> str | None:
    """A stray quote where a value starts."""
    m = re.search(r"\b\w+=", line)
    return None if not m else line[: m.end()] + '"' + line[m.end():]


def _control_char(line: str) -> str | None:
    """A control character (as from a corrupted file) after the element name."""
    parts = line.split(" ", 1)
    return None if len(parts) < 2 else parts[0] + " \x01" + parts[1]


def _dangling_operator(line: str) -> str | None:
    """An expression that ends in an operator."""
    m = re.search(r"\b(m|k|l|g|b|gain)=(\S+)", line)
    return None if not m else line[: m.start(2)] + "{2 *}" + line[m.end(2):]


OPERATORS = [_directive, _neg_value, _bad_suffix, _truncate_value, _delete_key, _unknown_letter,
             _undefined_name, _divide_by_zero, _massless_node, _unclosed, _extra_param,
             _duplicate, _overflow, _unterminated_quote, _control_char, _dangling_operator]


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


def materialise(folder: Path, name: str, original: Path, text: str) -> Path:
    """Write a variant into `folder` (a copy of the original's folder, so that relative
    .include and .data paths still resolve, made here if missing) and return the netlist to
    run: the variant itself, or for a library file the top file that instantiates it."""
    if not folder.exists():
        shutil.copytree(original.parent, folder)
    if original.parent != LIB:
        path = folder / f"{name}.spr"
        path.write_text(text)
        return path
    (folder / original.name).write_text(text)
    top = folder / f"top_{original.stem}.spr"
    top.write_text(f'.include "{original.name}"\n{LIB_TOPS[original.stem]}{_TAIL}')
    return top
