"""Register kernels (`springc.kernels.regkernel`): one run of a small network with its state in
scalars. The same trajectories as the shared kernel and as scipy; the same divergence guard;
which simulations get them."""

from __future__ import annotations

import numpy as np
import pytest
from reference_nets import RUNS, assert_matches_scipy, every_kind, inputs

from springc.bench import networks as bn, suite as benchsuite
from springc.kernels import codegen, regkernel, terms
from springc.sim import marshal
from springc.sim import execute
from springc.sim import simulate as sm
from springc.errors import SimulationError
from springc.lang.ir import IRBuilder, Source, Tran
from springc.bench.reference import solve_ivp_reference
from springc.check import check

FEW = 3  # runs: two threads of chunks of one run (lanes 1), one of them two chunks


def _kernel_text(res) -> str:
    return open(res.info["kernel"]).read()


@pytest.mark.parametrize("method", ["rk4", "rk38", "heun3"])
def test_register_kernel_gives_the_shared_kernels_trajectories(method):
    """Every force kind, three runs: within a few round-offs of the shared kernel (the same
    sums in the same order; FMA contraction may pair them differently)."""
    net, u = every_kind(), inputs()[:FEW]
    out = sm.simulate(check(net), u, method=method)
    ref = sm.simulate(check(net), u, method=method, write_out=False)
    assert "state in registers" in _kernel_text(out)
    assert "state in registers" not in _kernel_text(ref)
    for label, want in ref.probes.items():
        scale = np.abs(want).max()
        assert scale > 1e-6, label  # every node moves
        assert np.abs(out.probes[label] - want).max() <= 1e-12 * scale, (method, label)
    np.testing.assert_allclose(out.t, ref.t)


def test_register_kernel_matches_scipy():
    net, u = every_kind(), inputs(seed=1)[:FEW]
    res = sm.simulate(check(net), u, substeps=4)
    assert "state in registers" in _kernel_text(res)
    assert_matches_scipy(net, u, res)


def test_register_kernel_float32_agrees_with_float64():
    net, u = every_kind(), inputs(seed=2)[:1]
    lo = sm.simulate(check(net), u, precision="float32")
    hi = sm.simulate(check(net), u, precision="float64")
    assert "state in registers" in _kernel_text(lo)
    for label, want in hi.probes.items():
        err = np.linalg.norm(lo.probes[label] - want) / np.linalg.norm(want)
        assert err < 1e-4, (label, err)


def test_hard_driven_duffing_against_dop853():
    """The bench's Duffing resonator (stiffness up tenfold at the peak): RK4 with two steps a
    sample within 1e-6 of DOP853 at rtol 1e-11, velocities recorded at half the rate. A sine
    drive and no input samples: no kinks for DOP853 to step over, its step control alone
    (no `max_step`) holds rtol."""
    net = bn.duffing_resonator(amp=benchsuite.DUFFING_HARD)
    kw = dict(tstep=net.tran.tstep, tstop=0.1)
    res = sm.simulate(check(net), None, substeps=2, probes=["x(a)", "v(a)"], outrate=5e3, **kw)
    assert "state in registers" in _kernel_text(res)
    probes = sm.resolve_probes(net, ["x(a)", "v(a)"])
    t, want, _ = solve_ivp_reference(net, None, probes=probes, method="DOP853",
                                     rtol=1e-11, atol=1e-14, max_step=np.inf, **kw)
    assert np.allclose(res.t, t[::2])
    for label in ("x(a)", "v(a)"):
        ref = want[label][0][::2]
        err = np.linalg.norm(res.probes[label][0] - ref) / np.linalg.norm(ref)
        assert err < 1e-6, (label, err)


