"""Data-set simulation on Dask: a local multi-process cluster, and threads in this process for
work of fewer than `LOCAL_CLUSTER_FROM` clips, give exactly the results of a single-process
run, in order, and worker failures reach the caller as the user error."""

from __future__ import annotations

import time
from functools import partial
from pathlib import Path

import numpy as np
import pytest

from springc.errors import SimulationError
from springc.kws.features import massspring as msp
from springc.kws.features.distributed import map_batches
from shared_cache import KERNELS

S = msp.MassSpringSettings(bins=2, delays=2)


@pytest.fixture(autouse=True, scope="module")
def _kernel_cache():
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("SPRINGC_CACHE", str(KERNELS))
        yield


def clips(count: int = 6, seconds: float = 0.3) -> np.ndarray:
    """Tone bursts of different pitch and loudness at 16 kHz."""
    t = np.arange(int(16000 * seconds)) / 16000
    env = np.sin(np.pi * t / seconds) ** 2
    return np.stack([(0.1 + 0.1 * k) * env * np.sin(2 * np.pi * (300 + 400 * k) * t)
                     for k in range(count)]).astype(np.float32)


def _fail(batch):
    raise SimulationError("run run0 diverged (test)")


def test_two_worker_cluster_and_two_threads_equal_a_single_process_run(monkeypatch):
    """Six clips in three batches: on two threads here (fewer clips than
    `LOCAL_CLUSTER_FROM`), and on a two-worker local cluster (the bound lowered to them)."""
    from springc.kws.features import distributed

    parts = msp.batches(clips(), 2)
    sizes = [len(p) for p in parts]
    fn = partial(msp.phi_batch, s=S)
    alone = map_batches(fn, parts, workers=1)
    threads = map_batches(fn, parts, workers=2, sizes=sizes)
    monkeypatch.setattr(distributed, "_stays_here", lambda *a: False)
    cluster = map_batches(fn, parts, workers=2, sizes=sizes)
    for got in (threads, cluster):
        assert len(got) == len(parts)
        for a, b in zip(alone, got):
            np.testing.assert_array_equal(a, b)  # bit for bit, in order
    whole = msp.simulate_phi(clips().astype(np.float64), S, chunk=msp.BATCH,
                             precision=msp.DATASET_PRECISION)  # the batches' kernel
    np.testing.assert_allclose(np.concatenate(cluster), whole, rtol=1e-12)


@pytest.mark.parametrize("sizes", [None, [1, 1, 1]], ids=["cluster", "threads"])
def test_worker_errors_reach_the_caller(sizes):
    with pytest.raises(SimulationError, match="diverged"):
        map_batches(_fail, [1, 2, 3], workers=2, sizes=sizes)


def test_a_small_session_starts_no_cluster():
    """A session for fewer clips than `LOCAL_CLUSTER_FROM` opens no client (its batches run
    on threads here); one for an unknown count does (the next test)."""
    from springc.kws.features import distributed

    with distributed.session(None, 2, clips=distributed.LOCAL_CLUSTER_FROM - 1):
        assert distributed._OPEN == []
        assert map_batches(abs, [-1, -2], workers=2, sizes=[1, 1]) == [1, 2]


def test_an_existing_scheduler_by_address_gives_the_same_results():
    from dask.distributed import LocalCluster

    parts = msp.batches(clips(4), 2)
    fn = partial(msp.phi_batch, s=S)
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                      dashboard_address=":0", env={"SPRINGC_CACHE": str(KERNELS)}) as cluster:
        remote = map_batches(fn, parts, scheduler=cluster.scheduler_address)
    for a, b in zip(map_batches(fn, parts, workers=1), remote):
        np.testing.assert_array_equal(a, b)


def test_an_unreachable_scheduler_is_a_user_error():
    from springc.errors import UsageError

    with pytest.raises(UsageError, match="cannot reach the Dask scheduler"):
        map_batches(_fail, [1, 2], scheduler="not-an-address::")


def _touch(path: str) -> None:
    Path(path).write_text("done")


def test_work_ahead_runs_on_a_session_worker_and_drops_its_errors(tmp_path):
    """`ahead` outside a session does nothing; inside, the task runs on a worker (its file
    appears), and a failing one neither raises here nor stops the session's batches."""
    from springc.kws.features import distributed
    from springc.kws.features.distributed import ahead, session

    ahead(_touch, str(tmp_path / "outside"))
    with session(None, 2):
        assert len(distributed._OPEN) == 1  # a local cluster: the clips are not counted
        ahead(_fail, None)
        ahead(_touch, str(tmp_path / "inside"))
        assert map_batches(abs, [-1, -2]) == [1, 2]
        for _ in range(200):
            if (tmp_path / "inside").exists():
                break
            time.sleep(0.05)
    assert (tmp_path / "inside").read_text() == "done"
    assert not (tmp_path / "outside").exists()
