"""The numpy and scipy peers agree with physics and with each other."""

from __future__ import annotations

import numpy as np
import pytest

from springc.lang import physics
from springc.lang.ir import IRBuilder, Source, Tran
from springc.bench.reference import Equations, forcing, rk4_numpy, solve_ivp_reference
from reference_nets import nonlinear_net


def oscillator(w0: float = 20.0, b: float = 2.0):
    bld = IRBuilder("free oscillator")
    bld.mass("M1", "a", 1.0, b, x0=1.0)
    bld.spring("K1", "a", w0**2)
    bld.force("F1", "a", Source("in"), 3.0)
    bld.probe("x", "a")
    bld.tran = Tran(1e-3, 1.0, None)
    return bld.finish()


def free_decay(t: np.ndarray, w0: float = 20.0, b: float = 2.0) -> np.ndarray:
    wd = np.sqrt(w0**2 - b**2 / 4)
    return np.exp(-b * t / 2) * (np.cos(wd * t) + b / (2 * wd) * np.sin(wd * t))


def test_rk4_numpy_free_decay_matches_analytic_with_fourth_order_error():
    errs = []
    for tstep in (2e-3, 1e-3):
        t, probes, _ = rk4_numpy(oscillator(), tstep=tstep, tstop=1.0)
        errs.append(np.abs(probes["x(a)"][0] - free_decay(t)).max())
    assert abs(errs[0] / errs[1] - 16) < 1.0
    assert errs[1] < 1e-7


def test_solve_ivp_matches_analytic_and_numpy_rk4_with_input():
    net = oscillator()
    t, ref, _ = solve_ivp_reference(net, tstep=1e-3, tstop=1.0)
    assert np.abs(ref["x(a)"][0] - free_decay(t)).max() < 1e-9
    u = np.random.default_rng(0).standard_normal((2, 1, 301))
    _, ivp, _ = solve_ivp_reference(net, u[1:], tstep=1e-3, tstop=0.3)
    _, rk, _ = rk4_numpy(net, u, tstep=1e-3, tstop=0.3, substeps=4)
    assert np.abs(rk["x(a)"][1] - ivp["x(a)"][0]).max() < 1e-7


def test_forcing_interpolates_inputs_linearly():
    net = oscillator()
    u = np.array([[[0.0, 1.0, 3.0]]])
    f = forcing(net, u, tstep=0.5)
    assert f(0.75)[0, 0] == 3.0 * 2.0 and f(2.0)[0, 0] == 0.0


@pytest.mark.parametrize("dense_max", [100, 0])  # small matrices dense, then all sparse
def test_assembled_equations_are_the_physics_functions(monkeypatch, dense_max):
    """Every term kind (test_simulate's nonlinear network): springs, a Duffing term, a
    leverage coupling, a quadratic coupling, dashpots between nodes and to ground, local
    dampers, a monomial."""
    monkeypatch.setattr(Equations, "DENSE_MAX", dense_max)
    net = nonlinear_net()
    rng = np.random.default_rng(3)
    x, v, fext = rng.normal(size=(3, net.n, 4))
    want = (physics.internal_force(net, x) + physics.damping_force(net, v) + fext) \
        / net.mass()[:, None]
    got = Equations(net)(x, v, fext)
    np.testing.assert_allclose(got, want, rtol=1e-13, atol=1e-13 * np.abs(want).max())