@pytest.mark.parametrize("runs", [1, RUNS])
def test_register_kernel_stops_a_diverging_run_like_the_shared_kernel(runs):
    """Runs whose second mass is pushed beyond the limit: both kernels stop them at the same
    check with the same node named (one run: the state written back from its scalars; 8 runs:
    the lane loop's rows). The shared kernel at one lane a run for both (`chunk`): its lanes
    never change a run."""
    b = IRBuilder("runaway", "runaway.spr")
    b.mass("M1", "a", 1.0, 1.0)
    b.spring("K1", "a", 1e4)
    b.mass("M2", "b", 1.0, 0.0)
    b.force("F1", "b", Source("step", (1e31, 0.0)))
    b.probe("x", "a")
    b.tran = Tran(1e-3, 1.0, None)
    net = b.finish()
    u = np.zeros((runs, 1, 1001))
    msgs = []
    for write_out in (True, False):
        with pytest.raises(SimulationError) as err:
            sm.simulate(check(net), u, write_out=write_out, chunk=None if write_out else 1)
        msgs.append(err.value.message)
    assert "node b" in msgs[0] and msgs[0] == msgs[1]
    res = sm.simulate(check(net), u, write_out=True, tstop=0.05)  # before the guard stops it
    assert "state in registers" in _kernel_text(res)


def _opts(net, runs: int, **kw) -> codegen.KernelOptions:
    st = sm.settings(net, **{k: v for k, v in kw.items() if k == "method"})
    co = marshal.kernel_arrays(net, st, np.float64)
    opts = codegen.KernelOptions(st.method, lanes=codegen.choose_lanes(sm.task_runs(runs, None,
                                                                                     None)),
                                 msq=kw.get("msq", False))
    return sm.kernel_form(net, opts, co, st, runs, kw.get("write_out"))


def test_which_simulations_get_a_register_kernel(monkeypatch):
    """One run per chunk, a Runge-Kutta tableau, no reductions, no monomial terms, not asked
    for the shared kernel; a network beyond REGISTER_ALWAYS masses only where the force code
    would be written out (a long simulation, or asked for). The lanes are chosen as on two
    cores, whatever this machine has."""
    monkeypatch.setattr(execute, "threads", lambda: 2)
    net = every_kind()
    assert _opts(net, 1).registers is not None
    assert _opts(net, FEW).registers is not None
    assert _opts(net, RUNS).registers is None  # 4 runs a thread: 4 lanes, vector code
    assert _opts(net, 1, write_out=False).registers is None
    assert _opts(net, 1, method="exp-rk4").registers is None
    assert _opts(net, 1, msq=True).registers is None
    big = benchsuite.feature_extractor(bands=regkernel.REGISTER_ALWAYS // 3 + 1)
    assert big.n > regkernel.REGISTER_ALWAYS and _opts(big, 1).registers is None
    assert _opts(big, 1, write_out=True).registers is not None
    b = IRBuilder("monomial", "m.spr")
    b.mass("M1", "a", 1.0, 1.0)
    b.spring("K1", "a", 1.0)
    b.monomial("P1", 1.0, [("a", 4)])
    b.tran = Tran(1e-3, 0.01, None)
    assert _opts(b.finish(), 1).registers is None


def test_register_terms_of_every_kind():
    """Per node: damping, spring, stiffness row, inputs, quadratic couplings, Duffing terms,
    dashpot ends and shared signals, as indices into the coefficient arrays."""
    net = every_kind()
    co = marshal.coefficient_arrays(net, np.float64)
    a, b, c, d = terms.node_terms(co, net.n)
    assert a.damped and b.damped and not c.damped and not d.damped
    assert [j for _, j in a.row] == [1] and [j for _, j in b.row] == [0] and c.row == ()
    assert [ch for _, ch in c.ins] == [0, 0] and [ch for _, ch in b.ins] == [1]
    assert [(k, end, j) for k, _, end, j in c.ends] == [("quad", "j", 0), ("quad", "j", 1)]
    assert [(k, end, j) for k, _, end, j in b.ends] == [("quad", "i", 2), ("dashpot", "i", 3)]
    assert [(k, end, j) for k, _, end, j in d.ends] == [("duffing", "i", -1),
                                                        ("dashpot", "j", 1), ("common", "i", -1)]
    assert a.ends == (("quad", 0, "i", 2),)
    text = regkernel.generate(net, codegen.KernelOptions(lanes=1, registers=(a, b, c, d)))
    assert "for e in range" not in text  # no loop over index arrays
    assert "K3_3 = " in text and "- d_lm0 * (XA3 * XA3 * XA3)" in text
