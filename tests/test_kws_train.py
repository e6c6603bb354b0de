"""Training and evaluation end to end on tiny generated GSCD-layout corpora (tones and chirps
as "words"), the model folder, the feature cache and every bad-input path."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from springc.errors import DataError, UsageError
from springc.kws.features.digital import FeatureSettings
from springc.kws.training.svm import SVM_GRID
from springc.kws.training.train import TrainOptions, train

from kws_corpora import make_corpus


@pytest.fixture(autouse=True, scope="module")
def _cache(tmp_path_factory):
    """One feature cache for the module: tests reuse each other's features."""
    import os

    old = os.environ.get("SPRINGC_CACHE")
    os.environ["SPRINGC_CACHE"] = str(tmp_path_factory.mktemp("cache"))
    yield
    if old is None:
        os.environ.pop("SPRINGC_CACHE")
    else:
        os.environ["SPRINGC_CACHE"] = old


@pytest.fixture(scope="module")
def corpus(tmp_path_factory) -> Path:
    return make_corpus(tmp_path_factory.mktemp("corpus") / "data")


def _opts(data: Path, out: Path, **kw) -> TrainOptions:
    settings = FeatureSettings(bins=kw.pop("bins", 4), delays=kw.pop("delays", 2))
    return TrainOptions(data=data, out=out, settings=settings, jobs=kw.pop("jobs", 1), **kw)


def test_train_writes_a_complete_model_that_classifies_the_words(corpus, tmp_path):
    report = train(_opts(corpus, tmp_path / "model"))
    folder = tmp_path / "model"
    for name in ("settings.json", "weights.npz", "report.json", "confusion.csv",
                 "confusion.png", "per_class.csv"):
        assert (folder / name).is_file(), name
    settings = json.loads((folder / "settings.json").read_text())
    assert settings["features"]["bins"] == 4 and settings["features"]["delays"] == 2
    assert settings["features"]["td"] == 0.032 and settings["features"]["tau"] == 80.0
    assert settings["C"] in SVM_GRID
    assert set(settings["dataset"]["fingerprint"]) == {"train", "validation", "test"}
    assert report["n"] == 3 * 3 + _silence(report)  # 3 words x 3 clips of the test speaker
    assert report["accuracy"] >= 0.9
    assert json.loads((folder / "report.json").read_text())["accuracy"] == report["accuracy"]
    assert not list(tmp_path.glob(".model.tmp*"))


def _silence(report: dict) -> int:
    classes = report["classes"]
    return int(np.array(report["confusion"])[classes.index("_silence_")].sum()) \
        if "_silence_" in classes else 0


def test_kws12_defaults_to_balanced_splits_and_class_weights(corpus, tmp_path):
    """The test split holds 3 clips of each class (yes, no, _unknown_, _silence_); the
    training split keeps all of its clips; settings.json and the report say so."""
    report = train(_opts(corpus, tmp_path / "model"))
    settings = json.loads((tmp_path / "model" / "settings.json").read_text())
    assert settings["protocol"] == "balanced" and settings["class_weight"] == "balanced"
    assert report["protocol"] == "balanced" and report["class_weight"] == "balanced"
    for split in ("validation", "test"):
        present = {k: v for k, v in report["counts"][split].items() if v}
        assert present == {"yes": 3, "no": 3, "_unknown_": 3, "_silence_": 3}
    assert report["counts"]["train"]["yes"] == 6 * 3
    assert report["majority_rate"] == 0.25 and report["n"] == 12


def test_protocol_defaults_per_task(corpus, tmp_path):
    from springc.kws.data.dataset import balanced, open_dataset
    from springc.kws.data.task import open_task_data, task_protocol, task_weights

    assert open_task_data(corpus, "kws12", 3).clips == balanced(open_dataset(corpus, seed=3),
                                                                3).clips
    assert open_task_data(corpus, "kws12", 3, "lists").clips == open_dataset(corpus,
                                                                             seed=3).clips
    assert task_protocol("digits-pairs") == "lists" and task_weights("digits-pairs") is None
    assert task_weights("kws12") == "balanced" and task_weights("kws12", False) is None
    with pytest.raises(UsageError, match="balanced protocol is for the kws12 task"):
        open_task_data(corpus, "digits-pairs", 0, "balanced")
    with pytest.raises(UsageError, match="unknown protocol"):
        open_task_data(corpus, "kws12", 0, "even")


