"""Weight transfer: the head design obeys its equations, the classifier netlist passes the
compiler's checks, and the simulated network's readouts equal c . Phi (within 2% at a small
squaring error), scored exactly like the digital decisions."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import chirp

from springc.check import check
from springc.check.compiler import build
from springc.design.blocks import readout_params
from springc.errors import UsageError
from springc.kws.features import massspring as msp
from springc.kws.training import transfer as tr
from springc.kws.evaluation.evaluate import selection_models
from springc.kws.features.phi import n_features, spread
from springc.kws.training.report import score
from springc.kws.training.svm import LinearModel
from springc.lang import load_text
from shared_cache import KERNELS

S = msp.MassSpringSettings(bins=2, delays=2)
N = n_features(2, 2)


@pytest.fixture(autouse=True, scope="module")
def _kernel_cache():
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("SPRINGC_CACHE", str(KERNELS))
        yield


def words() -> np.ndarray:
    """Three 0.4 s chirps (up, down, two-tone) at 16 kHz."""
    t = np.arange(6400) / 16000
    env = np.sin(np.pi * t / 0.4) ** 2
    return np.stack([0.3 * env * chirp(t, 300, 0.4, 2500, method="logarithmic"),
                     0.6 * env * chirp(t, 2500, 0.4, 300, method="logarithmic"),
                     0.4 * env * (np.sin(2 * np.pi * 500 * t) + np.sin(2 * np.pi * 1800 * t))])


def model(rows: int, seed: int = 1) -> LinearModel:
    rng = np.random.default_rng(seed)
    return LinearModel(rng.normal(size=(rows, N)), rng.normal(size=rows),
                       np.array([f"c{k}" for k in range(max(rows, 2))]))


def test_head_design_obeys_its_equations():
    m = model(1)
    head = tr.design_head("h", m.coef[0], 0.5, S, amplitude=2e-3, epsilon=1e-3)
    lam = head.lam[head.keep]
    assert np.all(np.sign(head.gamma) == np.sign(lam)) and np.all(head.alpha / head.gamma > 0)
    np.testing.assert_allclose(2e-3**2 * head.gamma / (head.alpha * S.kc), 1e-3)  # epsilon
    k_total = readout_params(tr.TAU_READOUT, tr.Q_READOUT).k_total
    np.testing.assert_allclose(np.sum(head.gamma * head.alpha), tr.FILL * k_total)
    phi = np.random.default_rng(2).normal(size=4)  # sum_k lambda_k (Q_k . phi)^2 = phi C phi
    c = spread(m.coef[0], 2, 2)
    np.testing.assert_allclose(np.sum(head.lam * (head.q.T @ phi) ** 2), phi @ c @ phi)
    with pytest.raises(UsageError):
        tr.design_head("h", m.coef[0], 0.0, S, amplitude=0.0, epsilon=1.0)


def test_classifier_netlist_passes_the_compiler(tmp_path):
    heads = tr.heads_for([(("c0", "c1", "c2"), model(3))], S, 1e-3, 1e-5)
    for k, h in enumerate(heads):
        (tmp_path / f"head{k}.spr").write_text(tr.head_text(k, h, S, len(heads)))
    path = tmp_path / "classifier.spr"
    path.write_text(tr.classifier_text(heads, S, include_heads=False))
    report = build(path)
    assert report.elements["Q"] == 2 + sum(len(h.keep) for h in heads)
    assert report.dofs == msp.feature_network(S).n + 3 * (4 + 1)  # outputs and a readout


def test_the_8x3_classifier_passes_the_checks():
    # twelve heads of designed zero modes on one 8x3 front end: one component of
    # 788 nodes (dense PSD check), whose stiffness at rest has many zero eigenvalues
    s = msp.MassSpringSettings(bins=8, delays=3)
    rng = np.random.default_rng(3)
    n = n_features(8, 3)
    fit = LinearModel(rng.normal(size=(12, n)), rng.normal(size=12),
                      np.array([f"c{k}" for k in range(12)]))
    heads = tr.heads_for([(tuple(fit.classes), fit)], s, 1e-3, 1e-5)
    net = load_text(tr.classifier_text(heads, s), "<classifier>")
    assert net.n == msp.feature_network(s).n + 12 * (24 + 1)  # outputs and a readout each
    assert check(net).errors == []  # raised ArpackNoConvergence before the dense PSD check


def test_readouts_equal_c_phi_and_score_like_the_digital_model():
    sig = words()
    phi = msp.phi_batch(sig, S)  # the data-set path (single precision), as evaluation runs it
    amp = msp.reference_run(sig, S).amplitude
    m = model(3)
    m.coef /= phi.std(axis=0)  # comparable terms, as a trained model on standardised Phi
    heads = tr.heads_for([(tuple(m.classes), m)], S, amp, 1e-6)
    net = load_text(tr.classifier_text(heads, S), "<classifier>")
    reds = tr.classifier_batch(sig, check(net), tr.readout_reductions(heads),
                               msp.horizon(S, 0.4))
    d = tr.decisions(reds, heads)
    want = m.decision(phi)
    assert np.abs(d - want).max() < 0.02 * np.abs(want - m.intercept).max()
    loss = tr.insertion_loss_db(reds, heads)
    assert np.all(np.isfinite(loss)) and np.all(loss > 0)
    y = np.array(["c0", "c1", "c2"])
    got = score(selection_models([(tuple(m.classes), m)]), d, y, "kws12")
    assert got["accuracy"] == score([(tuple(m.classes), m)], phi, y, "kws12")["accuracy"]


def test_stand_in_heads_compile_the_kernel_of_trained_heads():
    """`compile_ahead`'s premise: the classifier's kernel depends on the kinds of terms and the
    reductions, not on the weights, amplitude or squaring error."""
    from springc.sim.simulate import simulate

    rng = np.random.default_rng(5)
    fit = LinearModel(3 * rng.normal(size=(12, N)), rng.normal(size=12),
                      np.array([f"w{k}" for k in range(12)]))
    paths = []
    for heads, eps in ((tr.heads_for([(tuple(fit.classes), fit)], S, 3e-6, 1e-4), 1e-4),
                       (tr.stand_in_heads(S), tr.DEFAULT_EPSILON)):
        net = check(load_text(tr.classifier_text(heads, S, epsilon=eps), "<classifier>"))
        res = simulate(net, np.zeros((1, 1, 160)), 16000, probes=[], tstop=0.01,
                       reductions=tr.readout_reductions(heads), chunk=msp.BATCH,
                       method="rk4", substeps=2, precision="float64")
        paths.append(res.info["kernel"])
    assert paths[0] == paths[1]


def test_summing_heads_obey_their_equations_and_load_the_taps_lightly():
    """Summing heads (transfer.Design("summing")): gamma_e = scale lambda_e |q_e|_1^2, each
    coupling's squaring error eps against its summing node's stiffness kappa |q_e|_1, the
    couplings fill the readout's stiffness, and all heads together put LOAD of the taps'
    static stiffness (or impedance at fc, the smaller) on the most loaded tap."""
    m = model(3)
    design = tr.Design("summing")
    heads = tr.heads_for([(tuple(m.classes), m)], S, 2e-3, 1e-3, design)
    k_total = readout_params(tr.TAU_READOUT, tr.Q_READOUT).k_total
    load = sum(np.abs(h.q[:, h.keep]).sum(axis=1) for h in heads) * heads[0].kappa
    holding = min(S.line_damping() * 2 * np.pi * S.fc, S.kc / S.line_sites(S.delays - 1))
    assert load.max() == pytest.approx(tr.LOAD * holding)
    for h in heads:
        l1 = np.abs(h.q[:, h.keep]).sum(axis=0)
        ratio = h.gamma / (h.lam[h.keep] * l1**2)
        np.testing.assert_allclose(ratio, ratio[0])  # one scale per head
        np.testing.assert_allclose(2e-3**2 * h.gamma / (h.alpha * h.kappa * l1), 1e-3)
        np.testing.assert_allclose(np.sum(h.gamma * h.alpha), tr.FILL * k_total)
        assert h.scale == pytest.approx(ratio[0] / tr.readout_scale())


def test_summing_readouts_equal_c_phi():
    """The whole network with summing heads (terminals matched by their own masses): the
    readouts are c . Phi within 3% (the summing nodes' lag at the features' envelopes and
    their 0.1% load on the taps come on top of the zero-mode heads' 2%), and the netlist
    passes the checks."""
    sig = words()
    phi = msp.phi_batch(sig, S)
    amp = msp.reference_run(sig, S).amplitude
    m = model(3)
    m.coef /= phi.std(axis=0)
    design = tr.Design("summing")
    heads = tr.heads_for([(tuple(m.classes), m)], S, amp, 1e-6, design)
    net = load_text(tr.classifier_text(heads, S, design=design), "<summing classifier>")
    assert "Q" in net.element_counts() and not any(n.startswith("Xh0.Xm") for n in net.nodes)
    reds = tr.classifier_batch(sig, check(net), tr.readout_reductions(heads),
                               msp.horizon(S, 0.4))
    d = tr.decisions(reds, heads)
    want = m.decision(phi)
    assert np.abs(d - want).max() < 0.03 * np.abs(want - m.intercept).max()


def test_train_builds_the_design_its_options_ask_for():
    """`springc train`'s head options: the buffered design beyond eps 1e-5 unless told
    (docs/results-eps.md), summing heads and the default physical scale for a device model,
    and head options refused for a digital model."""
    from springc.kws.evaluation.api import _design

    assert tr.default_design(1e-5) == tr.Design() and tr.default_design(1.0) == tr.BUFFERED
    none = dict(spl=None, area=None, temp=None, device_mass=None)
    assert _design("mass-spring", 1.0, None, None, None, none) == (None, None)
    design, scale = _design("device", None, None, None, None, none)
    assert design == tr.Design("summing") and scale == {"spl": 60.0, "area": 1e-6,
                                                        "temp": 300.0, "device_mass": 2e-9}
    # summing heads hold their own nodes: no buffer at any eps (a buffer node has no mass
    # without the zero-mode heads on it), and the zero-mode options refused
    assert _design("device", 1.0, None, None, None, none)[0] == tr.Design("summing")
    with pytest.raises(UsageError, match="summing heads have neither"):
        _design("device", 1.0, None, (1.0, 1.0), None, none)
    design, _ = _design("mass-spring", 1.0, None, None, 3.0, none)
    assert design == tr.Design("zero-mode", tr.BUFFERED.buffer, 3.0)
    assert tr.Design.from_dict(design.to_dict()) == design
    with pytest.raises(UsageError, match="build mass-spring heads"):
        _design("digital", None, "summing", None, None, none)
    with pytest.raises(UsageError, match="describe a device model"):
        _design("mass-spring", None, None, None, None, {**none, "spl": 70.0})
