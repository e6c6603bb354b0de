"""springc.design.blocks: delay line, readout and low-pass parameters (paper Sec. III)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from springc.design.blocks import delayline_params, lowpass_params, readout_omega, readout_params
from springc.errors import UsageError


def test_delayline_paper_example():
    """Paper Sec. III.A: 10 ms per site with kc = 10 needs m = 1e-3; kl = 1e-6 kc."""
    p = delayline_params(0.01, 10.0)
    assert p.m == pytest.approx(1e-3) and p.kl == pytest.approx(1e-5)
    assert math.sqrt(p.m / p.kc) == pytest.approx(0.01)
    assert p.b_match == pytest.approx(math.sqrt(p.m * p.kc))


def test_readout_paper_example():
    """Paper Sec. III.B: Q = 0.01 and tau = 80 s give w_r ~ 1.25 rad/s."""
    assert readout_omega(80.0, 0.01) == pytest.approx(1.25, abs=1e-3)


@pytest.mark.parametrize("tau,q", [(80.0, 0.01), (1.0, 0.2), (0.05, 0.45), (3.0, 1e-4)])
def test_readout_slow_eigenvalue_is_minus_one_over_tau(tau, q):
    """The slow root of m s^2 + b s + k is -1/tau: tau = 2Q / (w (1 - sqrt(1 - 4Q^2)))."""
    p = readout_params(tau, q, m=2.0)
    roots = np.roots([p.m, p.b, p.k_total])
    assert np.all(np.isreal(roots))
    assert -1 / roots.real.max() == pytest.approx(tau, rel=1e-9)
    assert p.m * p.omega / p.b == pytest.approx(q)


def test_readout_external_stiffness_is_subtracted():
    p = readout_params(80.0, 0.01, 1.0, k_external=1.0)
    assert p.k_local + 1.0 == pytest.approx(p.k_total)
    with pytest.raises(UsageError, match="exceeds"):
        readout_params(80.0, 0.01, 1.0, k_external=10.0)


def test_lowpass_is_critically_damped_with_half_amplitude_at_cutoff():
    """Q = 1/2: a double real root at -wc, and |X/F| k = 1/2 at f = fc."""
    p = lowpass_params(50.0, 100.0, b_external=0.1)
    wc = 2 * np.pi * 50.0
    roots = np.roots([p.m, p.b_total, p.k])
    assert roots.real == pytest.approx([-wc, -wc], rel=1e-6)
    h = p.k / (p.k - wc**2 * p.m + 1j * wc * p.b_total)
    assert abs(h) == pytest.approx(0.5)
    assert p.b == pytest.approx(p.b_total - 0.1)


@pytest.mark.parametrize("call", [
    lambda: delayline_params(-1, 10), lambda: delayline_params(0.01, 0),
    lambda: readout_params(0, 0.01), lambda: readout_params(1, 0.5),
    lambda: lowpass_params(50, 1, b_external=1.0), lambda: lowpass_params(0, 1),
])
def test_bad_values_are_user_errors(call):
    with pytest.raises(UsageError):
        call()
