"""Hard cases (issue 7): each is accurate against a reference or stopped by the divergence
guard with a clear message, never a silent wrong answer."""

from __future__ import annotations

import numpy as np
import pytest
from reference_nets import rel_error

from springc.check import accuracy
from springc.bench import suite as benchsuite
from springc.lang import physics
from springc.bench import networks as bn
from springc.errors import CheckError, SimulationError
from springc.lang.ir import IRBuilder, Source, Tran
from springc.bench.reference import solve_ivp_reference
from springc.sim.simulate import simulate
from springc.check import check

RATE = 32000.0


def test_stiff_all_to_all_block_is_stopped_with_the_substeps_it_needs():
    """8 masses joined pairwise by 5e9 constraint springs: fastest mode 2e5 rad/s, h omega =
    6.3 at 32 kHz (RK4 is stable to 2.8). The check refuses it before running and names the
    cure; past the check on purpose, the guard stops it and names the same cure; with those
    substeps, the run agrees with a 16x finer one."""
    net = benchsuite.stiff_block(nodes=8, k_constraint=5e9)
    u = benchsuite.speech_like(0.02, RATE, 1)
    with pytest.raises(CheckError, match="is unstable for rk4") as refused:
        check(net, "rk4")
    assert "substeps=3" in refused.value.format()
    checked = check(net, judge_step=False)
    with pytest.raises(SimulationError, match="diverged") as info:
        simulate(checked, u, tstop=0.02, check_step=False)
    assert "raise --substeps to at least 3" in info.value.format()
    got = simulate(checked, u, tstop=0.02, substeps=3).probes
    ref = simulate(checked, u, tstop=0.02, substeps=48).probes
    for label in ref:
        assert rel_error(got[label][0], ref[label][0]) < 2e-3


def test_delay_line_with_near_zero_local_stiffness():
    """A 100-site chain (grounding springs 1e-6 of the coupling): a pulse's peak arrives after
    sites x td (within 10%: dispersion delays the peak), and RK4 at two steps per site delay
    is within 1e-3 of a 16x finer run."""
    sites, td = 100, 1e-4
    net = bn.long_delay_line(sites=sites, td=td)
    rate = 1 / net.tran.tstep
    t = np.arange(round(net.tran.tstop * rate) + 1) / rate
    pulse = np.exp(-(((t - 10 * td) / (3 * td)) ** 2))[None, None, :]
    got = simulate(check(net), pulse)
    ref = simulate(check(net), pulse, substeps=16)
    end = net.probes[1].label
    assert rel_error(got.probes[end][0], ref.probes[end][0]) < 1e-3
    arrival = got.t[np.argmax(np.abs(got.probes[end][0]))] - 10 * td
    assert arrival == pytest.approx(sites * td, rel=0.1)


def test_overdamped_readout_q_001_matches_the_analytic_step_response():
    """Q = 0.01: eigenvalues -b and about -k/b, 1e4 apart; RK4 at 32 kHz follows the exact
    step response to 1e-7."""
    w = 2 * np.pi * 20.0
    k, bb, f = w**2, w / 0.01, 1e3
    b = IRBuilder("overdamped readout", "<test>")
    b.mass("M", "r", 1.0, bb)
    b.spring("K", "r", k)
    b.force("F", "r", Source("step", (f, 0.0)))
    b.probe("x", "r")
    b.tran = Tran(1 / RATE, 0.2, None)
    res = simulate(check(b.finish()))
    l1, l2 = np.roots([1.0, bb, k])
    exact = f / k * (1 - (l2 * np.exp(l1 * res.t) - l1 * np.exp(l2 * res.t)) / (l2 - l1))
    assert rel_error(res.probes["x(r)"][0], exact) < 1e-7


# The two driven references below have no input samples, so no kinks for DOP853 to step
# over: its step control alone (no `max_step`) holds rtol 1e-11, 1e-9 of the thresholds.


