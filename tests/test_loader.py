"""The kernel cache shared between processes: each kernel is compiled once under its lock and
loaded by the others from numba's cache, and a kernel compiles exactly the signature it is
called with."""

from __future__ import annotations

import contextlib
import gc
import json
import os
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from springc import lang
from springc.check import check
from springc.kernels import loader
from springc.sim.simulate import simulate

EXAMPLE = Path(__file__).resolve().parents[1] / "netlists" / "examples" / "duffing.spr"
ONE_PROCESS = f"""
import json, sys
from springc import lang
from springc.check import check
from springc.sim.simulate import simulate
sys.stdin.read()  # start together
out = simulate(check(lang.load_file({str(EXAMPLE)!r})), tstop=0.5, method="heun3")
from springc.kernels import loader
run = loader._LOADED.popitem()[1].module.run
print(json.dumps({{"x": out.probes["x(x)"][0].tolist(), "hits": sum(run.stats.cache_hits.values()),
                  "misses": sum(run.stats.cache_misses.values())}}))
"""


def test_two_processes_compile_a_kernel_once(tmp_path: Path) -> None:
    env = {**os.environ, "SPRINGC_CACHE": str(tmp_path)}
    procs = [subprocess.Popen([sys.executable, "-c", ONE_PROCESS], env=env, text=True,
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE) for _ in range(2)]
    for proc in procs:
        proc.stdin.close()
    results = [json.loads(proc.stdout.read()) for proc in procs]
    for proc in procs:
        proc.wait()
    assert [p.returncode for p in procs] == [0, 0]
    assert results[0]["x"] == results[1]["x"]
    assert sorted((r["misses"], r["hits"]) for r in results) == [(0, 1), (1, 0)]
    assert len(list(tmp_path.glob("springc_kernel_*.py"))) == 1


def test_a_kernel_compiles_only_the_signature_it_is_called_with(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("SPRINGC_CACHE", str(tmp_path))
    net = lang.load_file(EXAMPLE)
    first = simulate(check(net), tstop=0.2, method="heun3")
    kernel = loader._LOADED[Path(first.info["kernel"]).stem.removeprefix("springc_kernel_")]
    again = simulate(check(net), tstop=0.2, method="heun3")
    assert len(kernel.module.run.overloads) == 1
    np.testing.assert_array_equal(first.probes["x(x)"], again.probes["x(x)"])


def test_on_own_thread_returns_the_value_and_raises_the_error_of_its_call() -> None:
    here = threading.get_ident()
    assert loader.on_own_thread(lambda: threading.get_ident()) != here
    assert loader.on_own_thread(lambda: 6 * 7) == 42

    def fails():
        raise ValueError("from the compile thread")

    with pytest.raises(ValueError, match="from the compile thread"):
        loader.on_own_thread(fails)


def test_a_kernel_file_is_written_once(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("SPRINGC_CACHE", str(tmp_path))
    source = "import numpy as np\nARGS = ()\n"
    path = loader.write_source(source)
    stamp = path.stat().st_mtime_ns
    os.utime(path, ns=(stamp - 10**9, stamp - 10**9))
    assert loader.write_source(source) == path
    assert path.stat().st_mtime_ns == stamp - 10**9
    assert path.read_text() == source
    assert list(tmp_path.iterdir()) == [path]


def test_the_collector_is_paused_while_a_kernel_compiles_on_a_thread_of_its_own(
        tmp_path, monkeypatch) -> None:
    net = lang.load_file(EXAMPLE)
    monkeypatch.setenv("SPRINGC_CACHE", str(tmp_path / "a"))
    first = simulate(check(net), tstop=0.05, method="ssprk3")
    loader.forget(Path(first.info["kernel"]).stem.removeprefix("springc_kernel_"))
    monkeypatch.setenv("SPRINGC_CACHE", str(tmp_path / "b"))  # empty: numba compiles again
    seen = []
    real = loader.compile_lock

    @contextlib.contextmanager
    def watching(path):
        with real(path):
            yield
            seen.append(gc.isenabled())  # inside `compiling`, once numba has compiled

    monkeypatch.setattr(loader, "compile_lock", watching)
    compiled_on = []
    real_thread = loader.on_own_thread

    def recording(call):
        def traced():
            compiled_on.append(threading.get_ident())
            return call()

        return real_thread(traced)

    monkeypatch.setattr(loader, "on_own_thread", recording)
    assert gc.isenabled()
    again = simulate(check(net), tstop=0.05, method="ssprk3")
    assert seen == [False] and gc.isenabled()
    assert len(compiled_on) == 1 and compiled_on[0] != threading.get_ident()
    np.testing.assert_array_equal(first.probes["x(x)"], again.probes["x(x)"])
    with loader.gc_paused():  # nested: on again only when the outer scope ends
        with loader.gc_paused():
            assert not gc.isenabled()
        assert not gc.isenabled()
    assert gc.isenabled()
    gc.disable()
    try:
        with loader.gc_paused():  # entered with the collector off: left off
            pass
        assert not gc.isenabled()
    finally:
        gc.enable()


def test_call_types_resolved_once_give_the_same_machine_code():
    """numba compiles a function to the same assembly with each call type resolved once
    (`loader.call_types_remembered`, the scope of every kernel compile) as without: only the
    function's unique name differs. The types are kept during the compile and dropped after."""
    import re

    import numba

    source = ("def f(x, y):\n    s = 0.0\n    for i in range(x.shape[0]):\n"
              "        s += x[i] * y[i] + x[i] * 2.0 - y[i] * 3.0 + x[i] * y[i]\n"
              "    return s\n")

    def fresh():
        space: dict = {}
        exec(source, space)
        return numba.njit(space["f"])

    plain, remembered = fresh(), fresh()
    sig = (numba.float64[:], numba.float64[:])
    plain.compile(sig)
    with loader.call_types_remembered():
        remembered.compile(sig)
        kept = len(loader._CALL_TYPES)
    assert kept > 0 and loader._CALL_TYPES is None
    unique = re.compile(r"B\d+v\d+")  # numba's per-function id in the mangled name

    def code(f) -> list[str]:  # symbol sizes left out: a name's string grows with its id
        return [line for line in unique.sub("Bv", f.inspect_asm(sig)).splitlines()
                if not line.startswith("\t.size")]

    assert code(plain) == code(remembered)


BLAS_ALONE = """
import sys
import numpy as np
from springc.kernels import loader
loader.blas_module_alone()  # as a kernel's first compile or cache load does
alone = "scipy.linalg" not in sys.modules and "scipy.linalg.cython_blas" in sys.modules
from numba import njit

@njit
def product(a, b):
    return np.dot(a, b)

a = np.arange(12.0).reshape(3, 4)
b = np.arange(8.0).reshape(4, 2) - 3.0
assert np.array_equal(product(a, b), a @ b)  # numba's BLAS call, through the module loaded alone
from scipy.linalg import blas, cython_blas
assert cython_blas is sys.modules["scipy.linalg.cython_blas"] and "ddot" in cython_blas.__pyx_capi__
assert blas.ddot(a[0], a[1]) == a[0] @ a[1]
print(alone)
"""


def test_scipys_blas_module_loaded_alone_serves_numba_and_scipy() -> None:
    """scipy's BLAS extension module loaded without scipy.linalg's package
    (`loader.blas_module_alone`, at a kernel's first compile or cache load; that a warm `sim`
    then imports no scipy.linalg is tests/test_startup_imports.py's): numba's BLAS calls in
    the same process read it, and scipy.linalg imported afterwards finds it and works."""
    done = subprocess.run([sys.executable, "-c", BLAS_ALONE], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["True"]
