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
