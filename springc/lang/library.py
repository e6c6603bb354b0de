"""What a file of subcircuit definitions offers: `subckts(tree, text) -> [SubcktSummary]`.

A library file (no top-level element) is summarised by its own subcircuits: ports, parameters
with their defaults as written, and the degrees of freedom and elements of one instance with
the defaults, found by elaborating that instance alone. Physics is not checked here: a block's
ports usually get their masses from the network that uses it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from springc.errors import SourceLoc
from springc.lang import ast
from springc.lang.elaborate import elaborate
from springc.lang.files import Includes
from springc.lang.parser import parse


@dataclass(frozen=True)
class SubcktSummary:
    """One subcircuit of a library file, with what an instance of it holds."""

    name: str
    ports: list[str]
    params: dict[str, str]  # name -> default as written
    dofs: int  # per instance with the defaults, ports included
    elements: dict[str, int]  # per instance, by element letter
    loc: SourceLoc

    def to_json(self) -> dict:
        """A JSON object with the fields above (`loc` as `file:line:col`)."""
        return {"name": self.name, "ports": list(self.ports), "params": dict(self.params),
                "dofs": self.dofs, "elements": dict(self.elements), "loc": str(self.loc)}

    def describe(self) -> str:
        """Two lines for people: the header as it would be written, then one instance."""
        params = " ".join(f"{k}={v}" for k, v in self.params.items())
        counts = ", ".join(f"{k}={v}" for k, v in self.elements.items()) or "none"
        return (f"  {self.name} {' '.join(self.ports)}  {params}".rstrip() +
                f"\n    one instance: dofs {self.dofs}, elements {counts}")


def subckts(tree: ast.Netlist, text: str,
            lib_dirs: list[Path] | None = None) -> list[SubcktSummary]:
    """Every top-level subcircuit the parsed file `tree` (whose source is `text`) defines or
    includes."""
    found = [s for s in Includes(lib_dirs).expand(tree) if isinstance(s, ast.Subckt)]
    return [_summary(sub, text, tree.file, lib_dirs) for sub in found]


def _summary(sub: ast.Subckt, text: str, file: str,
             lib_dirs: list[Path] | None) -> SubcktSummary:
    ports = [p.text for p in sub.ports]
    # the file itself plus one instance line below it, so that errors keep their positions
    probe = f"{text}\nXsummary {' '.join(ports)} {sub.name}\n"
    net = elaborate(parse(probe, file), lib_dirs)
    params = {p.key: _written(p.value) for p in sub.params}
    return SubcktSummary(sub.name, ports, params, net.n, net.element_counts(), sub.loc)


def _written(value: ast.Value) -> str:
    """A parameter default as it is written in the source."""
    if isinstance(value, (ast.Num, ast.Word, ast.Str)):
        return value.text
    lines = Path(value.loc.file).read_text(encoding="utf-8").splitlines()
    line, start = lines[value.loc.line - 1], value.loc.col - 1
    depth = 0
    for end in range(start, len(line)):
        depth += {"{": 1, "}": -1}.get(line[end], 0)
        if depth == 0:
            return line[start:end + 1]
    return line[start:]
