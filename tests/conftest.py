"""Test-run settings: one BLAS thread per test process.

`make test` runs one pytest-xdist worker per core, and a worker's kernels run on numba threads
of their own, so OpenBLAS's default of a thread per core puts several busy threads on each
core: its threads spin between calls and the other worker waits. A dense eigensolve of the
checks took 2.2 s instead of 0.024 s that way (docs/performance.md, "BLAS threads beside busy
cores"). The environment variable reaches the processes the tests start; numpy is already loaded
here, so its thread pool is limited directly as well.
"""

import os

from threadpoolctl import threadpool_limits

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # numpy's BLAS; numba's threads stay
threadpool_limits(limits=1, user_api="blas")
