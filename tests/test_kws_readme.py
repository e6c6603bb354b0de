"""A model folder's README.md: its data, settings and accuracy table agree with settings.json
and report.json, and the training command it prints reproduces the model."""

from __future__ import annotations

import json
import shlex

import numpy as np
import pytest
from click.testing import CliRunner

from springc.kws.features.digital import FeatureSettings
from springc.kws.training.readme import train_arguments
from springc.kws.training.train import TrainOptions, train
from springc_cli.main import main
from kws_corpora import corpus_and_model


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    root = tmp_path_factory.mktemp("readme")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("SPRINGC_CACHE", str(root / "cache"))
        data, model = corpus_and_model(root, "--td", "0.064", "--protocol", "lists",
                                       "--class-weights", "none", "--seed", "3")
        yield root, data, model


def section(text: str, title: str) -> str:
    return text.split(f"## {title}\n", 1)[1].split("\n## ", 1)[0]


def test_the_readme_holds_the_data_settings_and_table(env):
    _, data, model = env
    text = (model / "README.md").read_text()
    settings = json.loads((model / "settings.json").read_text())
    report = json.loads((model / "report.json").read_text())
    assert text.startswith("# Keyword spotter: digital, 4 bins x 2 delays\n")
    assert f"test accuracy {100 * report['accuracy']:.2f}% on {report['n']} clips" in text
    assert f"`{data.resolve()}`" in section(text, "Data")
    assert "protocol `lists`, class weights `equal`, seed 3" in text
    assert "td 0.064" in section(text, "Settings") and f"C = {settings['C']}" in text
    rows = [r for r in section(text, "Accuracy on the test split").splitlines()
            if r.startswith("| `")]
    conf = np.array(report["confusion"])
    assert len(rows) == len(report["classes"])
    for row, c, counts in zip(rows, report["classes"], conf):
        cells = [x.strip() for x in row.strip("|").split("|")]
        assert cells[:3] == [f"`{c}`", str(counts.sum()), str(counts[report["classes"].index(c)])]
    assert sorted(p.name for p in model.iterdir()) == sorted(
        line.split("`")[1] for line in section(text, "Files").splitlines() if line)


def test_the_printed_command_reproduces_the_model(env, tmp_path):
    """Run the README's `springc train` line with another output folder: same settings
    (but the folder), same weights, same report."""
    _, _, model = env
    text = (model / "README.md").read_text()
    (line,) = [x for x in text.splitlines() if x.startswith("springc train ")]
    args = shlex.split(line)[1:]
    assert args[-2:] == ["-o", str(model)]
    again = tmp_path / "again"
    result = CliRunner().invoke(main, [*args[:-1], str(again), "-j", "1"])
    assert result.exit_code == 0, result.output
    for name in ("settings.json", "report.json"):
        old, new = (json.loads((m / name).read_text()) for m in (model, again))
        old.pop("seconds", None), new.pop("seconds", None)
        assert old == new, name
    with np.load(model / "weights.npz") as a, np.load(again / "weights.npz") as b:
        assert set(a) == set(b) and all(np.array_equal(a[k], b[k]) for k in a)


def test_settings_without_an_option_are_named(env, tmp_path):
    """A model trained through the library with a setting `springc train` cannot give
    (here fmin) lists it beside the command rather than printing a command that differs."""
    _, data, _ = env
    out = tmp_path / "m"
    train(TrainOptions(data=data, out=out, settings=FeatureSettings(bins=4, delays=2,
                                                                    fmin=100.0), jobs=1))
    text = (out / "README.md").read_text()
    assert "Settings `springc train` has no option for" in text and "fmin = 100.0" in text
    settings = json.loads((out / "settings.json").read_text())
    assert train_arguments(settings)[1] == {"fmin": 100.0}


def test_a_model_without_test_results_says_so(env, tmp_path):
    """A report without test results (`tune` with evaluate off) writes a folder whose README
    says it is not evaluated, and no confusion files that would have nothing to show."""
    from springc.kws.training.model import load_model, write_model

    _, _, model = env
    m = load_model(model)
    settings = json.loads((model / "settings.json").read_text())
    fits = [(classes, fit, settings["C"]) for classes, fit in m.models]
    out = tmp_path / "unevaluated"
    write_model(out, settings, fits, {"note": "no test split"})
    text = (out / "README.md").read_text()
    assert "not evaluated on the test split" in text
    assert "Not evaluated on the test split" in section(text, "Accuracy on the test split")
    assert sorted(p.name for p in out.iterdir()) == ["README.md", "report.json",
                                                    "settings.json", "weights.npz"]


