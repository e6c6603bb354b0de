"""`springc tune` on a tiny generated corpus: the loss gradient the tuner steps along agrees with
central differences of the loss, for the nominal network and for a fabricated population;
tuning starts from the network the model simulates, as its design says; steps lower the
training loss, the validation loss picks the epoch kept, the tuned folder is what `springc
eval` simulates, every tuned netlist passes the checks, bad inputs fail cleanly."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from springc.check import check
from springc.design.emit import num
from springc.design.scale import flat_text
from springc.kws.features import massspring as msp
from springc.kws.tuning import tune as T
from springc.kws.training.model import load_model
from springc.kws.data.task import targets
from springc.kws.training.transfer import model_heads
from springc.lang import load_file
from springc_cli.main import main
from kws_corpora import shared_corpus_and_model


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    data, model = shared_corpus_and_model(tmp_path_factory, "--realisation", "mass-spring")
    root = tmp_path_factory.mktemp("tune")
    return root, data, model


@pytest.fixture(scope="module")
def tuned_run(env):
    """Three full-batch steps on one clip (the loss of epoch e is taken before its step)
    with one validation clip: the folder and what the command printed."""
    root, _, model = env
    out = root / "tuned"
    result = CliRunner().invoke(main, ["tune", str(model), "-o", str(out), "--clips", "1",
                                       "--val-clips", "1", "--batch", "1", "--epochs", "3",
                                       "--lr", "0.1", "--no-refit", "-j", "1"])
    assert result.exit_code == 0, result.output
    return out, result.output


@pytest.fixture(scope="module")
def tuned(tuned_run):
    return tuned_run[0]


def setup(model_dir, clips: int, il_weight: float):
    opts = T.TuneOptions(model_dir, None, model_dir.parent / "unused", clips=clips,
                         il_weight=il_weight, evaluate=False)
    model, start = T.load_start(model_dir)
    _, chosen, _ = T.training_clips(opts, model)
    tg = T.make_targets(model.models, targets(chosen, model.settings["task"]))
    sig = msp.load_signals(chosen, False, 0, [])
    lay = T.layout(opts.params, start.s.bins, start.heads)
    return opts, model, start, lay, tg, sig


def test_the_loss_gradient_matches_central_differences(env):
    _, _, model_dir = env
    opts, model, start, lay, tg, sig = setup(model_dir, 1, 0.01)
    sig = sig[:, :6400]  # the first 0.4 s (every word has begun): under half the steps of 1 s
    eps = float(model.settings["transfer"]["epsilon"])
    z = T.initial_z(start, lay) + np.random.default_rng(1).normal(0, 0.3, lay.size)
    idx = np.arange(len(sig))
    b = T.make_batch(opts, start, lay, z, eps, tg,
                     msp.horizon(start.s, sig.shape[1] / msp.INPUT_RATE))
    assert b.temperature != 1.0  # the temperature's coordinate is perturbed too
    g, loss = T.z_gradient([T.batch_gradient((sig, idx), b)], lay, z)
    assert loss == pytest.approx(T.loss_at(opts, start, z, eps, tg, sig, idx), rel=1e-12)
    for name, sl in lay.slices.items():  # one coordinate of every group and log T
        i = min(sl.start + 1, sl.stop - 1)

        def diff(h: float) -> float:
            zp, zm = z.copy(), z.copy()
            zp[i] += h
            zm[i] -= h
            return (T.loss_at(opts, start, zp, eps, tg, sig, idx)
                    - T.loss_at(opts, start, zm, eps, tg, sig, idx)) / (2 * h)

        richardson = (4 * diff(5e-4) - diff(1e-3)) / 3
        assert g[i] == pytest.approx(richardson, rel=1e-6), name
        assert abs(g[i]) > 1e-6, name  # a gradient that is there


def test_a_populations_loss_gradient_matches_central_differences(env):
    """With a population the loss is the mean over its devices (the network at z, each
    coefficient times the device's fixed draw): the gradient a step takes is that mean's,
    against central differences with the same devices, and the devices' loss is not the
    nominal network's. The bound is the nominal test's: Richardson-extrapolated differences
    of a smooth loss, below the 1e-5 relative error a device factor missed in the chain rule
    would leave (the spread; the paper's zero-mode heads already lose accuracy there)."""
    _, _, model_dir = env
    opts, model, start, lay, tg, sig = setup(model_dir, 1, 0.0)
    opts.devices, opts.spread = 2, 1e-5
    sig = sig[:, :6400]
    eps = float(model.settings["transfer"]["epsilon"])
    z = T.initial_z(start, lay) + np.random.default_rng(3).normal(0, 0.3, lay.size)
    idx, devices = np.arange(len(sig)), T.step_population(opts, 5)
    assert devices == (10, 11)
    b = T.make_batch(opts, start, lay, z, eps, tg,
                     msp.horizon(start.s, sig.shape[1] / msp.INPUT_RATE), devices)
    assert len(T.on_devices(b)) == 2
    g, loss = T.z_gradient([T.batch_gradient((sig, idx), b)], lay, z)

    def at(zz: np.ndarray, population=devices) -> float:
        return T.loss_at(opts, start, zz, eps, tg, sig, idx, population)

    assert loss == pytest.approx(at(z), rel=1e-12)
    assert abs(loss - at(z, ())) > 1e-6 * abs(loss)
    for name in ("filter", "couplings"):
        i = lay.slices[name].start + 1

        def diff(h: float) -> float:
            zp, zm = z.copy(), z.copy()
            zp[i] += h
            zm[i] -= h
            return (at(zp) - at(zm)) / (2 * h)

        richardson = (4 * diff(5e-4) - diff(1e-3)) / 3
        assert g[i] == pytest.approx(richardson, rel=1e-6), name
        assert abs(g[i]) > 1e-6, name


def test_tuning_starts_from_the_network_the_model_simulates(env, tmp_path):
    """At the start (every factor 1) tune's network is the model folder's classifier.spr,
    the network `springc eval` simulates, built as the model's recorded design says: here
    the paper's heads, and in a copy whose settings record multipliers 10 times as stiff,
    those (every coupling of a head's multiplier 10 times the paper's)."""
    _, _, model_dir = env

    def start_network(folder):
        model, start = T.load_start(folder)
        lay = T.layout(T.GROUPS, start.s.bins, start.heads)
        eps = float(model.settings["transfer"]["epsilon"])
        return T.network(*T.tuned(start, T.initial_z(start, lay), lay), eps, start.design).net

    ours = start_network(model_dir)
    assert flat_text(ours) == flat_text(check(load_file(model_dir / "classifier.spr")).net)
    stiff = tmp_path / "stiff"
    shutil.copytree(model_dir, stiff)
    settings = json.loads((stiff / "settings.json").read_text())
    settings["transfer"]["design"] = {"heads": "zero-mode", "mvm_stiffness": 10.0,
                                      "buffer": None}
    (stiff / "settings.json").write_text(json.dumps(settings))
    other = start_network(stiff)
    mvm = [e for e, name in enumerate(ours.couplings.names) if ".Xm." in name]
    assert mvm and other.couplings.names == ours.couplings.names
    np.testing.assert_allclose(other.couplings.k[mvm], 10 * ours.couplings.k[mvm], rtol=1e-12)


def test_steps_lower_the_training_loss(tuned):
    hist = json.loads((tuned / "settings.json").read_text())["tune"]["history"]
    losses = [h["train_loss"] for h in hist if "train_loss" in h]
    assert len(losses) == 3
    assert losses[2] < losses[1] < losses[0]


def test_the_tuned_folder_is_what_eval_simulates(env, tuned):
    _, _, model_dir = env
    settings = json.loads((tuned / "settings.json").read_text())
    factors = np.concatenate(settings["transfer"]["couplings"])
    assert np.abs(factors - 1).max() > 1e-3
    assert len(settings["features"]["filter_scale"]) == 4
    s0, heads0 = model_heads(load_model(model_dir))
    s1, heads1 = model_heads(load_model(tuned))
    assert s1.filter_scale == tuple(settings["features"]["filter_scale"])
    for k, (h0, h1) in enumerate(zip(heads0, heads1)):
        f = np.array(settings["transfer"]["couplings"][k])
        np.testing.assert_allclose(h1.gamma, h0.gamma * f, rtol=1e-12)
        np.testing.assert_allclose(h1.gamma * h1.alpha, h0.gamma * h0.alpha, rtol=1e-12)
        assert h1.intercept == settings["transfer"]["intercepts"][k]
        text = (tuned / f"head{k}.spr").read_text()
        assert f"g={num(h1.gamma[0])}" in text and f"g={num(h0.gamma[0])}" not in text
    assert "fa=" in (tuned / "classifier.spr").read_text()
    report = json.loads((tuned / "report.json").read_text())
    result = CliRunner().invoke(main, ["eval", str(tuned), "-j", "1"])
    assert result.exit_code == 0, result.output
    assert f"{100 * report['accuracy']:.2f}%" in result.output
    readme = (tuned / "README.md").read_text()
    assert readme.startswith("# Keyword spotter: mass-spring, 4 bins x 2 delays\n\nTuned by")
    assert (f"springc tune {model_dir.resolve()} -o {tuned} --params "
            "filter,compression,couplings,readout --epochs 3 --batch 1 --clips 1 --val-clips 1 "
            "--lr 0.1 "
            "--il-weight 0 --seed 0 --no-refit") in readme
    assert f"-o {model_dir.resolve()}\n" in readme  # the train line makes the start model
    assert "filter_scale =" not in readme  # tune's settings are not train's to list
    assert not T.checkpoint_path(tuned).exists()  # removed once the folder is written


def test_the_lowest_validation_loss_picks_the_epoch_kept():
    hist = [{"epoch": 0, "validation_loss": 1.2}, {"epoch": 1, "validation_loss": 0.9},
            {"epoch": 2, "validation_loss": 1.0}, {"epoch": 3, "validation_loss": 0.9}]
    assert T.chosen_epoch(hist) == 1  # the first of equals
    assert T.chosen_epoch(hist[:1]) == 0  # the start
    assert T.chosen_epoch([{"epoch": 1, "train_loss": 1.0}, {"epoch": 2}]) == 2  # none: last


def test_a_validated_run_keeps_its_best_epoch(env, tuned_run):
    """With validation clips the validation loss from the start is recorded, the folder
    holds the kept epoch's network (the start's when the start was best), and the kept
    epoch's validation loss is that of the folder's network."""
    _, _, model_dir = env
    out, output = tuned_run
    tune = json.loads((out / "settings.json").read_text())["tune"]
    val = [h["validation_loss"] for h in tune["history"]]
    assert [h["epoch"] for h in tune["history"]] == [0, 1, 2, 3]
    assert tune["chosen_epoch"] == int(np.argmin(val)) and "kept epoch" in output
    s0, heads0 = model_heads(load_model(model_dir))
    s1, heads1 = model_heads(load_model(out))
    moved = max(np.abs(h1.gamma / h0.gamma - 1).max() for h0, h1 in zip(heads0, heads1))
    assert (moved > 1e-6) == (tune["chosen_epoch"] > 0)
    opts = T.TuneOptions(model_dir, None, out, clips=1, val_clips=1, evaluate=False)
    model, start = T.load_start(model_dir)
    _, _, held = T.training_clips(opts, model)
    clips = T.clip_set(held, model)
    eps = float(model.settings["transfer"]["epsilon"])
    lay = T.layout(opts.params, start.s.bins, start.heads)
    z = T.initial_z(start, lay)  # the start: its validation loss is the first recorded
    assert T.loss_at(opts, start, z, eps, clips.targets, clips.signals,
                     np.arange(len(held))) == pytest.approx(val[0], rel=1e-12)


def test_every_tuned_netlist_passes_the_checks(env, tuned):
    for name in ("classifier.spr", "features.spr"):
        result = CliRunner().invoke(main, ["build", str(tuned / name)])
        assert result.exit_code == 0, result.output
    _, _, model_dir = env
    opts, model, start, lay, _, _ = setup(model_dir, 1, 0.0)
    eps = float(model.settings["transfer"]["epsilon"])
    rng = np.random.default_rng(2)
    for z in (rng.normal(0, 30, lay.size), np.full(lay.size, 80.0), np.full(lay.size, -80.0)):
        s, heads = T.tuned(start, z, lay)
        for f, name in ((s.filter_factors(), "filter"), (s.compression_factors(),
                                                         "compression")):
            assert T.BOXES[name].lo <= f.min() and f.max() <= T.BOXES[name].hi
        net = T.network(s, heads, eps).net  # CheckError if illegal
        check(net)  # and at the netlist's own .tran / .options, as `springc build` checks


def test_a_checkpoint_resumes_only_its_own_run(tmp_path):
    path = tmp_path / ".out.tune-checkpoint.json"
    adam = T.Adam(0.1, np.zeros(3), np.zeros(3))
    z = adam.step(np.zeros(3), np.array([1.0, -2.0, 0.5]))
    T.save_checkpoint(path, "key-a", 1, z, adam, [{"epoch": 1, "train_loss": 0.5}], z * 0)
    state = T.load_checkpoint(path, "key-a", 3)
    assert state["epochs_done"] == 1 and state["adam"]["t"] == 1
    np.testing.assert_allclose(state["z"], [-0.1, 0.1, -0.1], rtol=1e-6)
    assert state["best"] == [0.0, 0.0, 0.0]
    assert T.load_checkpoint(path, "key-b", 3) is None
    assert T.load_checkpoint(path, "key-a", 4) is None


def test_bad_inputs_fail_cleanly(env, tmp_path):
    root, data, model = env
    digital = tmp_path / "digital"
    result = CliRunner().invoke(main, ["train", "--data", str(data), "-n", "4", "-m", "2",
                                       "-j", "1", "-o", str(digital)])
    assert result.exit_code == 0, result.output
    out = tmp_path / "out"
    cases = [
        (["tune", str(digital), "-o", str(out)], ["settings.json", "mass-spring"]),
        (["tune", str(model), "--data", str(tmp_path / "nowhere"), "-o", str(out)],
         ["nowhere", "no such data folder"]),
        (["tune", str(tmp_path / "nomodel"), "-o", str(out)], ["nomodel", "no such model"]),
        (["tune", str(model), "--params", "filter,gain", "-o", str(out)], ["gain"]),
        (["tune", str(model), "-o", str(model)], ["output folder is the model"]),
        (["tune", str(model), "-o", str(out), "--mc", "2"], ["--mc N and --spread S go"]),
        (["tune", str(model), "-o", str(out), "--mc", "2", "--spread", "-1"],
         ["--spread must be"]),
    ]
    for args, words in cases:
        result = CliRunner().invoke(main, args)
        assert result.exit_code == 1, (args, result.output)
        assert "Traceback" not in result.output
        for word in words:
            assert word in result.output, (args, result.output)
        assert not out.exists()
    shutil.rmtree(digital)
