"""springc/design/summer.py and netlists/lib/summer.spr: a weighted sum by springs, against
the potential it is made of, under fabrication spread beside the zero-mode multiplier, and in
time below its resonance."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner
from springc_cli.main import main

from springc.check import check
from springc.design.mvm import design_mvm, mvm_text
from springc.design.summer import design_summer, summer_text
from springc.kws.evaluation.device import Spread, fabricate
from springc.lang import load_text
from springc.lang.physics import stiffness_matrix
from springc.sim.simulate import simulate

WEIGHTS = np.array([0.7, -1.3, 0.25, -0.05, 2.0])


def netlist(text: str, name: str, n: int, outputs: list[str]) -> str:
    """`text`'s subcircuit on inputs i0.. (each a unit mass) and its outputs."""
    ins = [f"i{p}" for p in range(n)]
    body = "".join(f"M{p} i{p} m=1\n" for p in range(n))
    return text + "\n" + body + f"X1 {' '.join(ins + outputs)} {name}\n"


def static_gains(net, inputs: list[str], outputs: list[str]) -> np.ndarray:
    """d(outputs)/d(inputs) with the inputs held: -K_oo^-1 K_oi of the stiffness matrix."""
    k = stiffness_matrix(net)
    i = [net.node_index(n) for n in inputs]
    o = [net.node_index(n) for n in outputs]
    return -np.linalg.solve(k[np.ix_(o, o)], k[np.ix_(o, i)])


def test_the_output_is_the_weighted_mean_of_the_inputs() -> None:
    """y = sum w x / sum |w| from the stiffness matrix of the written netlist (rounding)."""
    s = design_summer(WEIGHTS, kappa=3.0, resonance_hz=200.0)
    net = load_text(netlist(summer_text(s), "summer", 5, ["y"]))
    gains = static_gains(net, [f"i{p}" for p in range(5)], ["y"])
    np.testing.assert_allclose(gains[0], WEIGHTS / np.abs(WEIGHTS).sum(), rtol=1e-12)
    assert s.stiffness == pytest.approx(3.0 * np.abs(WEIGHTS).sum(), rel=1e-15)
    assert np.sqrt(s.stiffness / s.m) / (2 * np.pi) == pytest.approx(200.0, rel=1e-12)


def input_stiffness(net, inputs: list[str]) -> np.ndarray:
    """The stiffness a block presents to the nodes it reads: the Schur complement of the
    stiffness matrix on `inputs`, the block's own nodes free (the unit input masses hold
    no spring of their own)."""
    k = stiffness_matrix(net)
    i = [net.node_index(n) for n in inputs]
    o = [p for p in range(net.n) if p not in i]
    return k[np.ix_(i, i)] - k[np.ix_(i, o)] @ np.linalg.solve(k[np.ix_(o, o)], k[np.ix_(o, i)])


def test_spread_moves_the_sum_at_first_order_and_the_zero_mode_mvm_by_its_size() -> None:
    """Every coefficient times its own gauss(1, 1e-3) (springc eval --mc's local spread).
    The sum: its gains move by about 1e-3 of themselves, and what it presents to its inputs
    stays a positive semidefinite stiffness of order kappa (every element is a potential of
    its own). The zero-mode multiplier (Q orthogonal, d = 1000 kc, its excess diagonal taken
    back by negative monomials): its inputs are the zero modes, free (stiffness 0) by
    cancellation, and spread leaves them a stiffness of about 1e-3 d of either sign, so that
    a device reads its inputs through a spring of that size, or runs away."""
    spread = Spread(1e-3, seed=4)
    s = design_summer(WEIGHTS, kappa=1.0, resonance_hz=200.0)
    net = load_text(netlist(summer_text(s), "summer", 5, ["y"]))
    ins = [f"i{p}" for p in range(5)]
    nominal = static_gains(net, ins, ["y"])
    devices = [fabricate(net, spread, k) for k in range(8)]
    worst = max(np.abs(static_gains(d, ins, ["y"]) - nominal).max() for d in devices)
    assert worst < 5e-3 * np.abs(nominal).max()
    lowest = min(np.linalg.eigvalsh(input_stiffness(d, ins)).min() for d in devices)
    assert lowest > -1e-12 * s.kappa
    q = np.linalg.qr(np.random.default_rng(1).standard_normal((5, 5)))[0]
    d = 1000 * 10.0
    mvm = load_text(netlist(mvm_text(design_mvm(q, m=1e-3, kc=10.0)), "mvm", 5,
                            [f"o{p}" for p in range(5)]))
    np.testing.assert_allclose(static_gains(mvm, ins, [f"o{p}" for p in range(5)]), q,
                               atol=1e-9)
    assert np.abs(input_stiffness(mvm, ins)).max() < 1e-9 * d  # zero modes
    leaks = [np.linalg.eigvalsh(input_stiffness(fabricate(mvm, spread, k), ins))
             for k in range(8)]
    assert max(np.abs(e).max() for e in leaks) > 1e-4 * d
    assert min(e.min() for e in leaks) < -1e-5 * d  # a negative stiffness: runs away


