"""Data-set simulation on Dask: batches of clips to worker processes, results back in order.

Default: a `LocalCluster` on this machine, one single-threaded worker process per core (each
batch is simulated in lockstep by one core; numba's own threads would only compete). Work of
fewer than `LOCAL_CLUSTER_FROM` clips runs on one thread per core in this process instead (the
kernels release the GIL): a cluster's start, its workers' imports and their kernel loads cost
more than such work gains from processes. With
`scheduler=ADDRESS` the batches go to an existing cluster (`dask scheduler` / `dask worker`
on other machines). Workers compile a kernel once and reuse it: the generated source and
numba's machine code live in the shared on-disk cache (`SPRINGC_CACHE`, passed on to local
workers), and every process keeps its loaded kernels. The work is deterministic per batch, so
the results equal a single-process run bit for bit whatever the scheduling.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any

from tqdm import tqdm

from springc.errors import SimulationError, UsageError

# clips: from here a local cluster's processes pay (docs/performance.md, "Small jobs on
# threads"); below, the batches run on threads here
LOCAL_CLUSTER_FROM = 512


def cores() -> int:
    """Cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def map_batches(fn: Callable[[Any], Any], batches: Sequence[Any], scheduler: str | None = None,
                *, workers: int | None = None, desc: str = "simulating",
                sizes: Sequence[int] | None = None) -> list[Any]:
    """[fn(b) for b in batches], computed on Dask; progress in clips (`sizes[k]` per batch) or
    batches. `scheduler`: None for a local cluster of `workers` processes (default: all
    cores; 1, or fewer than `LOCAL_CLUSTER_FROM` clips by `sizes`, runs here without Dask,
    on that many threads), or the address of a running scheduler. Inside
    `gpu.default_device('cuda')` the batches run here, one after the other: the GPU is this
    process's."""
    workers = workers or cores()
    clips = int(sum(sizes)) if sizes is not None else None
    bar = tqdm(total=int(sum(sizes)) if sizes is not None else len(batches), desc=desc,
               unit="clip" if sizes is not None else "batch", file=sys.stderr, disable=None,
               smoothing=0.1)
    step = (lambda k: sizes[k]) if sizes is not None else (lambda k: 1)
    with bar:
        if on_gpu():
            return _here(fn, batches, bar, step, 1)
        if not _OPEN and _stays_here(scheduler, workers, clips, len(batches)):
            return _here(fn, batches, bar, step, workers)
        if _OPEN:
            return _gather(_OPEN[-1], fn, batches, bar, step)
        with _client(scheduler, workers) as client:
            return _gather(client, fn, batches, bar, step)


def _stays_here(scheduler: str | None, workers: int, clips: int | None,
                batches: int | None = None) -> bool:
    """Whether work runs in this process: no scheduler named, and one worker, at most one
    batch or fewer than `LOCAL_CLUSTER_FROM` clips."""
    small = clips is not None and clips < LOCAL_CLUSTER_FROM
    return scheduler is None and (workers == 1 or (batches is not None and batches <= 1)
                                  or small)


def _here(fn, batches, bar, step, workers: int) -> list[Any]:
    """[fn(b) for b in batches] in this process: on this thread where one worker or one
    batch, else on up to `workers` threads (pending batches cancelled after an error)."""
    from concurrent.futures import ThreadPoolExecutor, as_completed

    out: list[Any] = [None] * len(batches)
    if workers <= 1 or len(batches) <= 1:
        for k, b in enumerate(batches):
            out[k] = fn(b)
            bar.update(step(k))
        return out
    pool = ThreadPoolExecutor(min(workers, len(batches)))
    try:
        futures = {pool.submit(fn, b): k for k, b in enumerate(batches)}
        for fut in as_completed(futures):
            k = futures[fut]
            out[k] = fut.result()  # the first error in completion order propagates
            bar.update(step(k))
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
    return out


def on_gpu() -> bool:
    """Whether simulations run on the GPU (`gpu.default_device`): in this process, then."""
    from springc.sim import gpu

    return gpu.current() == "cuda"


_OPEN: list = []  # the client of the `session` in progress, which `map_batches` uses
_AHEAD: list = []  # futures of `ahead` (Dask cancels a task whose future is dropped)


def ahead(fn: Callable[..., Any], *args: Any) -> None:
    """Start fn(*args) on a worker of the session in progress, if there is one, and never
    read its result: work done ahead for its side effects, such as compiling a kernel into
    the shared cache while this process does something else. Its errors are dropped (the
    same work done for real reports them)."""
    if _OPEN:
        _AHEAD.append(_OPEN[-1].submit(_quietly, fn, *args, pure=False))


def _quietly(fn: Callable[..., Any], *args: Any) -> None:
    try:
        fn(*args)
    except Exception:  # noqa: BLE001  (see `ahead`)
        pass


@contextmanager
def session(scheduler: str | None = None, workers: int | None = None,
            clips: int | None = None) -> Iterator[None]:
    """One Dask client for every `map_batches` call inside: a local cluster starts (and its
    workers import springc and load their kernels) once per command, not once per split. No
    cluster for one local worker, for work of fewer than `LOCAL_CLUSTER_FROM` `clips` (each
    `map_batches` inside then runs here) or on the GPU; a session inside a session is the
    outer one."""
    workers = workers or cores()
    if _OPEN or on_gpu() or _stays_here(scheduler, workers, clips):
        yield
        return
    with _client(scheduler, workers) as client:
        _OPEN.append(client)
        try:
            yield
        finally:
            _OPEN.pop()
            _AHEAD.clear()


def _client(scheduler: str | None, workers: int):
    """A Dask client: to `scheduler`, or to a new local cluster of `workers` processes."""
    from dask.distributed import Client, LocalCluster

    if scheduler is not None:
        try:
            return Client(scheduler, timeout="20s")
        except (OSError, TimeoutError, ValueError) as exc:
            raise UsageError(f"cannot reach the Dask scheduler at {scheduler!r} ({exc})",
                             hint="start one with `dask scheduler` and workers with "
                                  "`dask worker ADDRESS`, or leave out --scheduler") from None
    cache = os.environ.get("SPRINGC_CACHE")
    env = {"NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    if cache:
        env["SPRINGC_CACHE"] = cache
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                           dashboard_address=":0", silence_logs=50, env=env)
    return _OwnedClient(Client(cluster), cluster)


class _OwnedClient:
    """A client that closes its local cluster with it."""

    def __init__(self, client, cluster) -> None:
        self.client, self.cluster = client, cluster

    def __enter__(self):
        return self.client

    def __exit__(self, *exc) -> None:
        self.client.close()
        self.cluster.close()


def _gather(client, fn, batches, bar, step) -> list[Any]:
    from dask.distributed import as_completed

    futures = [client.submit(fn, b, pure=False) for b in batches]
    index = {f.key: k for k, f in enumerate(futures)}
    out: list[Any] = [None] * len(batches)
    try:
        for fut in as_completed(futures):
            k = index[fut.key]
            out[k] = fut.result()  # re-raises the worker's exception (user errors included)
            bar.update(step(k))
    except (KeyboardInterrupt, SimulationError):
        for f in futures:
            f.cancel()
        raise
    return out
