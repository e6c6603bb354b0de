"""`springc.train`, `evaluate`, `cross_validate`, `synthesise` and `tune`: each does what its
command does (`springc train`, `eval`, `cv`, `data synth`, `tune`), with the command's
defaults, on a tiny generated corpus (the digital realisation: no kernel to compile; `tune`
by its arguments, its runs in tests/test_kws_tune.py)."""

from __future__ import annotations

import inspect
import json
import os
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

import springc
from springc.errors import UsageError
from springc.kws.evaluation import api
from springc.kws.tuning.tune import tune_model
from springc_cli.data import synth_cmd
from springc_cli.kws import cv_cmd, eval_cmd, train_cmd
from springc_cli.main import main
from springc_cli.tune import tune_cmd
from kws_corpora import make_corpus

SMALL = dict(bins=4, delays=2, jobs=1)
SMALL_ARGS = ["-n", "4", "-m", "2", "-j", "1"]
ENGINES_HERE = all(shutil.which(p) for p in ("espeak-ng", "flite", "festival"))


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    """The corpus and one feature cache for the module (the second run of a command reads
    the features the first computed)."""
    root = tmp_path_factory.mktemp("kws-api")
    old = os.environ.get("SPRINGC_CACHE")
    os.environ["SPRINGC_CACHE"] = str(root / "cache")
    yield make_corpus(root / "data")
    if old is None:
        os.environ.pop("SPRINGC_CACHE")
    else:
        os.environ["SPRINGC_CACHE"] = old


def _cli(*args: str) -> str:
    result = CliRunner().invoke(main, list(args))
    assert result.exit_code == 0, result.output
    return result.output


@pytest.fixture(scope="module")
def models(corpus, tmp_path_factory):
    """(report, model folder) of `springc.train`, and the folder `springc train` wrote."""
    root = tmp_path_factory.mktemp("models")
    report = springc.train(corpus, root / "py", **SMALL)
    _cli("train", "--data", str(corpus), *SMALL_ARGS, "-o", str(root / "cli"))
    return report, root / "py", root / "cli"


def _timeless(report: dict) -> dict:
    return {k: v for k, v in report.items() if k != "seconds"}


def test_train_writes_the_model_the_command_writes(models):
    report, py, cli = models
    assert sorted(p.name for p in py.iterdir()) == sorted(p.name for p in cli.iterdir())
    for name in ("settings.json", "report.json"):
        ours, theirs = (json.loads((d / name).read_text()) for d in (py, cli))
        assert _timeless(ours) == _timeless(theirs), name
    assert _timeless(json.loads((py / "report.json").read_text())) == _timeless(report)
    with np.load(py / "weights.npz") as ours, np.load(cli / "weights.npz") as theirs:
        assert sorted(ours) == sorted(theirs)
        for key in ours:
            np.testing.assert_array_equal(ours[key], theirs[key])
    # yes, no, _unknown_ (cat) and _silence_: 3 test clips each, told apart
    assert report["n"] == 12 and report["accuracy"] >= 0.9


def test_evaluate_is_the_command_and_the_model(corpus, models):
    _, py, _ = models
    report = springc.evaluate(py, corpus, jobs=1)
    printed = json.loads(_cli("eval", str(py), "--data", str(corpus), "--json", "-j", "1"))
    assert {k: report[k] for k in printed} == printed
    assert springc.kws.load_model(py).evaluate(corpus, jobs=1) == report
    assert report["accuracy"] == models[0]["accuracy"]  # the test split training scored


@pytest.mark.parametrize("options, message", [
    (dict(clips=3), "--clips goes with --mc or --temp"),
    (dict(mc=2, spread=0.01), "is a digital model; a device is a mass-spring network"),
    (dict(mc=2, spread=0.01, budget=2), "--budget is a study of its own"),
    (dict(budget=2), "the energy budget needs a mass-spring or router model"),
    (dict(mc=2), "--mc also needs --spread"),
])
def test_evaluate_refuses_what_the_command_refuses(models, options, message):
    with pytest.raises(UsageError, match=message):
        springc.evaluate(models[1], **options)


def test_cross_validate_writes_what_the_command_writes(corpus, tmp_path):
    options = dict(realisations="digital", folds=4, **SMALL)
    report = springc.cross_validate(corpus, tmp_path / "py", **options)
    _cli("cv", "--data", str(corpus), *SMALL_ARGS, "--realisation", "digital", "-k", "4",
         "-o", str(tmp_path / "cli"))
    theirs = json.loads((tmp_path / "cli" / "cv.json").read_text())
    assert json.loads((tmp_path / "py" / "cv.json").read_text()) == theirs == report
    assert (tmp_path / "py" / "cv.png").stat().st_size > 1000
    assert report["clips"] == sum(report["fold_sizes"]) and report["folds"] == 4
    assert list(report["realisations"]) == ["digital"]
    assert report["realisations"]["digital"]["balanced_accuracy"] > 0.25  # chance: 1 of 4
    assert springc.cross_validate(corpus, None, **options) == report  # nothing written