def test_stage_stiffness_and_squarer_range_have_their_options():
    """A mass-spring model trained with `--squarer-range 1 --stage-stiffness 100` prints
    both options, and nothing beside the command; klp alone changed is no stage stiffness
    and is named beside it instead."""
    from dataclasses import replace

    from springc.kws.features import massspring as msp

    base = msp.from_features(FeatureSettings(bins=4, delays=2), squarer_range=1.0)
    settings = {"realisation": "mass-spring", "task": "kws12", "transfer": {"epsilon": 1e-5},
                "features": msp.stage_scaled(base, 100.0).to_dict()}
    args, missing = train_arguments(settings)
    assert " ".join(args).endswith("--threshold 0.001 --squarer-range 1 "
                                   "--stage-stiffness 100 --epsilon 1e-05 --paper-steps")
    assert missing == {}
    settings["features"] = replace(base, klp=1000.0).to_dict()
    args, missing = train_arguments(settings)
    assert "--stage-stiffness" not in args and missing == {"klp": 1000.0}


@pytest.mark.parametrize("realisation, design, epsilon, scale, heads", [
    ("device", {"heads": "summing", "mvm_stiffness": 1.0, "buffer": None}, 1e-5,
     {"spl": 60.0, "area": 1e-6, "temp": 300.0, "device_mass": 2e-9}, []),
    ("mass-spring", {"heads": "summing", "mvm_stiffness": 1.0, "buffer": None}, 1e-5, None,
     ["--heads", "summing"]),
    ("mass-spring", {"heads": "zero-mode", "mvm_stiffness": 10.0,
                     "buffer": {"kb": 6e-5, "kg": 1e4}}, 1e-6, None,
     ["--heads", "zero-mode", "--mvm-stiffness", "10", "--buffer", "6e-05", "10000"]),
    ("mass-spring", {"heads": "zero-mode", "mvm_stiffness": 10.0,
                     "buffer": {"kb": 6e-5, "kg": 1e4}}, 1.0, None, []),
])
def test_the_printed_options_rebuild_the_design_and_the_scale(realisation, design, epsilon,
                                                               scale, heads):
    """The heads and the physical scale a model records come back from the README's train
    line: its options, read as `springc train` reads them, give the same design and scale
    (a device model: `--realisation device` and its scale; heads named only where the
    realisation and epsilon would not choose them by themselves)."""
    from springc.kws.evaluation.api import _design
    from springc.kws.features import massspring as msp
    from springc.kws.training.transfer import Design, default_design

    features = msp.from_features(FeatureSettings(bins=4, delays=2)).to_dict()
    settings = {"realisation": "mass-spring", "task": "kws12", "features": features,
                "transfer": {"epsilon": epsilon, "design": design},
                **({"device": scale} if scale else {})}
    args, missing = train_arguments(settings)
    assert missing == {}
    opts = dict(zip(args[::2], args[1::2]))
    assert opts["--realisation"] == realisation
    value = lambda name: float(opts[name]) if name in opts else None  # noqa: E731
    given = {k: value("--" + k.replace("_", "-"))
             for k in ("spl", "area", "temp", "device_mass")}
    at = args.index("--epsilon") + 2
    assert args[at:at + len(heads)] == heads
    # --buffer takes two values: read them by position
    buffer = (tuple(float(v) for v in args[args.index("--buffer") + 1:][:2])
              if "--buffer" in args else None)
    built, physical = _design(realisation, value("--epsilon"), opts.get("--heads"), buffer,
                              value("--mvm-stiffness"), given)
    assert (built or default_design(epsilon)) == Design.from_dict(design)
    assert physical == scale


def test_a_design_no_option_gives_is_named():
    """Unbuffered zero-mode heads at an epsilon whose default is buffered: no option of
    `springc train` builds them, so the design is named beside the command."""
    from springc.kws.features import massspring as msp

    design = {"heads": "zero-mode", "mvm_stiffness": 1.0, "buffer": None}
    settings = {"realisation": "mass-spring", "task": "kws12",
                "features": msp.from_features(FeatureSettings(bins=4, delays=2)).to_dict(),
                "transfer": {"epsilon": 1.0, "design": design}}
    args, missing = train_arguments(settings)
    assert "--heads" not in args and missing == {"design": design}