def test_raw_lists_and_equal_weights_are_recorded(corpus, tmp_path):
    report = train(_opts(corpus, tmp_path / "m", protocol="lists", balance_weights=False))
    settings = json.loads((tmp_path / "m" / "settings.json").read_text())
    assert settings["protocol"] == "lists" and settings["class_weight"] is None
    assert report["counts"]["test"]["_silence_"] == 1  # 10 % of the 9 word clips
    assert report["n"] == 10 and report["majority_rate"] == 0.3


def test_physical_readout_of_stored_weights_reproduces_the_decision(corpus, tmp_path):
    """c . Phi + b with the raw coefficients from weights.npz gives the stored model's
    decisions on freshly computed test features."""
    from springc.kws.evaluation.evaluate import evaluate
    from springc.kws.training.model import load_model
    from springc.kws.features.phi import readout, spread
    from springc.kws.data.task import open_task_data
    from springc.kws.training.train import feature_matrices

    report = train(_opts(corpus, tmp_path / "m", bins=4, delays=3))
    model = load_model(tmp_path / "m")
    ds = open_task_data(corpus, "kws12")
    s = FeatureSettings(bins=4, delays=3)
    phi = feature_matrices(ds.split("test"), "test", "digital", [s], noise_files=[],
                           use_cache=False)[0]
    with np.load(tmp_path / "m" / "weights.npz") as w:
        coef, b, gidx = w["coef_raw"], w["intercept"], w["group_index"]
    classes, lin = model.models[0]
    assert np.allclose(readout(coef.T, phi) + b, lin.decision(phi), rtol=1e-12, atol=1e-9)
    assert np.array_equal(spread(coef[0], 4, 3), coef[0][gidx])
    assert evaluate(tmp_path / "m", jobs=1)["accuracy"] == report["accuracy"]


def test_parallel_and_cached_features_equal_serial_ones(corpus, tmp_path, monkeypatch):
    from springc.kws.features import cache
    from springc.kws.data.task import open_task_data
    from springc.kws.training.train import feature_matrices

    monkeypatch.setenv("SPRINGC_CACHE", str(tmp_path / "own-cache"))
    ds = open_task_data(corpus, "kws12")
    clips = ds.split("train")
    s = [FeatureSettings(bins=4, delays=2)]
    serial = feature_matrices(clips, "train", "digital", s, noise_files=ds.noise_files,
                              jobs=1, use_cache=False)[0]
    parallel = feature_matrices(clips, "train", "digital", s, noise_files=ds.noise_files,
                                jobs=2)[0]
    assert np.array_equal(serial, parallel)  # augmentation seeded per clip, not per worker
    assert len(list(cache.cache_root().glob("train-*.npz"))) == 1
    cached = feature_matrices(clips, "train", "digital", s, noise_files=ds.noise_files,
                              jobs=1)[0]
    assert np.array_equal(cached, serial)
    other_seed = feature_matrices(clips, "train", "digital", s, noise_files=ds.noise_files,
                                  jobs=1, seed=5)[0]
    assert not np.array_equal(other_seed, serial)  # training clips are augmented


def test_shared_pass_over_delays_matches_separate_runs(corpus):
    from springc.kws.data.task import open_task_data
    from springc.kws.training.train import feature_matrices

    ds = open_task_data(corpus, "kws12")
    clips = ds.split("test")[:4]
    s2, s4 = FeatureSettings(bins=4, delays=2), FeatureSettings(bins=4, delays=4)
    both = feature_matrices(clips, "test", "digital", [s2, s4], noise_files=[],
                            use_cache=False)
    alone = feature_matrices(clips, "test", "digital", [s2], noise_files=[], use_cache=False)
    assert np.allclose(both[0], alone[0], rtol=1e-4)
    assert both[1].shape[1] == 4 * 4 + 6 * 7


def test_digit_pairs_task_reports_each_pair(tmp_path):
    data = make_corpus(tmp_path / "digits", words=("one", "two", "three", "four"),
                       per_speaker=2)
    report = train(_opts(data, tmp_path / "pairs", task="digits-pairs"))
    assert set(report["pairs"]) == {"one-two", "one-three", "one-four", "two-three",
                                    "two-four", "three-four"}
    assert report["pairs"]["two-three"]["paper"] == 0.997
    assert all(p["n"] == 4 for p in report["pairs"].values())
    assert np.mean([p["accuracy"] for p in report["pairs"].values()]) >= 0.9
    settings = json.loads((tmp_path / "pairs" / "settings.json").read_text())
    assert set(settings["C"]) == set(report["pairs"])
    assert settings["protocol"] == "lists" and settings["class_weight"] is None
    assert report["counts"]["test"] == {"one": 2, "two": 2, "three": 2, "four": 2}


