"""springc.bench.ceiling: the flop accounting of the ceiling loop, and that a measurement reports
consistent, positive, finite numbers. No timing is asserted (the machine is shared)."""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest

from springc.bench import ceiling
from springc.lang.ir import IRBuilder, Source

N_PAD = ceiling.padding_for(70.0)  # the default rating: one compiled loop for all tests


def test_flops_per_dof_step_counts_stage_and_step_work():
    # per stage: 2 stage-state FMAs (4) + h*v (1) + eps*p, two FMAs (5) + 2 accumulating FMAs
    # (4) = 14, plus 2 per padding FMA; 4 stages; per step x += ax, v += av (2)
    assert ceiling.flops_per_dof_step(0) == 4 * 14 + 2 == 58
    assert ceiling.flops_per_dof_step(5) == 58 + 4 * 2 * 5


def test_padding_comes_closest_to_the_requested_flops():
    for flops in range(0, 300, 3):
        n = ceiling.padding_for(flops)
        best = min(abs(ceiling.flops_per_dof_step(k) - flops) for k in range(40))
        assert abs(ceiling.flops_per_dof_step(n) - flops) == best
    assert ceiling.padding_for(70.0) == 2  # 74 flops: 70 is halfway between 66 and 74


@pytest.mark.parametrize("precision, tol", [("float64", 1e-13), ("float32", 2e-6)])
def test_loop_computes_exactly_the_counted_arithmetic(precision, tol):
    """The compiled loop (threads, chunks, an uneven split) and a plain numpy transcription of
    the counted operations agree to rounding (FMA contraction): the loop does all the work it
    is credited with, the padding chain included (p differs by alpha^n per missing FMA)."""
    dtype = np.dtype(precision).type
    state = ceiling.make_state(7, 5, dtype, threads=2)
    assert state[0].shape == (2, 7 * 3)  # 2 chunks of 3 lanes (one padding lane)
    ref = tuple(a.copy() for a in state)
    ceiling.run_loop(state, N_PAD, 40, threads=2)
    ceiling.reference_steps(ref, N_PAD, 40)
    for got, want in zip(state, ref):
        assert got.dtype == dtype
        np.testing.assert_allclose(got, want, rtol=tol, atol=tol)
    short = tuple(a.copy() for a in ref)
    ceiling.reference_steps(short, N_PAD - 1, 1)
    ceiling.reference_steps(ref, N_PAD, 1)
    assert np.max(np.abs(short[1] - ref[1])) > 10 * tol  # one FMA less shows in v


def test_rk4_flop_estimate_of_a_chain():
    n = 200
    b = IRBuilder("chain")
    for i in range(n):
        b.mass(f"M{i}", f"s{i}", 1.0, 0.5 if i in (0, n - 1) else 0.0)
        b.spring(f"K{i}", f"s{i}", 1.0)
    for i in range(n - 1):
        b.coupling(f"C{i}", f"s{i}", f"s{i + 1}", 1.0)
    b.force("F", "s0", Source("in"))
    # per stage: 9 per dof, 2 per damped end, K 2, C 6, F 5; per step 2 per dof
    per_stage = 9 * n + 2 * 2 + 2 * n + 6 * (n - 1) + 5
    assert ceiling.rk4_flops_per_dof_step(b.finish()) == pytest.approx((4 * per_stage + 2 * n) / n)


def test_run_seconds_per_wall_second_formula():
    # 1 GFLOP/s, 100 flops per dof-step, 10 dofs, 1 kHz: 1e9 / (100 * 10 * 1000) = 1000
    assert ceiling.run_seconds_per_wall_second(1e9, 100, 10, 1000.0) == pytest.approx(1000.0)


@pytest.mark.parametrize("precision", ["float64", "float32"])
def test_measurement_reports_consistent_positive_numbers(precision):
    numba.set_num_threads(1)
    r = ceiling.measure_ceiling(
        20, 8, precision, threads=2, flops_per_step=70.0, rate=32000.0, min_seconds=0.02
    )
    for key in (
        "seconds",
        "flops_per_second",
        "bytes_per_second",
        "dof_steps_per_second",
        "run_seconds_per_wall_second",
    ):
        assert math.isfinite(r[key]) and r[key] > 0, key
    dof_steps = r["n_dof"] * r["batch"] * r["steps"]
    assert r["seconds"] >= 0.02
    assert r["flops_per_dof_step"] == ceiling.flops_per_dof_step(N_PAD) == 74
    assert r["flops_per_second"] == pytest.approx(74 * dof_steps / r["seconds"])
    itemsize = np.dtype(precision).itemsize
    assert r["bytes_per_second"] == pytest.approx(48 * itemsize * dof_steps / r["seconds"])
    # lanes x simulated seconds per wall second, rescaled from the loop's 74 flops to the 70 rated
    lane_seconds = r["batch"] * r["steps"] / r["rate"]
    assert r["run_seconds_per_wall_second"] == pytest.approx(lane_seconds / r["seconds"] * 74 / 70)


