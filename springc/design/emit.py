"""Writing `.spr` text that a person can read: comments, aligned statements, exact numbers.

Numbers are written with the shortest text that reads back to the same float64 (so a designed
stiffness matrix survives the round trip through the file bit for bit), exponents without `+`
or leading zeros. Long statements wrap with `+` continuation lines at 100 columns.
"""

from __future__ import annotations

import math
import os
import tempfile
import textwrap
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from springc.errors import DataError

WIDTH = 100


def num(value: float) -> str:
    """Shortest round-trip text of a finite number, in `.spr` syntax (`1e-6`, `2.5e12`, `0`)."""
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"cannot write the non-finite number {v} into a netlist")
    plain = repr(v).removesuffix(".0")
    mantissa, _, exp = np.format_float_scientific(v, unique=True, trim="-").partition("e")
    sci = f"{mantissa}e{int(exp)}"
    if "e" in plain:  # repr's own exponent form: write it in the same style
        plain = sci
    return plain if len(plain) <= len(sci) + 1 else sci  # 1000 reads better than 1e3


class SprWriter:
    """Accumulates the lines of a `.spr` file."""

    def __init__(self) -> None:
        self.lines: list[str] = []

    def comment(self, text: str = "") -> None:
        """`* text`, wrapped at the page width; blank lines in `text` are kept."""
        for para in text.split("\n"):
            wrapped = textwrap.wrap(para, WIDTH - 2) or [""]
            self.lines.extend(f"* {w}".rstrip() for w in wrapped)

    def blank(self) -> None:
        """An empty line between sections."""
        self.lines.append("")

    def statement(self, *words: str) -> None:
        """One statement; wrapped with `+` continuation lines when longer than the page."""
        line = ""
        for word in words:
            if line and len(line) + 1 + len(word) > WIDTH:
                self.lines.append(line)
                line = "+"
            line = f"{line} {word}" if line else word
        self.lines.append(line)

    def title(self, text: str) -> None:
        """`.title text`."""
        self.statement(".title", text)

    def include(self, path: str) -> None:
        """`.include "path"`."""
        self.statement(".include", f'"{path}"')

    def params(self, **values: float) -> None:
        """`.param name=value ...`."""
        self.statement(".param", *assignments(values))

    def subckt(self, name: str, ports: Iterable[str], params: dict[str, float] | None = None):
        """`.subckt name ports... params...`."""
        self.statement(".subckt", name, *ports, *assignments(params or {}))

    def ends(self, name: str) -> None:
        """`.ends name`."""
        self.statement(".ends", name)

    def text(self) -> str:
        """The file contents."""
        return "\n".join(self.lines) + "\n"


def assignments(values: dict[str, float | str]) -> list[str]:
    """`name=value` words; strings (expressions, `{...}`) pass through unchanged."""
    return [f"{k}={v if isinstance(v, str) else num(v)}" for k, v in values.items()]


def write_atomic(path: str | Path, text: str) -> Path:
    """Write `text` to `path` through a temporary file in the same folder and a rename, so that
    a failure never leaves a half-written file."""
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise DataError(str(path), f"folder {folder} does not exist")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=folder)
    try:
        with os.fdopen(fd, "w") as fh:
            fh.write(text)
        os.chmod(tmp, 0o644)  # mkstemp makes it private; a netlist is for reading
        os.replace(tmp, path)
    except BaseException:
        os.unlink(tmp)
        raise
    return path


def params_text(prefix: str, values: dict[str, float], title: str, example: str) -> str:
    """A `.param` file: a comment naming the design, `prefix_name=value` lines, and an example
    instance line (commented out) that uses them."""
    w = SprWriter()
    w.comment(title)
    w.comment("Written by `springc design`; `.include` this file and use the parameters, e.g.")
    w.comment(f"  {example}")
    w.blank()
    for key, value in values.items():
        w.params(**{f"{prefix}_{key}": value})
    return w.text()
