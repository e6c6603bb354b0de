"""`springc train` and `springc eval` through click and as the installed command."""

from __future__ import annotations

import json
import os
import subprocess

import pytest
from click.testing import CliRunner

from springc_cli.main import main
from kws_corpora import make_corpus


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    root = tmp_path_factory.mktemp("cli")
    old = os.environ.get("SPRINGC_CACHE")
    os.environ["SPRINGC_CACHE"] = str(root / "cache")
    data = make_corpus(root / "data")
    model = root / "model"
    result = CliRunner().invoke(main, ["train", "--data", str(data), "--bins", "4",
                                       "--delays", "2", "-j", "1", "-o", str(model)])
    assert result.exit_code == 0, result.output
    yield data, model, result.output
    if old is None:
        os.environ.pop("SPRINGC_CACHE")
    else:
        os.environ["SPRINGC_CACHE"] = old


def test_train_prints_accuracy_and_writes_the_folder(env):
    data, model, output = env
    assert "test accuracy" in output and f"model written to {model}" in output
    assert (model / "confusion.png").stat().st_size > 1000


def test_train_prints_the_balanced_counts_and_the_majority_rate(env):
    """kws12 defaults: the balanced protocol (3 test clips of each of yes, no, _unknown_ and
    _silence_: majority 25 %) and balanced class weights, both in settings.json."""
    _, model, output = env
    assert "protocol balanced, class weights balanced" in output
    table = output.split("test accuracy")[0]  # the counts table, before the TPR lines
    rows = {line.split()[0]: line.split()[1:] for line in table.splitlines() if line.strip()}
    assert rows["yes"] == ["18", "3", "3"] and rows["_unknown_"] == ["18", "3", "3"]
    assert rows["_silence_"][1:] == ["3", "3"] and rows["majority"][1:] == ["25.0%", "25.0%"]
    assert "(majority class 25.00%)" in output
    settings = json.loads((model / "settings.json").read_text())
    assert settings["protocol"] == "balanced" and settings["class_weight"] == "balanced"


def test_train_with_the_raw_lists_and_equal_weights(env, tmp_path):
    data, _, _ = env
    result = CliRunner().invoke(main, ["train", "--data", str(data), "-n", "4", "-m", "2",
                                       "-j", "1", "--protocol", "lists", "--class-weights",
                                       "none", "-o", str(tmp_path / "m")])
    assert result.exit_code == 0, result.output
    assert "protocol lists, class weights equal" in result.output
    settings = json.loads((tmp_path / "m" / "settings.json").read_text())
    assert settings["protocol"] == "lists" and settings["class_weight"] is None
    report = json.loads((tmp_path / "m" / "report.json").read_text())
    assert report["counts"]["test"]["_silence_"] == 1  # 10 % of the 9 word clips


def test_eval_json(env):
    data, model, _ = env
    result = CliRunner().invoke(main, ["eval", str(model), "--data", str(data), "--json"])
    assert result.exit_code == 0, result.output
    report = json.loads(result.output)
    assert set(report) == {"accuracy", "majority_rate", "n", "per_class"}
    saved = json.loads((model / "report.json").read_text())
    assert report["accuracy"] == saved["accuracy"] and report["n"] == saved["n"]
    assert report["majority_rate"] == saved["majority_rate"] == 0.25


def test_installed_command_runs(env):
    data, model, _ = env
    proc = subprocess.run(["springc", "eval", str(model), "--json", "-j", "1"],
                          capture_output=True, text=True, env=os.environ)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["n"] > 0


@pytest.mark.parametrize("args,message", [
    (["train", "--data", "{root}/nowhere", "-o", "{root}/m"], "no such data folder"),
    (["train", "--data", "{data}", "--jobs", "-2", "-o", "{root}/m"], "--jobs must be"),
    (["train", "--data", "{data}", "--bins", "1", "-o", "{root}/m"], "--bins must be"),
    (["train", "--data", "{data}", "--td", "0.0315", "-o", "{root}/m"], "td * feature rate"),
    (["train", "--data", "{data}", "--task", "digits-pairs", "--protocol", "balanced", "-o",
      "{root}/m"], "the balanced protocol is for the kws12 task"),
    (["train", "--data", "{data}", "--stage-stiffness", "10", "-o", "{root}/m"],
     "--stage-stiffness is a setting of the mass-spring network"),
    (["train", "--data", "{data}", "--realisation", "device", "--stage-stiffness", "0", "-o",
      "{root}/m"], "the stage stiffness must be > 0"),
    (["train", "--data", "{data}", "--squarer-range", "1", "-o", "{root}/m"],
     "--squarer-range is a setting of the mass-spring network"),
    (["eval", "{root}/nomodel"], "no such model folder"),
    (["eval", "{model}", "--realisation", "baseline"], "trained with the digital"),
    (["eval", "{model}", "--data", "{root}/nowhere"], "no such data folder"),
])
def test_bad_input_exits_1_with_a_message(env, tmp_path, args, message):
    data, model, _ = env
    args = [a.format(root=tmp_path, data=data, model=model) for a in args]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 1, result.output
    assert message in result.output
    assert "Traceback" not in result.output and "INTERNAL" not in result.output
    assert not (tmp_path / "m").exists()


def test_eval_of_a_model_missing_weights(env, tmp_path):
    import shutil

    data, model, _ = env
    shutil.copytree(model, tmp_path / "m2")
    (tmp_path / "m2" / "weights.npz").unlink()
    result = CliRunner().invoke(main, ["eval", str(tmp_path / "m2")])
    assert result.exit_code == 1
    assert "weights.npz: missing from the model folder" in result.output


def test_energy_budget_of_a_digital_model_is_a_user_error(env):
    data, model, _ = env
    result = CliRunner().invoke(main, ["eval", str(model), "--data", str(data), "--budget", "2"])
    assert result.exit_code == 1
    assert "the energy budget needs a mass-spring or router model" in result.output
    assert "Traceback" not in result.output
