"""Loading generated kernels: the only module that imports numba (besides
`springc.kernels.streamstore`, `stackalign` and `vmath`, the intrinsics the generated
kernels call, and `chunk`, the chunk code they share).

The source from `springc.kernels.codegen` is written to `<cache>/springc_kernel_<hash>.py` (a
real file, so numba's `cache=True` stores the machine code beside it for the next process)
and imported by path. The cache is `$SPRINGC_CACHE` or `~/.cache/springc/kernels`; processes
share it safely: a kernel file appears once and whole, and each kernel compiles under its own
lock file. LLVM's SLP vectoriser, which the generated lane code is written for (numba leaves
it off), is switched on only while a kernel's own first call compiles it, Python's cyclic
garbage collector is paused while numba compiles (`compiling`), and the compiler runs on a
thread of its own (`on_own_thread`).
"""

from __future__ import annotations

import contextlib
import functools
import fcntl
import gc
import importlib.machinery
import importlib.util
import os
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import TypeVar

import numpy as np

from springc.kernels.codegen import kernel_hash, shared_text

_LOADED: dict[str, "Kernel"] = {}
T = TypeVar("T")


class _HeldSetting:
    """A process-wide setting held while any thread is inside (`with setting():`): `hold()`
    sets it on the first entry and returns what was there, `restore(before)` puts that back
    on the last exit."""

    def __init__(self, hold: Callable[[], object], restore: Callable[[object], None]) -> None:
        self._hold, self._restore = hold, restore
        self._lock = threading.Lock()
        self._users = 0
        self._before: object = None

    @contextlib.contextmanager
    def __call__(self) -> Iterator[None]:
        with self._lock:
            if self._users == 0:
                self._before = self._hold()
            self._users += 1
        try:
            yield
        finally:
            with self._lock:
                self._users -= 1
                if self._users == 0:
                    self._restore(self._before)


def _slp_on() -> int:
    from numba.core import config

    before, config.SLP_VECTORIZE = config.SLP_VECTORIZE, 1
    return before


def _slp_restore(before: int) -> None:
    from numba.core import config

    config.SLP_VECTORIZE = before


def _gc_off() -> bool:
    before = gc.isenabled()
    gc.disable()
    return before


def _gc_restore(before: bool) -> None:
    if before:
        gc.enable()


# numba's SLP vectoriser on while any kernel call (and so its compilation) is under way in
# any thread, then back to numba's own setting
slp_vectorize = _HeldSetting(_slp_on, _slp_restore)
# Python's cyclic garbage collector off while numba compiles, then as it was. The compiler
# allocates millions of short-lived objects, and each collection they trigger scans every
# long-lived object of the process: in a test process of 790,000 objects, 8% of a cold run
# (docs/performance.md). What a compile leaves is collected at the next collection after it.
gc_paused = _HeldSetting(_gc_off, _gc_restore)


_CALL_TYPES: dict | None = None  # the call types resolved in the compiles under way


def _remember_on() -> None:
    global _CALL_TYPES
    import inspect

    from numba.core.types import functions

    resolve = functions.BaseFunction.get_call_type
    if getattr(resolve, "springc_remembers", False):
        _CALL_TYPES = {}
    elif list(inspect.signature(resolve).parameters) == ["self", "context", "args", "kws"]:
        functions.BaseFunction.get_call_type = _remembering(resolve)
        _CALL_TYPES = {}  # (a numba whose resolver takes other arguments is left as it is)


def _remember_off(_: None) -> None:
    global _CALL_TYPES
    _CALL_TYPES = None


def _remembering(resolve: Callable) -> Callable:
    """numba's `BaseFunction.get_call_type` (the signature of one call of an operator or a
    builtin on given argument types, found by trying each of the function's templates),
    answered from `_CALL_TYPES` where the same call was resolved before in the compiles
    under way. numba resolves every call expression afresh: 2797 times for 196 distinct
    calls in a 439-line kernel, a sixth of its compile. The answer depends on the function,
    the typing context and the argument types alone, which are the key; failures are not
    kept (numba tries another form of the arguments after one)."""

    def get_call_type(self, context, args, kws):
        memo = _CALL_TYPES
        if memo is None:
            return resolve(self, context, args, kws)
        try:
            key = (self, context, tuple(args), tuple(sorted(kws.items())))
            return memo[key]
        except KeyError:
            memo[key] = found = resolve(self, context, args, kws)
            return found
        except TypeError:  # an argument type that does not hash
            return resolve(self, context, args, kws)

    get_call_type.springc_remembers = True
    return get_call_type


# each call type resolved once while any kernel compiles (`_remembering`), then forgotten
call_types_remembered = _HeldSetting(_remember_on, _remember_off)


