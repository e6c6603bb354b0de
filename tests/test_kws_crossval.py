"""Speaker-grouped cross-validation (`springc.kws.evaluation.crossval`) and `springc cv`."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner
from sklearn.metrics import balanced_accuracy_score
from springc_cli.main import main
from kws_corpora import make_corpus

from springc.errors import UsageError
from springc.kws.evaluation import crossval
from springc.kws.features.digital import FeatureSettings
from shared_cache import KERNELS


def test_folds_keep_each_speaker_in_one_fold_and_are_nearly_equal():
    rng = np.random.default_rng(0)
    groups = np.repeat([f"s{k}" for k in range(40)], rng.integers(1, 12, 40))
    fold = crossval.speaker_folds(groups, 5)
    for g in np.unique(groups):
        assert len(np.unique(fold[groups == g])) == 1
    sizes = np.bincount(fold, minlength=5)
    assert sizes.max() - sizes.min() <= 11  # at most one group apart (largest group 11)
    assert sizes.sum() == len(groups)


def test_too_few_speakers_for_the_folds_is_a_user_error():
    with pytest.raises(UsageError, match="at least 5 speakers"):
        crossval.speaker_folds(np.array(["a", "a", "b", "c", "d"]), 5)


def test_silence_windows_are_groups_of_their_own():
    class Clip:
        def __init__(self, label, speaker, key):
            self.label, self.speaker, self._key = label, speaker, key

        def key(self):
            return self._key

    clips = [Clip("yes", "ann", "yes/ann_0"), Clip("_silence_", "noise-white", "n@0"),
             Clip("_silence_", "noise-white", "n@16000")]
    assert crossval.speaker_groups(clips).tolist() == ["ann", "n@0", "n@16000"]


def test_balanced_accuracy_matches_scikit_learn_with_weights():
    rng = np.random.default_rng(1)
    y = rng.choice(["a", "b", "c"], 300, p=[0.6, 0.3, 0.1])
    pred = np.where(rng.random(300) < 0.7, y, rng.choice(["a", "b", "c"], 300))
    w = rng.integers(0, 3, 300).astype(float)
    got = crossval.balanced_accuracy(y, pred == y, w)
    assert got == pytest.approx(balanced_accuracy_score(y, pred, sample_weight=w), abs=1e-12)


def test_bootstrap_error_matches_the_binomial_one_for_independent_clips():
    """One clip per speaker and one class: the balanced accuracy is the mean of Bernoulli
    outcomes, whose standard error is sqrt(p (1 - p) / n)."""
    rng = np.random.default_rng(2)
    n, p = 800, 0.7
    ok = rng.random(n) < p
    y = np.array(["yes"] * n)
    boot = crossval.speaker_bootstrap(y, {"a": ok, "b": ok}, np.arange(n).astype(str), 4000)
    phat = ok.mean()
    assert boot["a"].std(ddof=1) == pytest.approx(np.sqrt(phat * (1 - phat) / n), rel=0.06)
    assert np.array_equal(boot["a"], boot["b"])  # same draws: a paired difference of 0


def test_bootstrap_over_speakers_widens_the_error_of_correlated_clips():
    """Ten clips per speaker, all right or all wrong: ten times fewer independent outcomes,
    so the error is sqrt(10) times the one for independent clips."""
    rng = np.random.default_rng(3)
    speakers = 200
    ok = np.repeat(rng.random(speakers) < 0.6, 10)
    groups = np.repeat(np.arange(speakers).astype(str), 10)
    boot = crossval.speaker_bootstrap(np.array(["x"] * len(ok)), {"a": ok}, groups, 4000)
    phat = ok.mean()
    assert boot["a"].std(ddof=1) == pytest.approx(np.sqrt(phat * (1 - phat) / speakers),
                                                  rel=0.08)


def test_a_model_never_sees_the_speaker_it_is_tested_on():
    """Features that only identify the speaker, labels drawn per speaker: a model trained on
    a clip's own speaker would get it right; speaker-disjoint folds leave chance."""
    rng = np.random.default_rng(4)
    speakers, per = 60, 6
    groups = np.repeat(np.arange(speakers), per)
    x = np.eye(speakers)[groups] + 0.01 * rng.normal(size=(speakers * per, speakers))
    y = rng.choice(["a", "b"], speakers)[groups]
    fold = crossval.speaker_folds(groups.astype(str), 5)
    pred, chosen = crossval.fold_predictions(x, y, fold, (1.0, 100.0), None)
    assert len(chosen) == 5
    assert np.mean(pred == y) < 0.7
    # the same data with the speaker's own clips in training: (near) perfect
    own = np.arange(len(y)) % per == 0  # one clip of each speaker held out
    from springc.kws.training.svm import fit_linear

    model = fit_linear(x[~own], y[~own], 100.0)
    assert np.mean(model.predict(x[own]) == y[own]) > 0.95


