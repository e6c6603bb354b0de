"""Mass-spring feature extraction: the in-kernel Gram reduction against
`springc.kws.features.phi` on recorded trajectories (to round-off), the delay lines' delays from
the linearised network, and the simulated features against the digital realisation."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import chirp

from springc.lang import physics
from springc.errors import UsageError
from springc.lang.ir import IRBuilder, Source, Tran
from springc.kws.features import massspring as msp
from springc.kws.features.digital import FeatureSettings, features
from springc.kws.features.phi import group_index, n_features, readout_weights
from springc.sim.reductions import gram_reduction
from springc.sim.simulate import simulate
from springc.check import check
from shared_cache import KERNELS

SMALL = msp.MassSpringSettings(bins=2, delays=2)


@pytest.fixture(autouse=True, scope="module")
def _kernel_cache():
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("SPRINGC_CACHE", str(KERNELS))
        yield


def word(seconds: float = 0.4, f0: float = 300.0, f1: float = 2500.0,
         amp: float = 0.3) -> np.ndarray:
    """A chirp under a smooth envelope at 16 kHz, a stand-in for a spoken word."""
    t = np.arange(int(seconds * 16000)) / 16000
    env = np.sin(np.pi * t / seconds) ** 2
    return amp * env * chirp(t, f0, seconds, f1, method="logarithmic")


def chain4():
    """Four masses in a damped chain, driven at the first by in(0)."""
    b = IRBuilder("gram test chain")
    for k, name in enumerate("abcd"):
        b.mass(f"M{name}", name, 1.0 + 0.3 * k, 3.0)
        b.spring(f"K{name}", name, 900.0 + 100 * k)
    for p, q in ("ab", "bc", "cd"):
        b.coupling(f"C{p}{q}", p, q, 300.0, 1.0)
    b.force("F", "a", Source("in", (), 0, None), 50.0)
    b.tran = Tran(1e-3, 0.6, None)
    return b.finish()


def phi_of_recorded(x: np.ndarray, h: float, tau: float, n: int, m: int) -> np.ndarray:
    """springc.kws.features.phi's definition on trajectories x (runs, n m, K+1) sampled every h."""
    q = readout_weights(x.shape[-1], h, tau)
    g = np.einsum("rkt,rlt->rkl", x * q, x)
    idx = group_index(n, m).ravel()
    return np.stack([np.bincount(idx, weights=gr.ravel(), minlength=n_features(n, m))
                     for gr in g])


def test_gram_reduction_equals_phi_on_recorded_trajectories():
    net = chain4()
    nodes = list("abcd")
    k, kk = np.triu_indices(4)
    red = gram_reduction(net, 0.3, [nodes[i] for i in k], [nodes[j] for j in kk],
                         group_index(2, 2)[k, kk], np.where(k == kk, 1.0, 2.0), label="phi")
    u = np.random.default_rng(3).normal(size=(3, 1, 600))
    res = simulate(check(net), u, substeps=2, outrate=2000.0, reductions=[red, "gram:0.3:a,c"],
                   probes=[f"x({n})" for n in nodes])
    x = np.stack([res.probes[f"x({n})"] for n in nodes], axis=1)
    want = phi_of_recorded(x, 5e-4, 0.3, 2, 2)
    np.testing.assert_allclose(res.reductions["phi"], want, rtol=1e-11, atol=0)
    q = readout_weights(x.shape[-1], 5e-4, 0.3)
    pairs = [(0, 0), (0, 2), (2, 2)]  # the string form: pairs k <= l of the listed nodes
    plain = np.stack([(q * x[:, i] * x[:, j]).sum(-1) for i, j in pairs], axis=1)
    np.testing.assert_allclose(res.reductions["gram:0.3:a,c"], plain, rtol=1e-11)


@pytest.mark.parametrize("spec", ["gram:x:a", "gram:1:", "gram:1:zz", "gram:-1:a"])
def test_bad_gram_specs_are_user_errors(spec):
    with pytest.raises(UsageError):
        simulate(check(chain4()), None, reductions=[spec], tstop=0.01)


