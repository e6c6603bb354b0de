"""springc.kernels.expint: driven linear blocks integrated exactly (strang-rk4, exp-rk4,
exp-heun3)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import filter_refs
from filter_refs import filter_net as _filter_net
from reference_nets import rel_error
from springc.bench import networks as bn
from springc.bench import suite as benchsuite
from springc.kernels import expint
from springc.lang import physics
from springc.lang.ir import IRBuilder, Tran
from springc.errors import UsageError
from springc.sim.simulate import simulate
from springc.check import check


def test_propagator_is_the_exact_flow_for_linear_input():
    rng = np.random.default_rng(3)
    a = rng.standard_normal((4, 4)) - 2 * np.eye(4)
    b = rng.standard_normal((4, 2))
    tau, z0, u0, u1 = 0.3, rng.standard_normal(4), rng.standard_normal(2), rng.standard_normal(2)
    e, p0, p1 = expint.propagator(a, b, tau)
    sol = solve_ivp(lambda t, z: a @ z + b @ (u0 + (u1 - u0) * t / tau), (0, tau), z0,
                    method="DOP853", rtol=1e-12, atol=1e-14)
    assert np.allclose(e @ z0 + p0 @ u0 + p1 @ u1, sol.y[:, -1], rtol=1e-10, atol=1e-12)


def test_blocks_of_the_feature_extractor_are_its_filter_pairs():
    net = benchsuite.feature_extractor(bands=4)
    blocks = expint.find_blocks(net)
    assert len(blocks) == 4
    assert sorted(net.nodes[i] for i in blocks.nodes[0]) == ["f0a", "f0b"]
    # the Duffing resonator (sine source, cubic term) and a delay line (large) have none
    assert len(expint.find_blocks(bn.duffing_resonator())) == 0
    assert len(expint.find_blocks(bn.long_delay_line(sites=20))) == 0


def test_split_is_a_partition_of_the_forces():
    """Full acceleration = Runge-Kutta part (split netlist) + blocks' A z + B u."""
    net = benchsuite.feature_extractor(bands=3)
    blocks = expint.find_blocks(net)
    rest = expint.split_netlist(net, blocks)
    rng = np.random.default_rng(0)
    x, v, u = rng.standard_normal(net.n), rng.standard_normal(net.n), 0.7
    fext = np.zeros(net.n)
    np.add.at(fext, net.forces.node, net.forces.gain * u)
    rext = np.zeros(net.n)
    np.add.at(rext, rest.forces.node, rest.forces.gain * u)

    def accel(n, f):
        return (physics.internal_force(n, x) + physics.damping_force(n, v) + f) / n.mass()

    full, part = accel(net, fext), accel(rest, rext)
    for nodes, a, b in zip(blocks.nodes, blocks.a, blocks.b):
        m = len(nodes)
        z = np.concatenate([x[nodes], v[nodes]])
        part[nodes] += (a @ z + b @ np.full(b.shape[1], u))[m:]
    assert np.allclose(part, full, rtol=1e-12, atol=1e-9 * np.abs(full).max())


# The reductions every simulation asks for (of the linear filter, of the low-pass network),
# whether its test reads them or not, and the linear filter's dormant low-pass
# (`_linear_filter`): one kernel per method serves every test (a kernel's text depends on
# the term kinds and on whether it sums work and dissipation, not on the coefficients).
LINEAR = ["work:in", "dissipated:all", "energy"]
POWER = ["work:in", "dissipated:all", "dissipated:Mlp", "loss:Mlp", "energy"]


def _linear_filter(fa: float):
    """`filter_net(fa, lowpass=False)` (the same filter, input and first probe) with the
    low-pass of `lowpass=True` attached by a quadratic coupling of strength 0: the filter's
    equations are unchanged, the low-pass stays at rest, and the network has the low-pass
    network's term kinds, so the two share each method's kernel."""
    b = IRBuilder("one band, dormant low-pass", "<test>")
    out = bn.filter_pair(b, "f", fa)
    b.probe("x", out)
    wl = 2 * np.pi * 30.0
    b.mass("Mlp", "lp", 1.0, 1.4 * wl)
    b.spring("Klp", "lp", wl**2)
    b.quad("Qlp", out, "lp", 0.0)
    b.probe("x", "lp")
    b.tran = Tran(1 / filter_refs.RATE, filter_refs.SECONDS, None)
    return b.finish(), _filter_net(fa, lowpass=False)[1]