def test_baseline_trains_on_the_same_splits(corpus, tmp_path):
    report = train(_opts(corpus, tmp_path / "base", realisation="baseline", grid=(0.01,)))
    with np.load(tmp_path / "base" / "weights.npz") as w:
        assert w["coef_raw"].shape[1] == 98 * 40
    assert report["accuracy"] >= 0.8
    assert report["n"] == train(_opts(corpus, tmp_path / "dig"))["n"]


# -- bad input ----------------------------------------------------------------------------

def test_missing_data_folder(tmp_path):
    with pytest.raises(DataError, match="no such data folder"):
        train(_opts(tmp_path / "nowhere", tmp_path / "m"))


def test_empty_test_split(tmp_path):
    data = make_corpus(tmp_path / "d", words=("yes", "no"), per_speaker=1, empty_test=True)
    with pytest.raises(DataError, match="test split"):
        train(_opts(data, tmp_path / "m"))
    assert not (tmp_path / "m").exists()


def test_unknown_realisation_is_a_clear_error(corpus, tmp_path):
    with pytest.raises(UsageError, match="unknown realisation 'analog'"):
        train(_opts(corpus, tmp_path / "m", realisation="analog"))


def test_failed_training_keeps_the_previous_model(corpus, tmp_path):
    train(_opts(corpus, tmp_path / "m"))
    before = (tmp_path / "m" / "weights.npz").read_bytes()
    with pytest.raises(UsageError):
        train(_opts(corpus, tmp_path / "m", bins=1))
    assert (tmp_path / "m" / "weights.npz").read_bytes() == before


@pytest.fixture(scope="module")
def trained(corpus, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("trained") / "model"
    train(_opts(corpus, out))
    return out


@pytest.mark.parametrize("missing", ["settings.json", "weights.npz", "report.json"])
def test_model_folder_missing_a_file(trained, tmp_path, missing):
    import shutil

    from springc.kws.evaluation.evaluate import evaluate

    broken = tmp_path / "broken"
    shutil.copytree(trained, broken)
    (broken / missing).unlink()
    with pytest.raises(DataError, match=f"{missing}: missing from the model folder"):
        evaluate(broken)


def test_model_folder_with_mismatched_settings(trained, tmp_path):
    import shutil

    from springc.kws.evaluation.evaluate import evaluate

    broken = tmp_path / "broken"
    shutil.copytree(trained, broken)
    settings = json.loads((broken / "settings.json").read_text())
    settings["features"]["bins"] = 6
    (broken / "settings.json").write_text(json.dumps(settings))
    with pytest.raises(DataError, match="6 bins x 2 delays, which need N = 57"):
        evaluate(broken)


def test_eval_with_another_realisation_or_no_folder(trained, tmp_path):
    from springc.kws.evaluation.evaluate import evaluate

    with pytest.raises(UsageError, match="trained with the digital realisation"):
        evaluate(trained, realisation="baseline")
    with pytest.raises(UsageError, match="mass-spring"):
        evaluate(trained, realisation="mass-spring")
    with pytest.raises(DataError, match="no such model folder"):
        evaluate(tmp_path / "none")
    with pytest.raises(DataError, match="no such data folder"):
        evaluate(trained, data=tmp_path / "nodata")


def test_eval_on_data_with_a_class_the_model_never_saw(trained, tmp_path):
    """A test label unknown to the model is counted (TPR 0), not an internal error."""
    from springc.kws.evaluation.evaluate import evaluate

    other = make_corpus(tmp_path / "other", words=("yes", "no", "cat", "up"), per_speaker=1,
                        seed=3)
    report = evaluate(trained, data=other, jobs=1)
    assert report["per_class"]["up"] == 0.0
    assert report["n"] == 4 + _silence(report)


def test_negative_jobs_is_a_usage_error(corpus, tmp_path):
    with pytest.raises(UsageError, match="--jobs"):
        train(_opts(corpus, tmp_path / "m", jobs=-1))
