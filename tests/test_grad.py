"""springc.grad: adjoint gradients against central finite differences of `simulate`, a closed
form, and the parameter -> coefficient Jacobian against differences of elaboration."""

from __future__ import annotations

import numpy as np
import pytest
import soundfile as sf
from reference_nets import every_kind_netlist

from springc.check import check
from springc.errors import UsageError
from springc.grad import ParamNetlist, gradient
from springc.grad.params import coefficients
from springc.sim.simulate import simulate

RTOL = 1e-6  # the bar for agreement with finite differences (float64)

DUFFING = """
.param w0={2*pi} l0=4 bb=0.1 amp=0.8 xs=0.5 mass=1
M1 x m={mass} b={bb} x0={xs}
K1 x k={w0**2}
D1 x l={l0}
F1 x sin(1 1.2 {pi/2}) gain={amp}
.tran 10ms 2
"""

LEVER = """
.param g=0.7 lev=1.5 kc=3 ky=5 vy=0.2
M1 x m=1 b=0.05 x0=0.4
M2 y m=2 b=0.1 v0={vy}
K1 x k=20
K2 y k={ky}
Q1 x y g={g} a={lev}
C1 x y k={kc} a={lev}
.tran 10ms 2
"""

DASHPOTS = """
.param bd=0.3 bg=0.05 k1=12 amp=2
M1 x m=1
M2 y m=1.5 b=0.02
K1 x k={k1}
K2 y k=7
C1 x y k=2
B1 x y b={bd}
B2 y 0 b={bg}
F1 x gauss({1} 0.3 0.1) gain={amp}
.tran 10ms 2
"""

AUDIO = """
.param k0=4e5 kc=1e5 bb=40 gain=1e5 l0=1e9
Ma a m=1 b={bb}
Mb b m=1 b={bb/2}
Ka a k={k0}
Kb b k={2*k0}
Da a l={l0}
Cab a b k={kc}
Fa a in(0) gain={gain}
.tran {1/8000} 0.05
"""


def fd(pn: ParamNetlist, specs: list[str], name: str, inputs=None,
       rel: float = 1e-3) -> dict[str, np.ndarray]:
    """d spec / d name per run for each of `specs` (simulated together: one kernel serves
    them all): central differences with one Richardson step (error O(h^4))."""
    p = pn.values[name]
    h = rel * abs(p) if p else rel

    def at(value: float) -> dict[str, np.ndarray]:
        res = simulate(check(pn.netlist({name: value})), inputs, reductions=specs)
        return {s: np.asarray(res.reductions[s], np.float64) for s in specs}

    hi, lo, hi2, lo2 = at(p + h), at(p - h), at(p + h / 2), at(p - h / 2)
    out = {}
    for s in specs:
        d1 = (hi[s] - lo[s]) / (2 * h)
        d2 = (hi2[s] - lo2[s]) / h
        out[s] = (4 * d2 - d1) / 3
    return out


def only(specs: list[str], spec: str, weight=1.0) -> dict:
    """Weights that pick `spec` out of `specs` (the others weigh 0): the gradient of one
    reduction from the adjoint kernel of them all."""
    return {s: weight if s == spec else 0.0 for s in specs}


def assert_matches_fd(src: str, specs: list[str], wrt: list[str], inputs=None,
                      also: tuple[str, ...] = ()) -> None:
    """Each of `specs`: its value as `simulate`'s, its gradient as finite differences. The
    reductions of `also` are computed beside them (weight 0), for other tests' kernels."""
    pn = ParamNetlist.from_text(src)
    every = [*specs, *also]
    sim = simulate(check(pn.netlist()), inputs, reductions=every).reductions
    want = {name: fd(pn, every, name, inputs) for name in wrt}
    for spec in specs:
        res = gradient(pn, every, wrt, inputs, weights=only(every, spec))
        np.testing.assert_allclose(res.values[spec], sim[spec], rtol=1e-10, err_msg=spec)
        for k, name in enumerate(wrt):
            scale = np.max(np.abs(res.grad)) + 1e-300
            np.testing.assert_allclose(res.grad[:, k], want[name][spec].reshape(-1), rtol=RTOL,
                                       atol=1e-9 * scale, err_msg=f"{spec} d/d{name}")


# the reductions each network's tests ask for, all in every call: one simulator kernel and
# one adjoint kernel per network (the adjoint's text depends on the dampers summed)
DUFFING_SPECS = ["final:x(x)", "final:v(x)", "msq:x(x)", "msq:v(x):0.5:1.5", "work:in",
                 "dissipated:all"]
LEVER_SPECS = ["final:x(y)", "msq:x(x)", "dissipated:M2"]
GRAM = "gram:0.5:x,y"
DASHPOTS_SPECS = ["work:in", "dissipated:all", "dissipated:B1", "loss:all", "final:v(y)"]


