"""Streaming (non-temporal) stores and the aligned record buffer they write into."""

from __future__ import annotations

import numba as nb
import numpy as np
import pytest

from springc.kernels.codegen import RECORD_ALIGN
from springc.sim.execute import record_buffer
from springc.kernels.streamstore import store_fence, stream_store
from springc.check import check


@nb.njit
def _store_groups4(rec, values):
    for p in range(rec.shape[0]):
        for r in range(rec.shape[1]):
            for g in range(0, rec.shape[2], 4):
                stream_store(rec, p, r, g, (values[p, r, g], values[p, r, g + 1],
                                            values[p, r, g + 2], values[p, r, g + 3]))
    store_fence()


@nb.njit
def _store_pairs_at(rec, p, r, k, a, b):
    stream_store(rec, p, r, k, (a, b))
    store_fence()


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_streaming_stores_write_every_group_like_assignment(dtype):
    rec = record_buffer(3, 5, 8, dtype)
    values = np.random.default_rng(0).standard_normal(rec.shape).astype(dtype)
    _store_groups4(rec, values)
    np.testing.assert_array_equal(rec, values)


def test_a_streaming_store_touches_only_its_own_lanes():
    rec = record_buffer(2, 3, 6, np.float64)
    _store_pairs_at(rec, 1, 2, 4, 1.5, -2.5)
    want = np.zeros(rec.shape)
    want[1, 2, 4:6] = [1.5, -2.5]
    np.testing.assert_array_equal(rec, want)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("runs", [1, 5, 16, 33, 64])
def test_record_buffer_rows_are_aligned_and_padded(dtype, runs):
    rec = record_buffer(3, 7 * runs, runs, dtype)  # (probe, run, record)
    item = np.dtype(dtype).itemsize
    assert rec.ctypes.data % RECORD_ALIGN == 0
    assert rec.strides[1] % RECORD_ALIGN == 0
    assert rec.shape[:2] == (3, runs) and 7 * runs <= rec.shape[2] < 7 * runs + RECORD_ALIGN // item
    assert rec.flags.c_contiguous and not rec.any()


def test_a_kernel_refuses_a_misaligned_record_buffer(monkeypatch):
    from springc.lang.ir import IRBuilder, Tran
    from springc.sim import execute
    from springc.sim import simulate as sim

    b = IRBuilder("oscillator")
    b.mass("M1", "a", 1.0, 1.0)
    b.spring("K1", "a", 100.0)
    b.probe("x", "a")
    b.tran = Tran(1e-3, 0.01, None)
    net = b.finish()

    def shifted(probes, records, runs, dtype):
        good = record_buffer(probes, records, runs + 1, dtype)
        width = good.shape[2]
        return good.ravel()[1:1 + probes * runs * width].reshape(probes, runs, width)

    monkeypatch.setattr(execute, "record_buffer", shifted)
    with pytest.raises(ValueError, match="64-byte aligned"):
        # the shared kernel: a register kernel (one run, a few masses) stores ordinarily
        sim.simulate(check(net), np.zeros((4, 1, 11)), write_out=False)