def test_delay_lines_delay_by_multiples_of_td():
    """Linearised at rest, the terminal of line j lags the compressor node that drives the
    lines by latency + j td at low frequencies (phase slope), with unit gain (matched
    terminations, no reflection)."""
    s = msp.MassSpringSettings(bins=2, delays=3)
    net = msp.feature_network(s)
    k, b, m = physics.stiffness_matrix(net), physics.damping_matrix(net), np.diag(net.mass())
    force = np.zeros(net.n)
    force[net.node_index("lp0")] = 1.0

    def response(hz: float) -> np.ndarray:
        w = 2 * np.pi * hz
        x = np.linalg.solve(k - w * w * m + 1j * w * b, force)
        return np.array([x[net.node_index(msp.terminal(0, j))] for j in range(3)]) / \
            x[net.node_index("c0")]

    lo, hi = response(4.0), response(6.0)
    delay = -(np.unwrap(np.angle(hi)) - np.unwrap(np.angle(lo))) / (2 * np.pi * 2.0)
    np.testing.assert_allclose(delay - delay[0], [0.0, s.td, 2 * s.td], atol=0.01 * s.td)
    np.testing.assert_allclose(delay[0], s.latency(), rtol=0.05)
    np.testing.assert_allclose(np.abs(lo), 1.0, atol=0.01)


def test_simulated_phi_and_features_match_recorded_and_digital():
    """One simulation: Phi in the kernel equals phi of the recorded terminals to round-off, and
    the compressed features c_i follow the digital features (correlation, measured ~0.99)."""
    s = SMALL
    net = msp.feature_network(s)
    sig = np.stack([word(), word(f0=2500.0, f1=300.0, amp=0.6)])
    probes = [f"x({t})" for t in msp.terminals(s)] + [f"x(c{i})" for i in range(s.bins)]
    rate = msp.INPUT_RATE * msp.SUBSTEPS  # record every integration step
    res = simulate(check(net), sig[:, None, :], 16000.0, reductions=[msp.phi_reduction(net, s)],
                   probes=probes, outrate=rate, tstop=msp.horizon(s, 0.4))
    x = np.stack([res.probes[p] for p in probes[:4]], axis=1)
    want = phi_of_recorded(x, 1 / rate, s.tau, s.bins, s.delays)
    np.testing.assert_allclose(res.reductions["phi"], want, rtol=1e-10)
    cf = np.stack([res.probes[p][:, :: int(rate / 1000)] for p in probes[4:]], axis=1)  # 1 kHz
    d = features(sig, 16000, FeatureSettings(bins=2, delays=2))
    k = min(cf.shape[-1], d.shape[-1])
    for c in range(2):
        for i in range(2):
            if d[c, i, :k].max() > 0.05 * d[:, i].max():  # bins the chirp actually drives
                assert np.corrcoef(cf[c, i, :k], d[c, i, :k])[0, 1] > 0.95


def test_the_filters_stay_linear_and_the_compressor_within_the_step():
    """The squarer's cubic stiffness on a filter at full scale is under 0.5% of the filter's
    own (no detuning); the compressor's fastest mode at full scale stays within STABLE_WH /
    h, at 5x the low-pass cut-off or more at rest (quasi-static)."""
    s = msp.MassSpringSettings(bins=8, delays=3)
    wa = 2 * np.pi * np.array([f.fa for f in msp.filters(s)])
    cubic = 6 * s.g / msp.leverages(s) * msp.FULL_SCALE**2
    assert np.all(cubic / wa**2 < 0.005)
    duffing, mass = msp.compressor_duffing(s), msp.compressor_mass(s)
    c = msp.compressed(2 * msp.envelope(s, msp.FULL_SCALE), s.kq, duffing)
    h = 1 / (msp.INPUT_RATE * msp.SUBSTEPS)
    assert np.all(np.sqrt((s.kq + 3 * duffing * c**2) / mass) * h <= msp.STABLE_WH * (1 + 1e-9))
    assert np.all(np.sqrt(s.kq / mass) >= 2 * np.pi * 4.5 * s.fc)


def test_the_compressor_threshold_is_the_envelope_of_a_threshold_tone():
    """At the envelope of a tone of amplitude A_c the compressor gives 0.68 of its input
    (kq c + l c^3 = kq e with l = kq / e^2: c = 0.682 e); 1000x above, the cube root."""
    s = msp.MassSpringSettings(bins=4, delays=2)
    duffing = msp.compressor_duffing(s)
    e = msp.envelope(s, s.threshold)
    np.testing.assert_allclose(msp.compressed(e, s.kq, duffing) / e, 0.6823278, rtol=1e-6)
    big = msp.compressed(1e3 * e, s.kq, duffing)
    np.testing.assert_allclose(big, np.cbrt(1e3) * e * (1 - 0.0033), rtol=2e-3)


def test_settings_that_overload_the_lowpass_are_rejected():
    with pytest.raises(UsageError, match="overload the low-pass"):
        msp.MassSpringSettings(bins=2, delays=3, kc=200.0).validate()
    with pytest.raises(UsageError, match="two-mode"):
        msp.MassSpringSettings(filterbank="triangular").validate()
