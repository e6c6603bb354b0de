"""springc.sim.stepcheck: step doubling catches the error the linear estimate cannot see."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner
from springc_cli.main import main as cli

import filter_refs
from filter_refs import RATE
from filter_refs import filter_net as _filter_net
from reference_nets import TWOMODE, rel_error

from springc.check import accuracy
from springc.sim import stepcheck
from springc.errors import UsageError
from springc.lang import load_file
from springc.sim.simulate import simulate
from springc.check import check

TOL = 1e-4


def test_step_doubling_raises_the_substeps_until_the_true_error_meets_the_tolerance():
    """A 7.5 kHz filter squared into a low-pass: the linear estimate calls exp-heun3 at one
    step per sample good for 1e-4 (the filter is exact, the low-pass slow), but the squared
    signal's coupling is off by about 4e-4 against DOP853. Step doubling moves to the
    substeps whose true error meets the tolerance, and estimates it within a factor 3."""
    net, u = _filter_net(7500.0, lowpass=True)
    linear = accuracy.choose(net, 1 / RATE, 0.05, TOL)
    assert linear.substeps == 1 and linear.error < TOL
    got = stepcheck.verify(check(net), linear, 1 / RATE, 0.05, TOL, u[:1])
    ref = filter_refs.load("filter_7500_lowpass")  # DOP853 at rtol 1e-12

    def true_error(sub: int) -> float:
        out = simulate(check(net), u[:1], method=got.method, substeps=sub).probes
        return max(rel_error(out[k][0], ref[k][0]) for k in ref)

    assert true_error(linear.substeps) > TOL
    assert got.substeps > linear.substeps and got.linear_substeps == linear.substeps
    assert true_error(got.substeps) <= TOL
    assert got.pilot_error <= TOL and got.pilot_s == pytest.approx(0.05)
    assert true_error(got.substeps) / 3 < got.pilot_error < 3 * true_error(got.substeps)
    assert "step doubling over the first 0.05 s" in got.describe()


def test_doubling_error_is_the_coarse_runs_error_for_a_known_order():
    """exp-rk4 (order 4): (y(s) - y(2s)) / (1 - 1/16) against the error of y(s) itself."""
    net, u = _filter_net(7500.0, lowpass=True)
    ref = simulate(check(net), u[:1], method="exp-rk4", substeps=64).probes
    coarse = simulate(check(net), u[:1], method="exp-rk4", substeps=2).probes
    true = max(rel_error(coarse[k][0], ref[k][0]) for k in ref)
    est = stepcheck.doubling_error(check(net), "exp-rk4", 2, 1 / RATE, u[:1], 0.05)
    assert est == pytest.approx(true, rel=0.1)


def test_linear_netlists_keep_the_linear_choice():
    net = load_file(TWOMODE)
    choice = accuracy.choose(net, net.tran.tstep, 0.01, 1e-3)
    assert not accuracy.nonlinear(net)
    assert stepcheck.verify(check(net), choice, net.tran.tstep, 0.01, 1e-3) is choice


def test_a_tolerance_below_round_off_is_a_user_error():
    net, u = _filter_net(7500.0, lowpass=True)
    linear = accuracy.choose(net, 1 / RATE, 0.05, 1e-9)
    with pytest.raises(UsageError, match="does not meet tolerance 1e-15"):
        stepcheck.verify(check(net), linear, 1 / RATE, 0.05, 1e-15, u[:1])


def test_sim_tolerance_reports_the_step_doubling_check(tmp_path):
    out = tmp_path / "out.npz"
    got = CliRunner().invoke(cli, ["sim", "netlists/examples/quadratic_readout.spr", "-o",
                                   str(out), "--tstop", "0.2", "--tolerance", "1e-4"])
    assert got.exit_code == 0, got.output
    assert "on the nonlinear terms, step doubling over the first 0.1 s" in got.output
    assert out.exists() and np.load(out)["t"].size > 0
