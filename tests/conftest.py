"""Test-run settings: one BLAS thread per test process, and no full garbage collections over
the objects a session leaves at its end.

`make test` runs one pytest-xdist worker per core, and a worker's kernels run on numba threads
of their own, so OpenBLAS's default of a thread per core puts several busy threads on each
core: its threads spin between calls and the other worker waits. A dense eigensolve of the
checks took 2.2 s instead of 0.024 s that way (docs/performance.md, "BLAS threads beside busy
cores"). The environment variable reaches the processes the tests start; numpy is already loaded
here, so its thread pool is limited directly as well.

At a session's end pytest runs full garbage collections (to report objects whose finaliser
failed) and so does the interpreter at exit. A worker that compiled dozens of kernels holds
millions of objects, and those passes kept both workers busy for about 9 s after the last test
of a cold run (docs/performance.md, "Where a cold test run's time goes"). The objects alive
when the session ends are frozen out of them (`gc.freeze`), so a finaliser that fails in a
cycle still alive then goes unreported; the collector ran on its own schedule through the
tests, reporting what it found.
"""

import gc
import os

import pytest
from threadpoolctl import threadpool_limits

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # numpy's BLAS; numba's threads stay
threadpool_limits(limits=1, user_api="blas")


@pytest.hookimpl(tryfirst=True)
def pytest_unconfigure(config) -> None:
    gc.freeze()