def test_unknown_precision_is_refused():
    with pytest.raises(ValueError, match="float16"):
        ceiling.measure_ceiling(4, 4, "float16")


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_state_arrays_start_spread_over_a_page(dtype):
    """The six arrays start at distinct cache-line offsets, 4096/6 bytes (to a line) apart,
    within a 4 KiB page, so no two alias (see `make_state`); their values are unchanged."""
    state = ceiling.make_state(24, 64, dtype, threads=2)
    offsets = [a.ctypes.data % ceiling.PAGE for a in state]
    assert offsets == [k * ceiling.PAGE // 6 // ceiling.LINE * ceiling.LINE for k in range(6)]
    np.testing.assert_array_equal(state[0].ravel(), np.linspace(0.1, 1.0, 24 * 64).astype(dtype))
    assert all(a.flags.c_contiguous and not a.any() for a in state[1:])


def test_touch_record_writes_into_every_page_of_the_record():
    """Each 4 KiB page the (probe, run, record) array occupies gets a write (by address, as
    the OS sees it), however the rows of the two threads' runs fall on the pages: here also
    rows exactly a page long starting 64 bytes before a page's end (so each spans two)."""
    for shape, dtype, start in (((3, 5, 700), np.float64, 0), ((2, 7, 16), np.float32, 0),
                                ((1, 1, 1024), np.float32, 4032), ((2, 3, 512), np.float64,
                                                                   4032)):
        flat = ceiling.staggered(np.zeros(int(np.prod(shape)), dtype), start)
        ceiling.touch_record(flat, shape, threads=2)
        page = (flat.ctypes.data + np.arange(flat.size) * flat.itemsize) // ceiling.PAGE
        assert set(page[flat == 1]) == set(page)
        if flat.size * flat.itemsize > 8 * ceiling.PAGE:  # writes, not a fill
            assert np.count_nonzero(flat) < flat.size / 100


def test_first_touch_is_timed():
    took = ceiling.first_touch_seconds((2, 4, 1024), "float32")
    assert math.isfinite(took) and took > 0


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_store_seconds_writes_every_line_of_the_record(dtype):
    """Every value of every run's row, both threads' runs (3 runs: one and two), written;
    a misaligned record is refused (the stores would fault)."""
    from springc.sim.execute import record_buffer

    rec = record_buffer(2, 100, 3, dtype)
    took = ceiling.store_seconds(rec, threads=2)
    assert math.isfinite(took) and took > 0
    assert np.all(rec == 1)
    flat = np.zeros(rec.size + 2, dtype)
    skip = 1 if (flat.ctypes.data + flat.itemsize) % 64 else 2
    with pytest.raises(ValueError, match="64-byte aligned"):
        ceiling.store_seconds(flat[skip:skip + rec.size].reshape(rec.shape))


def test_peak_loop_computes_every_counted_fma():
    """The peak loop's chains after one pass are the affine map alpha x + beta applied
    PEAK_DEPTH times (closed form, to rounding); one FMA less would show."""
    acc = ceiling.peak_state(2, 3, np.float64)
    x0 = acc.copy()
    alpha, beta = 0.5, 1.0
    ceiling._peak_kernel(3)(acc, np.array([alpha, beta]), 1)
    fixed = beta / (1 - alpha)

    def iterated(n):
        return fixed + alpha ** n * (x0 - fixed)

    np.testing.assert_allclose(acc, iterated(ceiling.PEAK_DEPTH), rtol=0, atol=1e-15)
    assert np.max(np.abs(acc - iterated(ceiling.PEAK_DEPTH - 1))) > 1e-10


@pytest.mark.parametrize("precision", ["float64", "float32"])
def test_peak_measurement_counts_its_flops(precision):
    r = ceiling.measure_peak(5, precision, threads=2, min_seconds=0.02)
    chunks = min(r["threads"], 5)
    width = -(-5 // chunks)
    flops = 2 * ceiling.PEAK_CHAINS * ceiling.PEAK_DEPTH * chunks * width * r["passes"]
    assert r["seconds"] >= 0.02
    assert r["flops_per_second"] == pytest.approx(flops / r["seconds"])
