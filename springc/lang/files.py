"""The files a netlist names: `.include` (search path, cycles, each file once per scope) and
`.data` arrays (.npy, .csv). Every failure is a `NetlistError` at the directive naming the
file and the reason.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import threading
from collections import OrderedDict
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from springc.errors import NetlistError, SourceLoc
from springc.lang import ast

STDLIB_DIR = Path(__file__).resolve().parents[2] / "netlists" / "lib"


@dataclass(frozen=True)
class Read:
    """A file the front end read (`digest`: the sha256 of its bytes), or an include
    candidate it looked for and did not find (`digest` None); `shown`: the name an included
    netlist's diagnostics use ('' for data files)."""

    path: str
    digest: str | None
    shown: str = ""

    def current(self) -> bytes | None:
        """The file's bytes now (None where it is not a readable file)."""
        try:
            return Path(self.path).read_bytes()
        except OSError:
            return None


def digest(data: bytes | None) -> str | None:
    """The sha256 of `data` (None for None)."""
    return None if data is None else hashlib.sha256(data).hexdigest()


_READS = threading.local()


@contextlib.contextmanager
def recording() -> Iterator[list[Read]]:
    """Inside, on this thread: every file the front end reads, and every include candidate it
    finds missing, appended to the list yielded (what a checked netlist depends on besides
    its own text: `springc.check.store`)."""
    before = getattr(_READS, "log", None)
    _READS.log = log = []
    try:
        yield log
    finally:
        _READS.log = before


def _note(path: Path, data: bytes | None, shown: str = "") -> None:
    log = getattr(_READS, "log", None)
    if log is not None:
        log.append(Read(str(path.resolve()), digest(data), shown))


def search_dirs(lib_dirs: list[Path] | None = None) -> list[Path]:
    """Folders searched for `.include` after the including file's own folder: `lib_dirs`,
    the standard library, then the folders of the SPRINGC_PATH environment variable."""
    extra = [Path(p) for p in os.environ.get("SPRINGC_PATH", "").split(os.pathsep) if p]
    return [Path(p) for p in (lib_dirs or [])] + [STDLIB_DIR] + extra


def beside(name: ast.Str) -> Path:
    """The path a quoted file name stands for: relative to the file it is written in."""
    path = Path(name.text)
    return path if path.is_absolute() else Path(name.loc.file).parent / path


def display(path: Path) -> str:
    """`path` relative to the working directory when it lies below it (shorter messages)."""
    try:
        return str(path.relative_to(Path.cwd()))
    except ValueError:
        return str(path)


class Includes:
    """Splices included files into statement lists; parses each file once."""

    def __init__(self, lib_dirs: list[Path] | None) -> None:
        self.dirs = search_dirs(lib_dirs)
        self.parsed: dict[str, ast.Netlist] = {}

    def expand(self, tree: ast.Netlist) -> list:
        """The statements of `tree` with every `.include` replaced by the included ones."""
        main = Path(tree.file)
        key = str(main.resolve()) if main.is_file() else tree.file
        return self._expand(tree.statements, (key,), set())

    def _expand(self, stmts, chain: tuple[str, ...], seen: set[str]) -> list:
        # `seen` holds the files already included in this scope: a second include is skipped,
        # so libraries may include what they use without clashing with their users
        out: list = []
        for stmt in stmts:
            match stmt:
                case ast.Directive(name="include"):
                    out.extend(self._include(stmt, chain, seen))
                case ast.Subckt(body=body):
                    out.append(replace(stmt, body=tuple(self._expand(body, chain, set()))))
                case ast.For(body=body):
                    out.append(replace(stmt, body=tuple(self._expand(body, chain, seen))))
                case _:
                    out.append(stmt)
        return out

    def _include(self, stmt: ast.Directive, chain: tuple[str, ...], seen: set[str]) -> list:
        if len(stmt.args) != 1 or not isinstance(stmt.args[0], ast.Str):
            raise NetlistError(".include takes one quoted file name", stmt.loc,
                               'write .include "file.spr"')
        path = self._find(stmt.args[0], chain[-1])
        key = str(path)
        if key in chain:
            names = " -> ".join(Path(k).name for k in chain[chain.index(key):] + (key,))
            raise NetlistError(f"include cycle: {names}", stmt.loc,
                               "remove one of the .include lines")
        if key in seen:
            return []
        seen.add(key)
        tree = self._parse(path, stmt.args[0])
        return self._expand(tree.statements, chain + (key,), seen)

    def _find(self, name: ast.Str, including: str) -> Path:
        # a file never includes itself: `.include "readout.spr"` written in a user's own
        # readout.spr means the library block of that name, so the search goes on past it
        candidates = [Path(name.loc.file).parent] + self.dirs
        for folder in candidates:
            path = folder / name.text
            if path.is_file() and str(path.resolve()) != including:
                return path.resolve()
            if not path.is_file():
                _note(path, None)  # a file made here later would be found first
        looked = ", ".join(str(d) for d in candidates)
        raise NetlistError(f"cannot find include file '{name.text}'", name.loc,
                           f"looked in: {looked}")

    def _parse(self, path: Path, name: ast.Str) -> ast.Netlist:
        key = str(path)
        if key not in self.parsed:
            try:
                data = path.read_bytes()
                text = data.decode("utf-8")
            except (OSError, UnicodeDecodeError) as exc:
                raise NetlistError(f"cannot read include file '{path}': {exc}",
                                   name.loc) from None
            _note(path, data, display(path))
            self.parsed[key] = parse_included(text, display(path))
        return self.parsed[key]


