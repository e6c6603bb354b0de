"""The adjoint kernels compiled for a fixed number of lanes.

`springc.grad.adjoint` reads its lane count from its arrays; with a constant count LLVM
unrolls the lane loops and its SLP vectoriser turns each into vector arithmetic. `module(L)`
writes a copy of the adjoint module with `LANES = L` to the kernel cache folder
(`springc.kernels.loader.cache_dir`, a real file so numba caches its machine code beside it)
and imports it; `call(fn, ...)` runs one of its functions with the SLP vectoriser on while
the first call compiles (as the generated kernels do).
"""

from __future__ import annotations

import hashlib
import importlib.util
import inspect
import os
import sys
import tempfile
import threading
from pathlib import Path
from types import ModuleType

from springc.grad import adjoint
from springc.kernels.loader import cache_dir, compile_lock, slp_vectorize

CHOICES = (8, 4, 2, 1)  # lane counts compiled (each is a compile of its own)
_LOADED: dict[int, ModuleType] = {}
_LOCK = threading.Lock()


def choose(runs_per_thread: int) -> int:
    """The widest lane count of `CHOICES` that a thread's share of the runs fills."""
    return next(w for w in CHOICES if runs_per_thread >= w)


def module(lanes: int) -> ModuleType:
    """The adjoint module compiled for `lanes` lanes (loaded once per process)."""
    with _LOCK:
        if lanes not in _LOADED:
            _LOADED[lanes] = _load(lanes)
        return _LOADED[lanes]


def _load(lanes: int) -> ModuleType:
    source = inspect.getsource(adjoint)
    marker = "\nLANES = 0\n"
    if marker not in source:
        raise RuntimeError("springc.grad.adjoint has lost its `LANES = 0` line")
    text = source.replace(marker, f"\nLANES = {lanes}\n", 1)
    digest = hashlib.sha256(text.encode()).hexdigest()[:20]
    name = f"springc_grad_adjoint_{digest}"
    path = cache_dir() / f"{name}.py"
    if not path.exists():  # whole or absent: written beside, then renamed into place
        fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
        with os.fdopen(fd, "w") as fh:
            fh.write(text)
        os.replace(tmp, path)
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    mod.COMPILED = set()
    return mod


def call(mod: ModuleType, name: str, *args) -> None:
    """mod.name(*args); its first call per process compiles (or loads from numba's cache)
    under the file's lock with the SLP vectoriser on."""
    fn = getattr(mod, name)
    if name not in mod.COMPILED:
        with compile_lock(Path(mod.__file__)), slp_vectorize():
            fn(*args)
        mod.COMPILED.add(name)
        return
    fn(*args)
