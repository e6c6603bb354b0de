"""netlists/lib/squarer.spr and the paper's Fig. 5: a quadratic coupling after a matched delay
line squares at low energy and compresses at high energy."""

from __future__ import annotations

import numpy as np
import pytest

from springc.design import figures
from springc.lang import load_text


@pytest.fixture(scope="module")
def energetics():
    return figures.experiment_energetics()


def test_low_energy_slope_is_two(energetics):
    """E_out ~ E_in^2 for small pulses (measured slope 1.9994)."""
    assert energetics.slope_low == pytest.approx(2.0, abs=0.02)


def test_high_energy_slope_is_compressive(energetics):
    """Large pulses: E_out grows slower than E_in (measured slope 0.667, the paper's 2/3)."""
    assert energetics.slope_high < 1.0
    assert energetics.slope_high == pytest.approx(2 / 3, abs=0.05)


def test_energy_conservation_bounds(energetics):
    """Half of the input work goes into the left termination: E_out <= E_in / 2 always, and the
    linear line delivers almost all of that half."""
    e = energetics
    assert np.all(e.e_out_quad <= 0.5 * e.e_in_quad)
    assert e.e_out_lin / e.e_in_lin == pytest.approx(0.5, abs=0.01)
    assert e.e_in_quad == pytest.approx(e.e_in_lin, rel=1e-3)  # same drive, same line


def test_squarer_is_one_quadratic_coupling():
    net = load_text('.include "squarer.spr"\nMa a m=1\nMb b m=1\nXs a b squarer g=2 a=0.5\n')
    assert net.element_counts() == {"M": 2, "Q": 1}
    assert (net.quads.g[0], net.quads.a[0]) == (2.0, 0.5)
