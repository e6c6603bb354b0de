"""springc.grad.legal: every unconstrained vector maps to parameter values whose netlist
passes the checks (signs, potential, stable step)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from springc.check import check
from springc.errors import CheckError, UsageError
from springc.grad import ParamNetlist
from springc.grad.legal import Range, legal_map

# at spread 4 the corner k = 1.6e5, m = 0.25 puts the fastest mode at 800 rad/s, beyond
# RK4's limit of about 557 rad/s at a 5 ms step: the map must shrink to pass
NETLIST = """
.param k=4e4 m=1 b=2 lev=1.5 g=0.5 gain=3 off=0
M1 x m={m} b={b} x0={off}
M2 y m=1
K1 x k={k}
K2 y k=100
C1 x y k=50 a={lev}
Q1 x y g={g} a={lev}
F1 x sin(1 5) gain={gain}
.tran 5ms 1
"""
WRT = ["k", "m", "b", "lev", "g", "gain", "off"]


@pytest.fixture(scope="module")
def mapped():
    pn = ParamNetlist.from_text(NETLIST)
    return pn, legal_map(pn, WRT)


def test_the_unshrunk_box_would_fail():
    pn = ParamNetlist.from_text(NETLIST)
    with pytest.raises(CheckError, match="unstable|stable step|exceeds"):
        check(pn.netlist({"k": 1.6e5, "m": 0.25}), judge_step=True)


def test_random_unconstrained_vectors_give_netlists_that_pass_the_checks(mapped):
    pn, lm = mapped
    rng = np.random.default_rng(7)
    zs = [rng.normal(0.0, 3.0, len(WRT)) for _ in range(40)]
    zs += [np.full(len(WRT), 40.0), np.full(len(WRT), -40.0), rng.choice([-60.0, 60.0], 7)]
    for z in zs:
        values = lm.values(z)
        check(pn.netlist(values))  # raises CheckError on any failed check
        assert values["lev"] > 0 and values["m"] > 0 and values["b"] > 0


def test_the_box_keeps_signs_and_holds_the_start(mapped):
    pn, lm = mapped
    ranges = dict(zip(lm.names, lm.ranges))
    off = ranges["off"]  # a parameter at 0: a linear range through it
    assert not off.log and -1.0 <= off.lo < 0.0 < off.hi <= 1.0
    for name in WRT[:-1]:
        r = ranges[name]
        assert r.log and r.lo < pn.values[name] < r.hi and r.lo > 0
    assert ranges["k"].hi < 4 * 4e4  # shrunk: the spread-4 corner is unstable
    np.testing.assert_allclose(list(lm.values(lm.variables(pn.values)).values()),
                               [pn.values[n] for n in WRT], rtol=1e-12, atol=1e-15)


def test_chain_is_the_derivative_of_the_map(mapped):
    _, lm = mapped
    z = np.linspace(-2.0, 2.0, len(WRT))
    grad = np.arange(1.0, len(WRT) + 1)
    h = 1e-6
    fd = [(lm.values(z + h * e)[n] - lm.values(z - h * e)[n]) / (2 * h)
          for n, e in zip(WRT, np.eye(len(WRT)))]
    np.testing.assert_allclose(lm.chain(grad, z), grad * np.array(fd), rtol=1e-7)


def test_ranges_of_negative_parameters_stay_negative():
    r = Range(-8.0, -0.5, True)
    for z in (-50.0, -1.0, 0.0, 3.0, 50.0):
        assert -8.0 <= r.value(z) <= -0.5
    assert r.variable(r.value(0.3)) == pytest.approx(0.3)
    assert math.isfinite(r.value(800.0)) and math.isfinite(r.value(-800.0))


def test_an_illegal_start_or_bounds_are_user_errors():
    pn = ParamNetlist.from_text(NETLIST)
    with pytest.raises(UsageError, match="starting parameter values fail the checks"):
        legal_map(pn, ["k"], {"k": -1.0})
    with pytest.raises(UsageError, match="strictly inside"):
        legal_map(pn, ["k"], bounds={"k": (1e5, 2e5)})
    with pytest.raises(UsageError, match="no top-level .param"):
        legal_map(pn, ["kk"])
