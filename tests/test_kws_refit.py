"""The refit on the exact head response (`springc.kws.tuning.refit`, `springc tune`'s first stage),
on a tiny generated corpus: a network's decisions are the linear readout sum_e lambda_e J_e + b
of its zero modes' integrals J, J does not depend on the heads' weights (so a refitted
network reads out what the fit assumed), and a refitted folder is what `springc eval`
simulates."""

from __future__ import annotations

import functools
import json

import numpy as np
import pytest
from click.testing import CliRunner

from springc.kws.features import massspring as msp
from springc.kws.tuning import refit as rf
from springc.kws.training import transfer as tr
from springc.kws.evaluation.evaluate import model_integration, trained_data
from springc.kws.training.model import load_model
from springc.kws.data.task import open_task_data
from springc.lang import load_text
from springc_cli.main import main
from kws_corpora import shared_corpus_and_model


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    data, model = shared_corpus_and_model(tmp_path_factory, "--realisation", "mass-spring")
    root = tmp_path_factory.mktemp("refit")
    return root, data, model


def network_at(model_dir, eps: float):
    """The model's settings, its heads transferred at squaring error eps, four training
    clips' signals and the model's integration."""
    model = load_model(model_dir)
    s, _ = tr.model_heads(model)
    heads = tr.heads_for(model.models, s, float(model.settings["transfer"]["amplitude"]), eps)
    ds = open_task_data(trained_data(model), model.settings["task"], 0, None,
                        splits=("train",))
    sig = msp.load_signals(ds.split("train")[:4], False, 0, [])
    return s, heads, sig, model_integration(model)


def respond(s, heads, sig, plan, eps):
    net = load_text(tr.classifier_text(heads, s, epsilon=eps), "<classifier>")
    return rf.response(net, heads, s, sig, plan, jobs=1)


@functools.lru_cache(maxsize=None)
def transferred(model_dir, eps: float):
    """`network_at` and the transferred network's response, once per eps for the module
    (the readout test and the reweighting test read the same one at eps 1e-2)."""
    s, heads, sig, plan = network_at(model_dir, eps)
    return s, heads, sig, plan, respond(s, heads, sig, plan, eps)


def lam(heads):
    return [h.lam[h.keep] for h in heads], [h.intercept for h in heads]


@pytest.mark.parametrize("eps", [1e-6, 1e-2])
def test_decisions_are_the_linear_readout_of_j(env, eps):
    """The readout is a linear oscillator driven by sum_e gamma_e y_e^2: its decision is
    sum_e lambda_e J_e + b, with J the leaky integrals at its slow pole, squaring ideal or
    not."""
    s, heads, sig, plan, got = transferred(env[2], eps)
    d = rf.decide(got.j, heads, *lam(heads))
    scale = np.median(np.abs(got.decisions))
    assert np.abs(d - got.decisions).max() < 1e-3 * scale


def test_j_does_not_depend_on_the_weights(env):
    """At eps 1e-2 the couplings' cubic stiffness distorts the zero modes, but it is the same
    for any weights (alpha / gamma is fixed by eps): a network with other weights has the
    same J, so the refit's decisions predicted from the transferred network's J are the
    reweighted network's."""
    eps = 1e-2
    s, heads, sig, plan, before = transferred(env[2], eps)
    rng = np.random.default_rng(3)
    weights = [rng.normal(size=len(h.keep)) * np.abs(h.lam[h.keep]).max() for h in heads]
    intercepts = [float(v) for v in rng.normal(size=len(heads))]
    new = tr.reweighted_heads(heads, weights, intercepts, s, float(load_model(env[2]).settings[
        "transfer"]["amplitude"]), eps)
    after = respond(s, new, sig, plan, eps)
    assert np.abs(after.j - before.j).max() < 1e-4 * np.abs(before.j).max()
    assert not np.allclose(after.decisions, before.decisions, rtol=1e-2)  # other weights
    predicted = rf.decide(before.j, heads, weights, intercepts)
    assert np.abs(predicted - after.decisions).max() < 1e-3 * np.abs(after.decisions).max()


def test_a_refitted_folder_is_what_eval_simulates(env):
    root, _, model_dir = env
    out = root / "refitted"
    # 16 of the 59 training clips: the refit's simulations are most of this test's time
    result = CliRunner().invoke(main, ["tune", str(model_dir), "-o", str(out), "--epochs", "0",
                                       "--val-clips", "0", "--refit-clips", "16", "-j", "1"])
    assert result.exit_code == 0, result.output
    assert "heads refitted on the exact response" in result.output
    settings = json.loads((out / "settings.json").read_text())
    kept = settings["tune"]["refit_kept"]
    assert ("not kept" in result.output) != kept
    assert "exact response of 16 clips" in result.output
    model = load_model(out)
    _, heads = tr.model_heads(model)
    if kept:  # the folder's heads are the refit's, designed as the transfer designs its own
        refit = settings["transfer"]["refit"]
        for h, w, b in zip(heads, refit["weights"], refit["intercepts"]):
            np.testing.assert_allclose(h.lam[h.keep], w, rtol=1e-12)
            assert h.intercept == pytest.approx(b, rel=1e-12)
            ratio = h.alpha / h.gamma  # the same eps on every coupling
            np.testing.assert_allclose(ratio, ratio[0], rtol=1e-12)
    else:  # the transferred heads, unchanged
        assert "refit" not in settings["transfer"]
        _, start = tr.model_heads(load_model(model_dir))
        for h, h0 in zip(heads, start):
            np.testing.assert_allclose(h.gamma, h0.gamma, rtol=1e-12)
    report = json.loads((out / "report.json").read_text())
    evaluated = CliRunner().invoke(main, ["eval", str(out), "-j", "1"])
    assert evaluated.exit_code == 0, evaluated.output
    assert f"{100 * report['accuracy']:.2f}%" in evaluated.output
    readme = (out / "README.md").read_text()
    assert ("heads refitted first on the transferred network's exact response"
            in readme) == kept
    assert "--epochs 0" in readme and "--refit-clips 16" in readme
    nothing = CliRunner().invoke(main, ["tune", str(model_dir), "-o", str(root / "none"),
                                        "--epochs", "0", "--no-refit"])
    assert nothing.exit_code == 1 and "nothing to tune" in nothing.output
    assert not (root / "none").exists()