def test_cli_cv_on_a_small_corpus(tmp_path, monkeypatch):
    monkeypatch.setenv("SPRINGC_CACHE", str(tmp_path / "cache"))
    data = make_corpus(tmp_path / "data", per_speaker=4)
    out = tmp_path / "cv"
    result = CliRunner().invoke(main, ["cv", "--data", str(data), "-n", "4", "-m", "2",
                                       "--realisation", "digital", "-k", "4", "-j", "1",
                                       "-o", str(out)])
    assert result.exit_code == 0, result.output
    report = json.loads((out / "cv.json").read_text())
    r = report["realisations"]["digital"]
    assert report["clips"] == sum(report["fold_sizes"]) and len(r["c_per_fold"]) == 4
    assert 0.25 < r["balanced_accuracy"] <= 1 and r["se"] >= 0  # chance: 1 of 4 classes
    assert (out / "cv.png").stat().st_size > 1000
    assert f"{100 * r['balanced_accuracy']:5.1f}%" in result.output


def test_cli_cv_rejects_two_folds(tmp_path):
    result = CliRunner().invoke(main, ["cv", "--data", str(tmp_path), "-k", "2", "-o",
                                       str(tmp_path / "cv")])
    assert result.exit_code == 1
    assert "--folds must be at least 3" in result.output and "Traceback" not in result.output
    assert not (tmp_path / "cv").exists()


def test_mass_spring_features_cross_validated_beside_digital(tmp_path, monkeypatch):
    """Both realisations on the same folds: the simulated network's features separate the
    words of the small corpus (4 classes, chance 25%) and the reported gap is the paired
    difference of the two balanced accuracies, with a bootstrap interval around it."""
    monkeypatch.setenv("SPRINGC_CACHE", str(KERNELS))  # shared compiled kernels
    data = make_corpus(tmp_path / "data", per_speaker=2)
    opts = crossval.CVOptions(data=data, settings=FeatureSettings(bins=2, delays=2), folds=4,
                              jobs=1)
    report = crossval.cross_validate(opts)
    d, m = report["realisations"]["digital"], report["realisations"]["mass-spring"]
    assert m["balanced_accuracy"] > 0.6 and d["balanced_accuracy"] > 0.6
    gap = m["gap"]
    assert gap["points"] == pytest.approx(100 * (d["balanced_accuracy"] - m["balanced_accuracy"]))
    assert gap["ci95"][0] <= gap["points"] + 1e-9 and gap["points"] - 1e-9 <= gap["ci95"][1]
    assert len(m["c_per_fold"]) == 4 and "gap" not in d


def test_fold_views_are_speaker_disjoint_data_sets_of_the_same_clips(tmp_path):
    """Each view is a data set of its own (opened as any other): its test split one fold,
    its validation split the next, its training split the rest, no speaker in two of
    them, and every word clip of the corpus in exactly one view's test split."""
    from springc.kws.data.dataset import open_dataset

    data = make_corpus(tmp_path / "data", per_speaker=2)
    views = crossval.write_fold_views(data, 3, tmp_path / "views")
    words = {f"{c.path.parent.name}/{c.path.name}" for c in open_dataset(data).clips
             if c.label != "_silence_"}
    tested = []
    for view in views:
        clips = [c for c in open_dataset(view).clips if c.label != "_silence_"]
        assert {f"{c.path.parent.name}/{c.path.name}" for c in clips} == words
        speakers = {s: {c.speaker for c in clips if c.split == s}
                    for s in ("train", "validation", "test")}
        assert all(speakers.values())
        assert not speakers["train"] & speakers["test"]
        assert not speakers["train"] & speakers["validation"]
        assert not speakers["validation"] & speakers["test"]
        tested += [f"{c.path.parent.name}/{c.path.name}" for c in clips if c.split == "test"]
    assert sorted(tested) == sorted(words)