_PARSED: OrderedDict[tuple[str, str], ast.Netlist] = OrderedDict()
_PARSED_LOCK = threading.Lock()
PARSED_KEPT = 256  # included files whose trees a process keeps (the least recently used go)


def parse_included(text: str, filename: str) -> ast.Netlist:
    """`parser.parse(text, filename)`, kept for the next include of the same text under the
    same name: a library block that every netlist of a sweep, a population or a tuning run
    includes is parsed once per process (the trees are immutable, so one serves all)."""
    from springc.lang.parser import parse  # the parser imports nothing from here

    key = (filename, text)
    with _PARSED_LOCK:  # threads that load netlists share the trees
        tree = _PARSED.get(key)
        if tree is not None:
            _PARSED.move_to_end(key)
            return tree
    tree = parse(text, filename)
    with _PARSED_LOCK:
        _PARSED[key] = tree
        while len(_PARSED) > PARSED_KEPT:
            _PARSED.popitem(last=False)
    return tree


def read_array(path: Path, loc: SourceLoc) -> np.ndarray:
    """A numeric array from a .npy or .csv file; errors name the file and the reason."""
    suffix = path.suffix.lower()
    if suffix not in (".npy", ".csv"):
        raise NetlistError(f"data file '{path}': unsupported type '{suffix}'", loc,
                           "use a .npy or .csv file")
    if not path.is_file():
        raise NetlistError(f"data file '{path}' not found", loc)
    if getattr(_READS, "log", None) is not None:
        with contextlib.suppress(OSError):  # unreadable: np.load names the reason below
            _note(path, path.read_bytes())
    try:
        if suffix == ".npy":
            array = np.load(path, allow_pickle=False)
        else:
            array = np.loadtxt(path, delimiter=",", ndmin=1, comments="#")
    except Exception as exc:  # noqa: BLE001 - numpy raises many types for bad files
        raise NetlistError(f"data file '{path}' cannot be read: {exc}", loc) from None
    if array.dtype.kind not in "biuf" or array.ndim == 0 or array.size == 0:
        raise NetlistError(f"data file '{path}' does not hold a non-empty numeric array "
                           f"(dtype {array.dtype}, shape {array.shape})", loc)
    array = np.ascontiguousarray(array, dtype=np.float64)
    bad = np.flatnonzero(~np.isfinite(array))
    if bad.size:
        where = np.unravel_index(bad[0], array.shape)
        raise NetlistError(f"data file '{path}' holds {bad.size} non-finite value(s), the first "
                           f"{array[where]} at index {list(map(int, where))}", loc,
                           "every value must be a finite number")
    return array
