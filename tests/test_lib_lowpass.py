"""netlists/lib/lowpass.spr: the critically damped low-pass mass (paper Sec. III.C)."""

from __future__ import annotations

import numpy as np
import pytest

from springc.analyses.ac import response
from springc.lang import load_text
from springc.check import check


@pytest.mark.parametrize("fc,k", [(50.0, 100.0), (10.0, 1.0)])
def test_response_is_critically_damped_second_order(fc, k):
    """X/F = (1/k) wc^2 / (wc^2 - w^2 + 2 i wc w): |H| k = 1/2 at fc, no resonance peak."""
    net = load_text(f'.include "lowpass.spr"\nXl n lowpass fc={fc} k={k}\nF1 n in(0)\n')
    f = np.geomspace(fc / 100, fc * 100, 400)
    wc, w = 2 * np.pi * fc, 2 * np.pi * f
    h = response(check(net), "n", f).h
    assert h == pytest.approx(wc**2 / (wc**2 - w**2 + 2j * wc * w) / k, rel=1e-9)
    assert np.all(np.diff(np.abs(h)) < 0)
    assert abs(response(check(net), "n", np.array([fc])).h[0]) * k == pytest.approx(0.5)


def test_external_damping_is_taken_off_the_local_damping():
    net = load_text('.include "lowpass.spr"\nXl n lowpass fc=50 k=100 bext=0.1\n')
    assert net.masses.b[0] == pytest.approx(2 * 100 / (2 * np.pi * 50) - 0.1)