def test_duffing_driven_to_tenfold_stiffness():
    net = bn.duffing_resonator(amp=benchsuite.DUFFING_HARD)
    res = simulate(check(net))
    x = res.probes["x(a)"][0]
    peak = np.abs(x).max()
    at_peak = physics.stiffness_matrix(net, np.array([peak]))[0, 0]
    grow = at_peak / physics.stiffness_matrix(net)[0, 0]
    assert grow > 10
    _, ref, _ = solve_ivp_reference(net, None, tstep=net.tran.tstep, tstop=net.tran.tstop,
                                    rtol=1e-11, atol=1e-13, max_step=np.inf)
    assert rel_error(x, ref["x(a)"][0]) < 1e-4


def _quad_pair(amp: float) -> object:
    b = IRBuilder("quadratic coupling driven hard", "<test>")
    w0 = 2 * np.pi * 50.0
    b.mass("Ma", "a", 1.0, 2 * 0.02 * w0)
    b.spring("Ka", "a", w0**2)
    b.mass("Mb", "b", 1.0, 2 * np.pi * 20.0)
    b.spring("Kb", "b", (2 * np.pi * 20.0) ** 2)
    b.quad("Q", "a", "b", 6 * w0**2)
    b.force("F", "a", Source("sin", (amp, 50.0)))
    b.probe("x", "a")
    b.probe("x", "b")
    b.tran = Tran(1e-4, 0.3, None)
    return b.finish()


def test_quadratic_coupling_driven_to_tenfold_stiffness():
    """Driven to 11.6x its stiffness at rest, the pair is sensitive: RK4 at the .tran step
    (h omega_eff = 0.1) is 3% off; it converges at fourth order and meets 5e-5 at 8 substeps."""
    net = _quad_pair(3e4)
    _, ref, _ = solve_ivp_reference(net, None, tstep=net.tran.tstep, tstop=net.tran.tstop,
                                    rtol=1e-11, atol=1e-13, max_step=np.inf)
    err = {}
    for sub in (2, 4, 8):
        res = simulate(check(net), substeps=sub)
        err[sub] = max(rel_error(res.probes[k][0], ref[k][0]) for k in ref)
    xa, xb = res.probes["x(a)"][0], res.probes["x(b)"][0]
    k = np.argmax(np.abs(xa))
    grow = physics.stiffness_matrix(net, np.array([xa[k], xb[k]]))[0, 0] / \
        physics.stiffness_matrix(net)[0, 0]
    assert grow > 10
    assert err[2] / err[4] > 10 and err[4] / err[8] > 10  # fourth order: 16 per halving
    assert err[8] < 5e-5


def _undamped(f0: float, seconds: float, driven: bool):
    b = IRBuilder("undamped oscillator", "<test>")
    b.mass("M", "a", 1.0, 0.0, x0=1e-3)
    b.spring("K", "a", (2 * np.pi * f0) ** 2)
    if driven:  # an in(0) force makes it a block of the split schemes (fed zeros here)
        b.force("F", "a", Source("in", channel=0), 1.0)
    b.probe("x", "a")
    b.tran = Tran(1 / RATE, seconds, None)
    return b.finish()


def test_long_undamped_run_energy_drift():
    """10 s (320000 steps) of an undamped 1 kHz oscillator: RK4's energy decays exactly as
    |R(i theta)|^(2N) predicts (25%); exp-rk4 keeps it to round-off."""
    seconds = 10.0
    net = _undamped(1000.0, seconds, driven=True)
    zeros = np.zeros((1, 1, int(seconds * RATE) + 1))
    e0 = physics.energy(net, *net.initial_state())
    rk4 = simulate(check(net), zeros, reductions=["energy"], probes=[]).reductions["energy"][0]
    theta = 2 * np.pi * 1000.0 / RATE
    steps = round(seconds * RATE)
    predicted = np.exp(2 * steps * accuracy.log_ratio("rk4", [1j * theta])[0].real)
    assert rk4 / e0 == pytest.approx(predicted, rel=1e-6)
    assert 0.7 < rk4 / e0 < 0.8
    exp = simulate(check(net), zeros, method="exp-rk4", reductions=["energy"],
                   probes=[]).reductions["energy"][0]
    assert abs(exp / e0 - 1) < 1e-9