def test_every_kind_and_pair_of_kinds_matches_finite_differences():
    """Each kind's force and the transpose of its Jacobian are rendered from its description
    (`springc.grad.render`): a kind added to `terms.ELEMENTS` joins this network
    (`reference_nets.every_kind_netlist`), and its gradient in the written-out adjoint is
    checked here against central differences of `simulate` for every coefficient (the
    element loops against the written-out adjoint on the same network: test_grad_written)."""
    from springc.grad import written
    from springc.kernels import codegen, lower, terms

    src, wrt = every_kind_netlist()
    specs = ["msq:x(h)", "work:in", "dissipated:all", "final:v(s0)", "final:v(s1)",
             "final:v(s2)"]
    pn = ParamNetlist.from_text(src)
    net = check(pn.netlist()).net
    assert all(getattr(codegen.features(lower.kernel_netlist(net)), kind.feature)
               for kind in terms.KINDS)
    assert written.eligible(net)
    inputs = 0.4 * np.sin(np.arange(51) * 0.7)[None, None, :]
    want = {name: fd(pn, specs, name, inputs) for name in wrt}
    for spec in specs:
        res = gradient(pn, specs, wrt, inputs, weights=only(specs, spec))
        assert res.info["written"]
        scale = np.max(np.abs(res.grad)) + 1e-300
        for k, name in enumerate(wrt):
            np.testing.assert_allclose(res.grad[:, k], want[name][spec].reshape(-1),
                                       rtol=RTOL, atol=1e-9 * scale, err_msg=f"{spec} d/d{name}")


def test_duffing_matches_finite_differences():
    assert_matches_fd(DUFFING, DUFFING_SPECS, ["w0", "l0", "bb", "amp", "xs", "mass"])


def test_quadratic_coupling_with_leverage_matches_finite_differences():
    assert_matches_fd(LEVER, LEVER_SPECS, ["g", "lev", "kc", "ky", "vy"], also=(GRAM,))


def test_gram_reduction_matches_finite_differences():
    pn = ParamNetlist.from_text(LEVER)
    every, w = [*LEVER_SPECS, GRAM], np.array([1.0, -2.0, 0.5])
    res = gradient(pn, every, ["g", "lev"], weights=only(every, GRAM, list(w)))
    for k, name in enumerate(["g", "lev"]):
        want = fd(pn, every, name)[GRAM][0] @ w
        assert res.grad[0, k] == pytest.approx(want, rel=RTOL)


def test_dashpots_work_dissipation_and_loss_match_finite_differences():
    assert_matches_fd(DASHPOTS, DASHPOTS_SPECS, ["bd", "bg", "k1", "amp"])


def _wav(path, seconds: float, seed: int) -> str:
    rng = np.random.default_rng(seed)
    t = np.arange(int(8000 * seconds)) / 8000
    sig = 0.3 * np.sin(2 * np.pi * 110 * t) + 0.05 * rng.standard_normal(len(t))
    sf.write(path, sig, 8000, subtype="FLOAT")
    return str(path)


def test_audio_input_per_run_matches_finite_differences(tmp_path):
    inputs = [_wav(tmp_path / "a.wav", 0.05, 1), _wav(tmp_path / "b.wav", 0.04, 2)]
    assert_matches_fd(AUDIO, ["msq:x(b)", "work:in", "final:x(a)"],
                      ["k0", "kc", "bb", "gain", "l0"], inputs)


def test_linear_oscillator_under_a_step_matches_the_closed_form():
    """x(T) of m x'' + b x' + k x = F0 step: the closed form's derivative in k (complex
    step, exact for it) against the adjoint at a step fine enough that RK4's error is far
    below the tolerance."""
    m, b, f0, T = 1.0, 0.4, 2.0, 3.0
    src = f".param k=9\nM1 x m={m} b={b}\nK1 x k={{k}}\nF1 x step({f0} 0)\n.tran 1ms {T}\n"

    def closed(k):
        wn = np.sqrt(k / m)
        z = b / (2 * np.sqrt(k * m))
        wd = wn * np.sqrt(1 - z * z)
        return f0 / k * (1 - np.exp(-z * wn * T) * (np.cos(wd * T) + z * wn / wd
                                                    * np.sin(wd * T)))

    res = gradient(ParamNetlist.from_text(src), "final:x(x)", ["k"])
    assert res.values["final:x(x)"][0] == pytest.approx(closed(9.0), rel=1e-9)
    assert res.grad[0, 0] == pytest.approx(np.imag(closed(9.0 + 1e-30j)) / 1e-30, rel=1e-8)


def test_monomial_and_substeps_match_finite_differences():
    src = """
.param c=0.8 k=3
M1 x m=1 b=0.1 x0=0.7
M2 y m=1 b=0.1 v0=-0.5
K1 x k={k}
K2 y k=2
P1 c={c} x^2 y^2
P2 c={c/4} y^2
.options substeps=3 method=rk38
.tran 20ms 1.5
"""
    assert_matches_fd(src, ["final:x(y)", "msq:v(x)"], ["c", "k"])