@contextlib.contextmanager
def compiling(path: Path, blas: bool = True) -> Iterator[None]:
    """The scope of a kernel's first call, which compiles it (or loads it from numba's cache):
    scipy's BLAS module loaded alone (`blas_module_alone`; `blas` False: the caller's cache
    does that on a miss), the kernel file's lock (`compile_lock`), the SLP vectoriser on, the
    collector paused, each call's type resolved once (`call_types_remembered`)."""
    if blas:
        blas_module_alone()
    with gc_paused(), compile_lock(path), slp_vectorize(), call_types_remembered():
        yield


def load_first(dispatcher) -> bool:
    """Let `dispatcher` load a cached compile without first setting up numba's lowering
    registries (`_cache_load_alone`): a warm command's kernel then loads in tens of
    milliseconds instead of after 0.2-0.4 s of registries it does not read
    (docs/performance.md, "A warm kernel without numba's registries"). False, and nothing
    changed, where the dispatcher does not cache or numba's cache is not the one this knows."""
    from numba.core.caching import FunctionCache

    cache = getattr(dispatcher, "_cache", None)
    if type(cache) is not FunctionCache or not hasattr(cache, "_load_overload"):
        return False
    dispatcher._cache = _cache_load_alone()(dispatcher.py_func)
    return True


@functools.cache
def _cache_load_alone() -> type:
    """numba's function cache, loading an entry without `target_context.refresh()` first.
    The refresh imports and installs every lowering registry (numpy's array functions,
    random generators, cffi, ...), which only compiling reads: a loaded entry is machine
    code whose symbols numba resolves from its runtime (initialised here, as the refresh
    would) and its C helpers (registered when numba is imported). On a miss numba's compiler
    refreshes the context itself (`numba.core.compiler.CompilerBase`), so scipy's BLAS module
    is loaded alone first (`blas_module_alone`)."""
    from numba.core.caching import FunctionCache
    from numba.core.runtime import rtsys

    class CacheLoadAlone(FunctionCache):
        def load_overload(self, sig, target_context):
            rtsys.initialize(target_context)
            found = self._load_overload(sig, target_context)
            if found is None:
                blas_module_alone()
            return found

    return CacheLoadAlone


BLAS_MODULE = "scipy.linalg.cython_blas"


def blas_module_alone() -> None:
    """Load scipy's BLAS extension module by itself, before numba's first compile or cache
    load in the process. numba's CPU target imports `scipy.linalg.cython_blas` when it loads
    its registries, only to learn that a BLAS is there (`numba.np.linalg.ensure_blas`), and
    that import runs scipy.linalg's whole package (docs/performance.md, "A warm command's
    floor"). The extension module alone is what numba reads (a kernel calling BLAS takes its
    functions from its C API table); `from scipy.linalg import cython_blas` finds it later.
    Nothing to do where scipy.linalg is imported already or the module is not found: numba
    then imports it its own way."""
    if BLAS_MODULE in sys.modules or "scipy.linalg" in sys.modules:
        return
    try:
        import scipy
    except ImportError:
        return
    folder = Path(scipy.__file__).parent / "linalg"
    found = [folder / f"cython_blas{s}" for s in importlib.machinery.EXTENSION_SUFFIXES]
    path = next((p for p in found if p.exists()), None)
    if path is None:
        return
    spec = importlib.util.spec_from_file_location(BLAS_MODULE, path)
    try:
        module = importlib.util.module_from_spec(spec)
        sys.modules[BLAS_MODULE] = module
        spec.loader.exec_module(module)
    except Exception:  # a scipy this does not know: numba imports it its own way
        sys.modules.pop(BLAS_MODULE, None)


def on_own_thread(call: Callable[[], T]) -> T:
    """call() on a new thread: its result, or its exception raised here.

    The numba compiler runs there. CPython 3.11 holds a thread's frames in 16 KB chunks and
    frees a chunk as soon as the stack drops below it, so a compile that starts deep in its
    caller's stack (a test, a command) can sit on a chunk boundary at a hot call depth and
    pay an mmap and a munmap per call there (python/cpython#142183, fixed in 3.13 and 3.14):
    up to half of a compile in system time. A new thread starts the compiler at the same
    shallow depth whatever the caller (docs/performance.md, "Cold-cache compiles in
    mass-spring training")."""
    result: list[T] = []
    error: list[BaseException] = []

    def body() -> None:
        try:
            result.append(call())
        except BaseException as exc:  # re-raised in the caller's thread
            error.append(exc)

    thread = threading.Thread(target=body, name="springc-compile", daemon=True)
    thread.start()
    thread.join()
    if error:
        raise error[0]
    return result[0]


