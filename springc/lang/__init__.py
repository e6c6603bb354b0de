"""The .spr language front end: text -> AST (`parse`) -> flat IR (`elaborate`).

`load_file` and `load_text` do both. See shared/design/spr-language.md for the language.
"""

from __future__ import annotations

from pathlib import Path

from springc.errors import NetlistError
from springc.ir import FlatNetlist
from springc.lang.elaborate import elaborate
from springc.lang.files import STDLIB_DIR, search_dirs
from springc.lang.parser import parse

__all__ = ["STDLIB_DIR", "elaborate", "load_file", "load_text", "parse", "search_dirs"]


def load_text(text: str, filename: str = "<text>",
              lib_dirs: list[Path] | None = None) -> FlatNetlist:
    """Parse and elaborate netlist source `text`; relative paths are taken from the folder
    of `filename` (the working directory for `<text>`)."""
    return elaborate(parse(text, filename), lib_dirs)


def load_file(path: str | Path, lib_dirs: list[Path] | None = None) -> FlatNetlist:
    """Parse and elaborate the netlist file `path`."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise NetlistError(f"{path}: no such netlist file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise NetlistError(f"{path}: cannot read the netlist ({exc})") from None
    return load_text(text, str(path), lib_dirs)