@pytest.mark.skipif(not ENGINES_HERE, reason="text-to-speech engines not installed")
def test_synthesise_writes_the_corpus_the_command_writes(tmp_path):
    out = springc.synthesise(tmp_path / "py", clips=4, seed=3, jobs=1, words=["yes", "no"],
                             engines=["flite"])
    assert out == tmp_path / "py"
    _cli("data", "synth", str(tmp_path / "cli"), "--clips", "4", "--seed", "3", "-j", "1",
         "--words", "yes,no", "--engines", "flite")
    ours = sorted(p.relative_to(out) for p in out.rglob("*") if p.is_file())
    theirs = sorted(p.relative_to(tmp_path / "cli") for p in (tmp_path / "cli").rglob("*")
                    if p.is_file())
    assert ours == theirs and len([p for p in ours if p.suffix == ".wav"
                                   and p.parts[0] in ("yes", "no")]) == 4
    for path in ours:
        assert (out / path).read_bytes() == (tmp_path / "cli" / path).read_bytes(), path


# the Python name of an option and its default as the command spells it
AS_OPTION = {"use_cache": ("no_cache", lambda v: not v), "mc": ("devices", None),
             "params": ("params", ",".join),
             "realisations": ("realisations", lambda v: tuple(v or ())),
             "engines": ("engines", ",".join)}
# device None: the innermost `springc.default_device`, the CPU outside one (--device cpu)
PYTHON_ONLY = {"device", "progress"}
# --json and --baseline (realisation="baseline") choose output and spelling; --plot of
# `data synth` draws spectrograms, the one option without a Python argument
COMMAND_ONLY = {"as_json", "baseline", "plot_path"}


@pytest.mark.parametrize("entry, command, required", [
    (api.train, train_cmd, ["--data", "D", "-o", "O"]),
    (api.evaluate, eval_cmd, ["M"]),
    (api.cross_validate, cv_cmd, ["--data", "D", "-o", "O"]),
    (api.synthesise, synth_cmd, ["O"]),
    (tune_model, tune_cmd, ["M", "-o", "O"]),
])
def test_every_option_is_an_argument_with_the_commands_default(entry, command, required):
    given = command.make_context(command.name, list(required)).params
    needed = {p.name for p in command.params if p.required}  # no default to compare
    seen = needed | COMMAND_ONLY | {"device"}
    for name, p in inspect.signature(entry).parameters.items():
        option, spell = AS_OPTION.get(name, (name, None))
        seen.add(option)
        if p.default is p.empty or name in PYTHON_ONLY or option in needed:
            continue
        assert (spell(p.default) if spell else p.default) == given[option], name
    assert set(given) <= seen


def test_the_entries_are_reached_from_the_top():
    for name in ("train", "evaluate", "cross_validate", "synthesise"):
        assert getattr(springc, name) is getattr(springc.kws, name) is getattr(api, name)
        assert name in springc.__all__ and name in springc.kws.__all__
    assert springc.tune is springc.kws.tune is tune_model
    assert "tune" in springc.__all__ and "tune" in springc.kws.__all__
    with pytest.raises(AttributeError, match="no attribute 'classify'"):
        springc.classify  # a model classifies: springc.kws.load_model


def test_a_device_models_studies_default_to_its_recorded_scale(tmp_path):
    """What `--spl`, `--area`, `--temp`, `--device-mass` do not give, a device model's
    settings give (`train --realisation device` records them); a mass per unit given leaves
    the recorded device mass out (the two say the same thing); a mass-spring model records
    none; a broken settings file is a data error naming it."""
    model = tmp_path / "device"
    model.mkdir()
    recorded = {"spl": 70.0, "area": 4e-6, "temp": 77.0, "device_mass": 3e-10}
    (model / "settings.json").write_text(json.dumps({"device": recorded}))
    none = dict(spl=None, area=None, temp=None, device_mass=None, mass=None)
    assert api.recorded_scale(model, none) == {**recorded, "mass": None}
    assert api.recorded_scale(model, {**none, "spl": 60.0})["spl"] == 60.0
    assert api.recorded_scale(model, {**none, "mass": 1e-12})["device_mass"] is None
    plain = tmp_path / "plain"
    plain.mkdir()
    (plain / "settings.json").write_text(json.dumps({"realisation": "mass-spring"}))
    assert api.recorded_scale(plain, none) == none
    (plain / "settings.json").write_text("{")
    with pytest.raises(springc.errors.DataError, match="settings.json: is not a model"):
        api.recorded_scale(plain, none)
