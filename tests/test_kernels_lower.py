"""springc.kernels.lower: the kernel's netlist, P x^2 moved into the linear springs."""

from __future__ import annotations

import numpy as np

from springc.check import check
from springc.kernels.lower import kernel_netlist
from springc.lang import load_text
from springc.sim.simulate import simulate

PAIR = """* two coupled oscillators, driven; extra terms below D1
M1 a m=1 b=0.3
M2 c m=2 b=0.1
K2 c k={kc}
C1 a c k=40 a=1
D1 a l=5
{extra}
F1 a sin(2 3Hz) gain=1
.probe x(a) x(c)
.tran 1ms 2
"""


def _pair(extra: str, kc: float):
    return load_text(PAIR.format(extra=extra, kc=kc), "<pair>")


def test_squares_of_one_variable_become_springs_and_nothing_else_moves():
    net = _pair("K1 a k=100\nP1 c=-7 c^2\nP2 c=0.5 a^3\nP3 c=0.25 a^1 c^1", 90.0)
    low = kernel_netlist(net)
    assert low.monomials.names == ["P2", "P3"]
    assert low.springs.names == ["K2", "K1", "P1"]
    assert low.springs.k[-1] == -14.0 and low.nodes[low.springs.node[-1]] == "c"
    assert np.array_equal(low.monomials.ptr, [0, 1, 3])
    assert [low.nodes[i] for i in low.monomials.var] == ["a", "a", "c"]
    assert kernel_netlist(low) is low  # nothing left to move


def test_a_folded_square_simulates_as_the_spring_it_is():
    """P c x^2 (c < 0, the multipliers' correction) on a stiffer spring: the same motion as
    the net spring, to rounding (the Duffing term keeps the kernel nonlinear)."""
    folded = _pair("K1 a k=100\nP1 c=-7 c^2", 90.0)
    plain = _pair("K1 a k=100", 76.0)
    got = simulate(check(folded), method="rk4", substeps=4).probes
    want = simulate(check(plain), method="rk4", substeps=4).probes
    for k in want:
        scale = np.abs(want[k]).max()
        assert np.abs(got[k] - want[k]).max() < 1e-12 * scale