@pytest.mark.parametrize("method", ["exp-rk4", "exp-heun3"])
def test_lawson_schemes_are_exact_for_a_driven_linear_filter(method):
    """An 8 kHz, Q 126 filter pair at 32 kHz: RK4 is far off, the Lawson schemes match
    DOP853 (the low-pass is coupled with strength 0: no stage sees a force of the rest)."""
    net, u = _linear_filter(8000.0)
    ref = filter_refs.load("filter_8000")  # DOP853 at rtol 1e-11
    label = net.probes[0].label
    exp = simulate(check(net), u, method=method, reductions=LINEAR).probes[label]
    rk4 = simulate(check(net), u, method="rk4", reductions=LINEAR).probes[label]
    assert rel_error(exp[0], ref[label][0]) < 1e-8
    assert rel_error(rk4[0], ref[label][0]) > 0.3


def test_exp_rk4_with_quadratic_back_action_meets_1e3_where_rk4_fails():
    net, u = _filter_net(7500.0, lowpass=True)
    ref = simulate(check(net), u[:1], method="rk4", substeps=32, reductions=POWER).probes
    err = {}
    for method in ("rk4", "strang-rk4", "exp-rk4", "exp-heun3"):
        power = [] if method == "strang-rk4" else POWER  # Strang sums no work
        got = simulate(check(net), u[:1], method=method, reductions=power).probes
        err[method] = max(rel_error(got[k][0], ref[k][0]) for k in ref)
    assert err["exp-rk4"] < 1e-3 and err["exp-heun3"] < 1e-3
    assert err["rk4"] > 0.1
    # freezing the filter over the step aliases its square into the low-pass: worse
    assert err["strang-rk4"] > 2 * err["exp-rk4"]


def test_exp_heun3_converges_at_third_order_or_better():
    """The filter with its squared output low-passed (quadratic back-action on the block):
    against DOP853, halving the step divides exp-heun3's error by at least 2^2.5 (Heun3 is
    third order; wrong flow fractions or weights would leave an O(h) error or none at all
    converging), measured 2^5.1 and 2^4.5."""
    net, u = _filter_net(7500.0, lowpass=True)
    ref = filter_refs.load("filter_7500_lowpass")  # DOP853 at rtol 1e-12
    err = []
    for sub in (1, 2, 4):
        got = simulate(check(net), u[:1], method="exp-heun3", substeps=sub,
                       reductions=POWER).probes
        err.append(max(rel_error(got[k][0], ref[k][0]) for k in ref))
    assert err[0] < 1e-3
    assert np.log2(err[0] / err[1]) > 2.5 and np.log2(err[1] / err[2]) > 2.5


def test_strang_splitting_refuses_work_reductions():
    net, u = _filter_net(1000.0, lowpass=False)
    with pytest.raises(UsageError, match="work"):
        simulate(check(net), u, method="strang-rk4", reductions=["work:in"])



@pytest.mark.parametrize("method", ["exp-rk4", "exp-heun3"])
def test_lawson_work_and_dissipation_converge_to_fine_rk4(method):
    """Input work and dissipation, in the block (the filter's dampers) and in the rest (the
    low-pass), summed by a Lawson kernel converge to RK4 at 32 substeps. The blocks' flow is
    exact, the power's quadrature (the tableau's weights on the stage values) is not: at one
    substep the 7.5 kHz filter's power is sampled at 32 kHz and the work is 5e-3 off
    (measured, both schemes); each halving of the step divides that by 16 (exp-rk4) or 8."""
    net, u = _filter_net(7500.0, lowpass=True)
    ref = simulate(check(net), u[:1], method="rk4", substeps=32, reductions=POWER).reductions
    err = []
    for sub in (1, 2, 4):
        got = simulate(check(net), u[:1], method=method, substeps=sub, reductions=POWER)
        err.append({k: abs(got.reductions[k][0] / ref[k][0] - 1) for k in POWER})
    assert max(err[1].values()) < 1e-3
    assert err[0]["work:in"] > 2**2.5 * err[1]["work:in"] > 2**5 * err[2]["work:in"]


def test_lawson_work_balances_dissipation_and_energy():
    """A driven damped linear filter, integrated exactly: the input work equals the energy
    dissipated plus the energy left at the end (starting from rest), up to the quadrature of
    the power, 2.5e-4 of the work at one substep (3 kHz at 32 kHz) and 16 times less per
    halving of the step."""
    net, u = _linear_filter(3000.0)
    off = []
    for sub in (1, 4):
        r = simulate(check(net), u, method="exp-rk4", substeps=sub, reductions=LINEAR).reductions
        off.append(np.abs(r["work:in"] - r["dissipated:all"] - r["energy"]) / r["work:in"])
    assert np.all(off[0] < 1e-3) and np.all(off[1] < 1e-5)
    assert np.all(off[1] < off[0] / 100)
