"""Checked netlists kept on disk, so that a netlist run again starts at its simulation.

`springc build` and `springc.load` (every command that simulates) parse, elaborate and
check a netlist: a tenth of a second for a small one, seconds for a large one, and the
imports of the parser and of scipy besides. An unchanged netlist gets the same
`CheckedNetlist` again, so the result is kept in the cache folder (`$SPRINGC_CACHE` or
`~/.cache/springc/kernels`, beside the kernels) under a key made of the netlist's text,
file name, the options of the check and springc's source files. The entry also records every
other file the front end read (`.include`, `.data`) with its digest, and every place an
include search looked without finding a file: it serves only while each still reads the
same, so an edited library block or a new file that would shadow one is seen.

Netlists with `.step` or `.mc` are not kept (their points are elaborated and checked when
simulated), nor are loads with `params=` overrides. A damaged or unreadable entry is a miss.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import pickle
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

from springc.check.checks import CheckedNetlist
from springc.errors import register_source
from springc.lang.files import Read, digest
from springc.version import __version__

VERSION = 1  # bump when what an entry holds changes meaning
T = TypeVar("T")


def folder() -> Path:
    """Where the entries live (made by the first entry written: a netlist refused by the
    checks leaves nothing behind)."""
    base = Path(os.environ.get("SPRINGC_CACHE") or Path.home() / ".cache/springc/kernels")
    return base / "checked"


@functools.cache
def code() -> str:
    """A fingerprint of springc's own source files (names, sizes, modification times): an
    entry pickles springc's objects, so another version of the code never reads it."""
    package = Path(__file__).resolve().parents[1]
    stats = [(str(p.relative_to(package)), p.stat().st_size, p.stat().st_mtime_ns)
             for p in sorted(package.rglob("*.py"))]
    return hashlib.sha256(repr(stats).encode()).hexdigest()[:16]


def key(text: str, filename: str, **settings) -> str:
    """The entry's key: the netlist's text and name (resolved: relative includes are found
    beside it), the working directory for netlist text, SPRINGC_PATH, the check's
    settings (method, tstep, substeps, judge_step, lib_dirs) and springc's version."""
    path = Path(filename)
    where = str(path.resolve()) if path.is_file() else f"{filename} in {Path.cwd()}"
    items = [VERSION, __version__, code(), where, text, os.environ.get("SPRINGC_PATH", ""),
             {k: str(v) for k, v in sorted(settings.items())}]
    return hashlib.sha256(json.dumps(items).encode()).hexdigest()[:32]


def lookup(entry: str) -> CheckedNetlist | None:
    """The checked netlist stored under `entry`, if every file it read is unchanged."""
    try:
        with open(folder() / f"{entry}.pkl", "rb") as fh:
            deps, checked = pickle.load(fh)
    except (OSError, pickle.PickleError, EOFError, AttributeError, ValueError, TypeError):
        return None
    now = [read.current() for read in deps]
    if any(read.digest != digest(data) for read, data in zip(deps, now)):
        return None
    for read, data in zip(deps, now):  # diagnostics quote the lines of included files too
        if read.shown and data is not None:
            register_source(read.shown, data.decode("utf-8", "replace"))
    checked.entry = entry
    return checked


def checked_file(path: Path) -> CheckedNetlist:
    """The netlist file at `path` checked with the default options, from the store where it
    was checked before and is unchanged (the entry `springc.load` keeps for it), else parsed,
    elaborated, checked and kept. A file with `.step` or `.mc` is checked at its nominal
    design and not kept."""
    from springc.check.checks import check
    from springc.lang import files, read_source, variation
    from springc.lang.parser import parse

    text = read_source(path)
    entry = key(text, str(path), method=None, lib_dirs=None, tstep=None, substeps=None,
                judge_step=None)
    found = lookup(entry)
    if found is not None:
        return found
    with files.recording() as reads:
        var = variation.read(parse(text, str(path)), None)
        checked = check(var.nominal())
    if not var.varies:
        save(entry, checked, reads)
    return checked


def save(entry: str, checked: CheckedNetlist, deps: list[Read]) -> None:
    """Store `checked` under `entry` with the files it read (atomically: a reader sees the
    whole entry or none)."""
    _write(folder() / f"{entry}.pkl", (deps, checked))
    checked.entry = entry


def remembered(checked: CheckedNetlist, name: str, compute: Callable[[], T]) -> T:
    """`compute()`, a result that depends on the checked netlist alone (and on `name`,
    which says what it is and with which arguments), kept beside the netlist's entry: computed
    once per entry. Without an entry (a netlist checked in memory) it is just computed."""
    entry = getattr(checked, "entry", None)
    if entry is None:
        return compute()
    suffix = hashlib.sha256(name.encode()).hexdigest()[:16]
    return _kept(folder() / f"{entry}.{suffix}.pkl", compute)


def memo(name: str, parts: list[str | bytes], compute: Callable[[], T]) -> T:
    """`compute()`, kept in the cache folder under `name` and a digest of `parts` (all that
    the result depends on besides springc's source, which is in the key too): for results
    on networks built in memory, which have no netlist entry (the keyword-spotting
    trainings' integration choices, tens of seconds each). Computed once per key."""
    digest = hashlib.sha256()
    for part in [str(VERSION), __version__, code(), name, *parts]:
        data = part if isinstance(part, bytes) else part.encode()
        digest.update(len(data).to_bytes(8, "little") + data)
    return _kept(folder() / "memo" / f"{digest.hexdigest()[:32]}.pkl", compute)


def _kept(path: Path, compute: Callable[[], T]) -> T:
    """The value pickled at `path`, or `compute()` written there (a damaged or unreadable
    entry is computed again)."""
    try:
        with open(path, "rb") as fh:
            return pickle.load(fh)
    except (OSError, pickle.PickleError, EOFError, AttributeError, ValueError, TypeError):
        pass
    value = compute()
    _write(path, value)
    return value


def _write(path: Path, value) -> None:
    """Pickle `value` to `path` atomically (nothing on a full or read-only disk)."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
    except OSError:
        return
    try:
        with os.fdopen(fd, "wb") as fh:
            pickle.dump(value, fh, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(tmp, path)
    except OSError:
        Path(tmp).unlink(missing_ok=True)


