"""The thermal-noise generator's branch-free Box-Muller (`springc.kernels.thermal.box_muller`,
the numpy mirror of the kernels' polynomial logarithm, sine and cosine) against Box-Muller in
numpy's own functions on the same bits, and its moments (`springc.bench.noise`). numpy only:
no kernel is compiled."""

from __future__ import annotations

import numpy as np

from springc.bench.noise import draw_statistics
from springc.kernels import thermal


def test_the_polynomials_are_box_muller_to_rounding() -> None:
    r = thermal.counter_bits(9, np.arange(64), [0, 1], np.arange(4096))
    odd = np.array([False, True])[None, :, None]
    got, want = thermal.box_muller(r, odd), thermal.box_muller_libm(r, odd)
    assert np.abs(got - want).max() < 2e-14  # |z| < 7: a few units in the last place


def test_the_extremes_of_the_bits() -> None:
    """u1 at its least (2^-33: the largest radius, sqrt(66 ln 2)) and at its largest, and
    each quadrant's ends of the angle."""
    hi = np.array([0, 0, 2**32 - 1, 2**31, 1], np.uint64) << np.uint64(32)
    lo = np.array([0, 2**30 - 1, 2**30, 2**31 + 12345, 2**32 - 1], np.uint64)
    r = (hi | lo)[None, None, :]
    for odd in (False, True):
        got = thermal.box_muller(r, odd)
        np.testing.assert_allclose(got, thermal.box_muller_libm(r, odd), rtol=1e-14,
                                   atol=1e-15)
    assert np.isclose(np.hypot(thermal.box_muller(r, False), thermal.box_muller(r, True))[0, 0, 0],
                      np.sqrt(66 * np.log(2)), rtol=1e-14)


def test_the_draws_are_standard_normal() -> None:
    s = draw_statistics(1 << 17)
    for key, want in (("mean", 0.0), ("var", 1.0), ("skew", 0.0), ("kurtosis", 3.0)):
        assert abs(s[key] - want) < 4 * s["se"][key], key
    assert abs(s["pair_corr"]) < 4 * s["draws"] ** -0.5 * 2**0.5
    assert s["max_vs_libm"] < 2e-14
