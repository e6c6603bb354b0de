"""netlists/lib/compressor.spr: the quasi-static cube-root compressor after the low-pass."""

from __future__ import annotations

import numpy as np
import pytest

from springc.kws.features.massspring import compressed
from springc.lang import load_text
from springc.sim.simulate import simulate
from springc.check import check

KQ, THRESHOLD = 10.0, 1e-4  # l = kq / threshold^2
NETLIST = f""".include "compressor.spr"
Min in m=1e-3 b=20
Kin in k=1e4
F1 in in(0) gain=1e4
Xc in out compressor k={KQ} m=4e-6 b=9e-3 l={KQ / THRESHOLD**2}
.tran {{1/16000}} 1
"""


def test_compressor_is_one_spring_one_mass_one_duffing():
    net = load_text(NETLIST)
    assert net.element_counts() == {"M": 2, "K": 1, "C": 1, "D": 1, "F": 1}


def test_slow_drive_follows_the_static_cube_root_law():
    """A 1 s exponential ramp over five decades (0.1x to 1e4x the threshold): out tracks the
    static solution of kq (x_in - c) = l c^3, following below the threshold (c = x_in) and
    growing as the cube root above it. It lags by its time constant b / k_eff times the
    ramp's growth rate 11.5/s: 1.0% at rest stiffness, less as it stiffens (measured worst
    0.96%)."""
    rate = 16000.0
    t = np.arange(int(1.0 * rate)) / rate
    u = THRESHOLD * np.geomspace(0.1, 1e4, len(t))  # ~ x_in (stiff follower)
    net = load_text(NETLIST)
    res = simulate(check(net), u[None, None, :], rate, probes=["x(in)", "x(out)"], outrate=rate,
                   tstop=t[-1], substeps=8)
    x_in, c = res.probes["x(in)"][0], res.probes["x(out)"][0]
    want = compressed(x_in, KQ, np.array(KQ / THRESHOLD**2))
    late = t > 0.02  # after the start-up transient
    assert np.max(np.abs(c[late] / want[late] - 1)) < 0.012
    low, high = x_in < 0.2 * THRESHOLD, x_in > 100 * THRESHOLD
    assert np.allclose(c[late & low], x_in[late & low], rtol=0.05)
    slope = np.polyfit(np.log(x_in[late & high]), np.log(c[late & high]), 1)[0]
    assert slope == pytest.approx(1 / 3, abs=0.01)