def test_below_its_resonance_the_sum_follows_in_time() -> None:
    """Inputs driven by sines at 5 Hz (their own springs and dampers make them critically
    damped at 32 Hz; the sum's 200 Hz resonance above both): y(t) is the weighted mean of
    the inputs' trajectories within the error of a second-order mode driven below its
    resonance, |1 - H| = |1 - 1 / (1 - r^2 + 2 i zeta r)| at r = 5/200 (the lag 2 zeta r =
    0.035 of the amplitude)."""
    s = design_summer(WEIGHTS[:2], kappa=1.0, resonance_hz=200.0)
    text = summer_text(s) + "".join(
        f"M{p} i{p} m=1 b=400\nK{p} i{p} k=4e4\nF{p} i{p} sin({4e4 * a:g} 5 {ph:g})\n"
        for p, (a, ph) in enumerate([(1.0, 0.0), (0.5, 1.0)]))
    text += "X1 i0 i1 y summer\n.probe x(i0) x(i1) x(y)\n.tran 0.1m 1\n"
    res = simulate(check(load_text(text)), method="rk4", substeps=2)
    x0, x1, y = (res.probes[k][0] for k in ("x(i0)", "x(i1)", "x(y)"))
    want = (WEIGHTS[0] * x0 + WEIGHTS[1] * x1) / np.abs(WEIGHTS[:2]).sum()
    late = res.t > 0.2  # past the start's transient
    r = 5 / 200
    lag = abs(1 - 1 / (1 - r**2 + 2j * 0.7 * r))
    assert np.max(np.abs(y - want)[late]) < 1.1 * lag * np.max(np.abs(want))


def test_the_library_block_is_the_designed_sum(tmp_path) -> None:
    """summer2 of netlists/lib/summer.spr elaborates to the elements `springc design summer`
    writes for the same two weights."""
    lib = load_text('.include "summer.spr"\nM0 a m=1\nM1 b m=1\n'
                    "X1 a b y summer2 w0=0.7 w1=-1.3 kappa=2 m=1e-6 b=1e-3\n")
    s = design_summer([0.7, -1.3], kappa=2.0, resonance_hz=100.0)
    np.testing.assert_allclose(static_gains(lib, ["a", "b"], ["y"])[0], s.gains, rtol=1e-12)
    out = tmp_path / "s.spr"
    res = CliRunner().invoke(main, ["design", "summer", "--weights", "0.7,-1.3", "--kappa", "2",
                                    "-o", str(out)])
    assert res.exit_code == 0, res.output
    written = load_text(netlist(out.read_text(), "summer", 2, ["y"]))
    np.testing.assert_allclose(static_gains(written, ["i0", "i1"], ["y"])[0], s.gains,
                               rtol=1e-12)
    bad = CliRunner().invoke(main, ["design", "summer", "--weights", "0,0", "-o", str(out)])
    assert bad.exit_code == 1 and "not all zero" in bad.output