def test_checkpointing_gives_the_same_gradient():
    """The sum of every reduction of the Duffing test (its kernel), in one segment and in
    segments of 7 steps."""
    pn = ParamNetlist.from_text(DUFFING)
    whole = gradient(pn, DUFFING_SPECS, ["w0", "l0"])
    parts = gradient(pn, DUFFING_SPECS, ["w0", "l0"], every=7)
    assert whole.info["every"] == 200 and parts.info["every"] == 7
    np.testing.assert_allclose(parts.grad, whole.grad, rtol=1e-12)


def test_several_reductions_sum_with_their_weights():
    """Two reductions weighted in one call (work:in at the default weight 1, the others
    of the dashpot test's reductions at 0: its kernels, not a compile of their own) against
    each alone."""
    pn = ParamNetlist.from_text(DASHPOTS)
    both = gradient(pn, DASHPOTS_SPECS, ["bd"],
                    weights={"dissipated:all": -2.0, "dissipated:B1": 0.0, "loss:all": 0.0,
                             "final:v(y)": 0.0})
    alone = [gradient(pn, DASHPOTS_SPECS, ["bd"], weights=only(DASHPOTS_SPECS, s)).grad
             for s in ("work:in", "dissipated:all")]
    one = alone[0] - 2 * alone[1]
    np.testing.assert_allclose(both.grad, one, rtol=1e-12)


def test_jacobian_of_coefficients_matches_elaboration_differences():
    src = """
.param p=1.3 q=0.4
.param r={sqrt(p)*exp(q)+log(p)/log10(3)+min(p,q,2)+max(p*q,0.1)*abs(-q)+tan(q)+cos(p)}
.subckt cell a kk=1 k2={kk**2.5}
K1 a k={k2}
.ends
M1 x m={1/p} b={q**p} x0={sin(p)}
K1 x k={r}
M2 y m=1
C1 x y k={p*q} a={p/q}
X1 y cell kk={p+q}
.for i 1 2
K{i}0 y k={i*p}
.endfor
"""
    pn = ParamNetlist.from_text(src)
    at = {"q": 0.5}  # away from the file's values: set values and their companions
    jac = pn.jacobian(at, ["p", "q"])
    for name in ("p", "q"):
        v, h = {**pn.values, **at}[name], 1e-4
        hi, lo = (coefficients(pn.netlist({**at, name: v + s * h})) for s in (1, -1))
        hi2, lo2 = (coefficients(pn.netlist({**at, name: v + s * h / 2})) for s in (1, -1))
        for key, got in jac[name].items():
            want = (4 * (hi2[key] - lo2[key]) / h - (hi[key] - lo[key]) / (2 * h)) / 3
            np.testing.assert_allclose(got, want, rtol=1e-8, atol=1e-9, err_msg=str(key))


def test_parameter_errors_are_user_errors():
    pn = ParamNetlist.from_text(DUFFING + ".param unused=3 sa=1\nF2 x sin({sa} 2)\n")
    with pytest.raises(UsageError, match="no top-level .param 'w1'.*"):
        gradient(pn, "final:x(x)", ["w1"])
    with pytest.raises(UsageError, match="no element coefficient depends on"):
        gradient(pn, "final:x(x)", ["unused"])
    with pytest.raises(UsageError, match="sets more than element coefficients"):
        gradient(pn, "final:x(x)", ["sa"])
    with pytest.raises(UsageError, match="bad reduction"):
        gradient(pn, "mean:x(x)", ["w0"])
    with pytest.raises(UsageError, match="--of energy: no gradient for this reduction"):
        gradient(pn, "energy", ["w0"])


def test_values_outside_the_legal_set_fail_the_checks():
    from springc.errors import CheckError

    with pytest.raises(CheckError, match="l=-1"):
        gradient(ParamNetlist.from_text(DUFFING), "final:x(x)", ["w0"], values={"l0": -1.0})


def test_runs_in_lanes_match_runs_alone(tmp_path, monkeypatch):
    """Five runs share lanes (two threads' worth: chunks of 2 lanes, the last one padded):
    each run's value and gradient as when it runs alone."""
    import importlib

    monkeypatch.setattr(importlib.import_module("springc.sim.execute"), "threads",
                        lambda: 2)
    # the lanes of springc.grad.adjoint's element loops, not the written-out kernels
    monkeypatch.setattr(importlib.import_module("springc.grad.written"), "eligible",
                        lambda net: False)
    inputs = [_wav(tmp_path / f"{k}.wav", 0.02, k) for k in range(5)]
    pn = ParamNetlist.from_text(AUDIO)
    together = gradient(pn, "msq:x(b)", ["k0", "bb", "gain"], inputs)
    assert together.info["lanes"] == 2
    for k, path in enumerate(inputs):
        alone = gradient(pn, "msq:x(b)", ["k0", "bb", "gain"], [path])
        assert alone.info["lanes"] == 1
        np.testing.assert_allclose(together.grad[k], alone.grad[0], rtol=1e-12)
        np.testing.assert_allclose(together.values["msq:x(b)"][k], alone.values["msq:x(b)"][0],
                                   rtol=1e-12)
