"""The .spr language front end: text -> AST (`parse`) -> flat IR (`elaborate`).

`load_file` and `load_text` do both. The language is documented in docs/language.md, which
also describes these choices of this front end (each is tested):
- `.include` looks in the including file's folder, then `lib_dirs`, `STDLIB_DIR` and the
  SPRINGC_PATH folders; a file already included in the same scope is skipped (libraries may
  include what they use), a cycle is an error naming the chain.
- `.param` and `.data` lines run before the other statements of their scope (top level,
  subcircuit body, loop body), in their own order, as in SPICE: an element may use a
  parameter defined below it.
- Parameter keys of elements are case-insensitive (`M1 a M=1`), subcircuit parameters are not.
- `{expr}` interpolation works in any name, not only inside `.for`; element lines may name
  nodes inside instances (`C1 X1.a b`), a port resolving to the node bound to it.
- A subcircuit defined inside another is visible only there; `.tran`, `.ac`, `.options` are
  top-level only; a second `.tran`, `.title` or option key is an error; `.title` lines of
  included files are ignored.
- `B 0 a` is stored as `B a 0`; ground elsewhere is an error. A node named only by `F`,
  `.probe` or `.ac` becomes a node (the checks report that it has no mass).
- `sin(amp freq)` gets phase 0 in the IR; `wav("file" [channel])` takes an optional channel.
"""

from __future__ import annotations

import importlib
from pathlib import Path

from springc.errors import NetlistError
from springc.lang.files import STDLIB_DIR, search_dirs
from springc.lang.ir import FlatNetlist

__all__ = ["STDLIB_DIR", "load_file", "load_text", "parse", "read_source", "read_variation",
           "search_dirs"]
# name -> (module, attribute), imported on first use: the parser (lark) and the elaborator
# cost a tenth of a second, which a netlist loaded from the check cache does not pay
_LAZY = {"parse": ("parser", "parse"), "read_variation": ("variation", "read")}


def __getattr__(name: str):
    if name in _LAZY:
        module, attr = _LAZY[name]
        return getattr(importlib.import_module(f"springc.lang.{module}"), attr)
    raise AttributeError(f"module 'springc.lang' has no attribute {name!r}")


def load_text(text: str, filename: str = "<text>",
              lib_dirs: list[Path] | None = None) -> FlatNetlist:
    """Parse and elaborate netlist source `text`; relative paths are taken from the folder
    of `filename` (the working directory for `<text>`). With `.step` or `.mc` this is the
    nominal netlist (`.param` values as written, random functions nominal), their lines
    checked; `read_variation` gives the points."""
    from springc.lang.parser import parse
    from springc.lang.variation import read

    return read(parse(text, filename), lib_dirs).nominal()


def read_source(path: str | Path) -> str:
    """The text of the netlist file `path`; a `NetlistError` naming the file and reason."""
    path = Path(path)
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise NetlistError(f"{path}: no such netlist file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise NetlistError(f"{path}: cannot read the netlist ({exc})") from None


def load_file(path: str | Path, lib_dirs: list[Path] | None = None) -> FlatNetlist:
    """Parse and elaborate the netlist file `path`."""
    return load_text(read_source(path), str(path), lib_dirs)