_PARALLEL_LOCK = threading.Lock()
# numba's threading layer for the node-split kernels unless NUMBA_THREADING_LAYER names one:
# its own work queue. OpenMP's threads spin at each of a step's eight joins, and on a busy
# machine a spinning thread holds the core its peer waits for (a step 20-70 times slower);
# the work queue is not safe for launches from two threads at once, which `numba_threads`
# rules out (docs/performance.md#one-run-on-every-core).
THREADING_LAYER = "workqueue"


@contextlib.contextmanager
def numba_threads(count: int) -> Iterator[None]:
    """Inside: numba's threads for a parallel kernel called from this thread, `count` of
    them (at most the pool numba starts with), one such call at a time in the process;
    then numba's setting before."""
    import numba

    with _PARALLEL_LOCK:
        if numba.config.THREADING_LAYER == "default":
            numba.config.THREADING_LAYER = THREADING_LAYER  # read at the first launch
        before = numba.get_num_threads()
        numba.set_num_threads(max(1, min(count, numba.config.NUMBA_NUM_THREADS)))
        try:
            yield
        finally:
            numba.set_num_threads(before)


def as_python() -> bool:
    """Whether kernels run as Python (`NUMBA_DISABLE_JIT=1`: numba's decorators and
    springc's intrinsics then leave plain functions, which a debugger steps through)."""
    from numba.core import config

    return bool(config.DISABLE_JIT)


def cache_dir() -> Path:
    """The kernel cache folder (created if missing)."""
    folder = Path(os.environ.get("SPRINGC_CACHE") or Path.home() / ".cache/springc/kernels")
    folder.mkdir(parents=True, exist_ok=True)
    return folder


@dataclass
class Kernel:
    """A loaded kernel module: `run(**arrays)` calls the generated `run` with named arguments.

    `compile_s` is the time its first call took to compile `run` or load it from numba's
    cache."""

    module: ModuleType
    path: Path
    digest: str
    compile_s: float | None = None

    @property
    def args(self) -> tuple[str, ...]:
        return self.module.ARGS

    def run(self, **arrays) -> None:
        """Call the generated `run`; missing or extra arguments are a programming error."""
        missing = set(self.args) - set(arrays)
        extra = set(arrays) - set(self.args)
        if missing or extra:
            raise TypeError(f"kernel arguments: missing {sorted(missing)}, extra {sorted(extra)}")
        values = [arrays[name] for name in self.args]
        if self.compile_s is None:
            self.compile(values)
        if as_python():  # the noise generator's uint64 products wrap, as when compiled
            with np.errstate(over="ignore"):
                self.module.run(*values)
            return
        with slp_vectorize():
            self.module.run(*values)

    def compile(self, values: list) -> None:
        """Compile `run` for the types of `values` (or load it from numba's cache) under the
        kernel's lock, so that concurrent processes compile each kernel once."""
        import numba

        start = time.perf_counter()
        signature = tuple(numba.typeof(v) for v in values)
        alone = not as_python() and load_first(self.module.run)
        with compiling(self.path, blas=not alone):
            if not as_python():
                on_own_thread(lambda: self.module.run.compile(signature))
        self.compile_s = time.perf_counter() - start


def kernel_path(source: str) -> Path:
    """Where the kernel for `source` lives in the cache."""
    return cache_dir() / f"springc_kernel_{kernel_hash(source)}.py"


def write_source(source: str) -> Path:
    """Write the shared part of `source` (`codegen.shared_text`) to its cache file, once: a file
    already there is never replaced, because numba's cache is keyed on its timestamp and
    another process may be compiling from it. Linking a complete temporary file into place
    makes the file appear whole or not at all."""
    path = kernel_path(source)
    if path.exists():
        return path
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as fh:
            fh.write(shared_text(source))
        os.link(tmp, path)
    except FileExistsError:
        pass  # another process wrote the same text first
    finally:
        os.unlink(tmp)
    return path


@contextlib.contextmanager
def compile_lock(path: Path) -> Iterator[None]:
    """Hold an exclusive lock on `path`'s lock file: a process about to compile a kernel waits
    while another compiles it, then loads the machine code that one cached."""
    with open(path.with_suffix(".lock"), "a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def load(source: str) -> Kernel:
    """Import the generated kernel (compiled lazily by numba, from its cache when present)."""
    digest = kernel_hash(source)
    if digest in _LOADED:
        return _LOADED[digest]
    import numba  # noqa: F401  (the one place numba is imported; fail early if missing)

    path = write_source(source)
    name = f"springc_kernel_{digest}"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    kernel = Kernel(module, path, digest)
    _LOADED[digest] = kernel
    return kernel


def forget(digest: str | None = None) -> None:
    """Drop loaded kernels from this process (to measure cached compile times)."""
    for key in [digest] if digest else list(_LOADED):
        module = _LOADED.pop(key, None)
        if module is not None:
            sys.modules.pop(module.module.__name__, None)
