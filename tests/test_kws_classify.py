"""`springc classify MODEL INPUT...` on single files and folders (digital models): the scores
are the decision values eval computes for the same clips, the labels its predictions, and
every bad input is a named user error that leaves nothing behind. The mass-spring network and
`--stream` are in tests/test_kws_stream.py."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from click.testing import CliRunner

from springc.kws.evaluation.classify import classify, sound_files
from springc.kws.features.digital import FeatureSettings
from springc.kws.training.model import load_model
from springc.kws.data.task import open_task_data
from springc.kws.training.train import feature_matrices
from springc_cli.main import main
from kws_corpora import RATE, make_corpus, word_sound


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    """A tiny corpus, a 4 x 2 digital kws12 model, a digits-pairs model and the log-Mel
    baseline (seconds)."""
    root = tmp_path_factory.mktemp("classify")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("SPRINGC_CACHE", str(root / "cache"))
        data = make_corpus(root / "data")
        digits = make_corpus(root / "digits", words=("one", "two", "three", "four"),
                             per_speaker=1)
        for folder, model, task in ((data, "model", "kws12"), (digits, "pairs", "digits-pairs"),
                                    (data, "baseline", "kws12")):
            result = CliRunner().invoke(main, ["train", "--data", str(folder), "-n", "4", "-m",
                                               "2", "-j", "1", "--task", task, "-o",
                                               str(root / model), "--realisation",
                                               "baseline" if model == "baseline" else "digital"])
            assert result.exit_code == 0, result.output
        yield root, data


def run(*args) -> tuple[int, str, object]:
    result = CliRunner().invoke(main, ["classify", *map(str, args)])
    return result.exit_code, result.output, result


def eval_decisions(model_dir: Path, data: Path, task: str = "kws12") -> dict[str, np.ndarray]:
    """{file: decision rows} of the test split's word clips as eval computes them: its clip
    loading, feature extraction (and cache) and the model's decision."""
    model = load_model(model_dir)
    ds = open_task_data(data, task, protocol="lists", splits=("test",))
    clips = [c for c in ds.split("test") if c.label != "_silence_"]
    feats = {k: v for k, v in model.settings["features"].items() if k != "realisation"}
    x = feature_matrices(clips, "test", "digital", [FeatureSettings(**feats)], noise_files=[],
                         jobs=1)[0]
    rows = np.concatenate([m.decision(x) for _, m in model.models], axis=1)
    return {str(c.path): r for c, r in zip(clips, rows)}


def test_scores_are_the_decisions_eval_computes(env):
    """Every test clip given as a file: its scores are eval's decision rows for it, its label
    the model's prediction, and the share of right labels eval's accuracy on those clips."""
    root, data = env
    want = eval_decisions(root / "model", data)
    code, output, result = run(root / "model", *want, "--json")
    assert code == 0, output
    got = json.loads(result.stdout)
    assert [g["file"] for g in got] == list(want)
    classes = list(load_model(root / "model").models[0][0])
    right = 0
    for g in got:
        d = want[g["file"]]
        assert list(g["scores"]) == classes
        np.testing.assert_allclose([g["scores"][c] for c in classes], d, rtol=1e-9, atol=1e-12)
        assert g["label"] == classes[int(np.argmax(d))]
        right += g["label"] == {"cat": "_unknown_"}.get(Path(g["file"]).parent.name,
                                                        Path(g["file"]).parent.name)
    assert right == 9  # eval: 100% on the 9 test word clips of this corpus


def test_the_baseline_scores_its_log_mel_features(env):
    """The log-Mel baseline classifies clips too: its scores are its logistic regression's
    decisions on the features training computes (float32, as cached)."""
    from springc.kws.features.baseline import baseline_features
    from springc.kws.data.dataset import SAMPLE_RATE, load_clip

    root, data = env
    model = load_model(root / "baseline")
    clips = [c for c in open_task_data(data, "kws12", protocol="lists", splits=("test",))
             .split("test") if c.label != "_silence_"]
    x = baseline_features(np.stack([load_clip(c) for c in clips]), SAMPLE_RATE)
    want = model.models[0][1].decision(x.astype(np.float32))
    got = classify(root / "baseline", [c.path for c in clips])
    classes = list(model.models[0][0])
    for g, d in zip(got, want):
        np.testing.assert_allclose([g["scores"][c] for c in classes], d, rtol=1e-9)


def test_a_folder_is_every_sound_file_under_it(env, tmp_path):
    """Folders are searched recursively (sorted), the noise folder and other files left out;
    the results equal naming the files."""
    root, data = env
    folder = tmp_path / "in"
    shutil.copytree(data / "yes", folder / "yes")
    shutil.copytree(data / "_background_noise_", folder / "_background_noise_")
    (folder / "notes.txt").write_text("not a sound\n")
    files = sorted((folder / "yes").glob("*.wav"))
    assert sound_files([folder]) == files
    assert classify(root / "model", [folder]) == classify(root / "model", files)


def test_the_text_output_names_each_file_and_label(env):
    root, data = env
    path = data / "no" / "1a2b3c47_nohash_0.wav"
    code, output, result = run(root / "model", path)
    assert code == 0, output
    first, second = result.stdout.splitlines()
    assert first == f"{path}: no"
    values = [float(v) for v in second.split()[1::2]]
    assert second.split()[0] == "no" and values == sorted(values, reverse=True)


def test_a_long_file_is_cut_to_a_clip_with_a_warning(env, tmp_path, caplog):
    """Without --stream a recording longer than a clip is its first second (as data sets
    read clips), and the user is told."""
    root, data = env
    x, _ = sf.read(data / "yes" / "1a2b3c47_nohash_0.wav")
    sf.write(tmp_path / "long.wav", np.concatenate([x, 0.5 * x]), RATE, subtype="PCM_16")
    sf.write(tmp_path / "short.wav", x, RATE, subtype="PCM_16")
    long, short = classify(root / "model", [tmp_path / "long.wav", tmp_path / "short.wav"])
    assert long["scores"] == short["scores"]
    assert any("long.wav: 2.00 s long; its first 1 s is classified" in m
               for m in caplog.messages)


def test_conversions_match_the_data_set_reader(env, tmp_path, caplog):
    """A stereo file is its first channel and a 32 kHz file is resampled, each warned: the
    scores are those of the plain 16 kHz mono file within the resampler's error."""
    from springc.sim.audio import resample

    root, data = env
    x, _ = sf.read(data / "yes" / "1a2b3c47_nohash_0.wav")
    sf.write(tmp_path / "mono.wav", x, RATE, subtype="FLOAT")
    sf.write(tmp_path / "stereo.wav", np.stack([x, -x], axis=1), RATE, subtype="FLOAT")
    sf.write(tmp_path / "fast.wav", resample(x, RATE, 2 * RATE), 2 * RATE, subtype="FLOAT")
    mono, stereo, fast = classify(root / "model", [tmp_path / n for n in
                                                   ("mono.wav", "stereo.wav", "fast.wav")])
    assert stereo["scores"] == mono["scores"]
    for c, v in mono["scores"].items():
        assert fast["scores"][c] == pytest.approx(v, rel=1e-2, abs=1e-2)
    assert any("stereo.wav: has 2 channels; the first is used" in m for m in caplog.messages)
    assert any("fast.wav: is at 32000 Hz; resampled" in m for m in caplog.messages)


def test_a_digit_pairs_model_votes(env):
    """Digit pairs: the scores are each word's summed margins over its pairs, the label the
    word winning most pairs; the pairs' decisions are eval's rows."""
    root, _ = env
    want = eval_decisions(root / "pairs", root / "digits", "digits-pairs")
    got = classify(root / "pairs", list(want))
    pairs = ["-".join(classes) for classes, _ in load_model(root / "pairs").models]
    assert len(pairs) == 6  # each "a-b": positive decisions for b
    for g in got:
        d = dict(zip(pairs, want[g["file"]]))
        assert list(g["pairs"]) == pairs
        np.testing.assert_allclose(list(g["pairs"].values()), list(d.values()), rtol=1e-9)
        for word in ("one", "two", "three", "four"):
            margin = sum(v if pair.split("-")[1] == word else -v
                         for pair, v in d.items() if word in pair.split("-"))
            assert g["scores"][word] == pytest.approx(margin)
        wins = {w: sum(1 for p, v in d.items() if w in p.split("-")
                       and (v > 0) == (p.split("-")[1] == w)) for w in g["scores"]}
        assert wins[g["label"]] == max(wins.values())
    right = sum(g["label"] == Path(g["file"]).parent.name for g in got)
    assert right >= 3  # of the 4 test clips (one per digit)


def _wav(path: Path, x: np.ndarray, rate: int = RATE, subtype: str = "PCM_16") -> Path:
    sf.write(path, x, rate, subtype=subtype)
    return path


def _inputs(k: Path) -> dict[str, Path]:
    """Bad inputs, made in `k`."""
    rng = np.random.default_rng(0)
    nan = word_sound("yes", rng)
    nan[100] = np.nan
    (k / "empty-folder").mkdir()
    (k / "text-folder").mkdir()
    (k / "text-folder" / "notes.txt").write_text("words\n")
    (k / "notes.txt").write_text("words\n")
    (k / "cut.wav").write_bytes(b"RIFF")
    (k / "a-file").write_text("not a folder\n")
    sf.write(k / "empty.wav", np.zeros(0), RATE)
    return {"good": _wav(k / "good.wav", word_sound("yes", rng)),
            "nan": _wav(k / "nan.wav", nan, subtype="FLOAT"),
            "slow": _wav(k / "slow.wav", np.zeros(10), rate=1),
            "absent": k / "absent.wav", "empty-folder": k / "empty-folder",
            "text-folder": k / "text-folder", "notes": k / "notes.txt", "cut": k / "cut.wav",
            "empty": k / "empty.wav", "a-file": k / "a-file"}


# name: (arguments, with {model}, {pairs}, {root} and the inputs' names in braces; message)
BAD = {
    "no model": (["{root}/nomodel", "{good}"], "nomodel: no such model folder"),
    "no such input": (["{model}", "{good}", "{absent}"], "absent.wav: no such file or folder"),
    "empty folder": (["{model}", "{empty-folder}"], "empty-folder: holds no sound file"),
    "folder of text": (["{model}", "{text-folder}"], "text-folder: holds no sound file"),
    "not a sound file": (["{model}", "{notes}"], "notes.txt: not a sound file"),
    "cut wav": (["{model}", "{good}", "{cut}"], "cut.wav: cannot read as audio"),
    "no samples": (["{model}", "{empty}"], "empty.wav: the file holds no samples"),
    "NaN sample": (["{model}", "{nan}"], "nan.wav: sample 100 of channel 0"),
    "1 Hz": (["{model}", "{slow}"], "slow.wav: sample rate 1 Hz is below 8000 Hz"),
    "other realisation": (["{model}", "{good}", "--realisation", "mass-spring"],
                          "trained with the digital realisation; it cannot be classified "
                          "with --realisation mass-spring"),
    "plots without stream": (["{model}", "{good}", "--plots", "{root}/p"],
                             "--plots draws the decisions through a streamed recording"),
    "plots is a file": (["{model}", "{good}", "--stream", "--plots", "{a-file}"],
                        "a-file: is a file, not a folder for the plots"),
    "plots under a file": (["{model}", "{good}", "--stream", "--plots", "{a-file}/p"],
                           "is a file, not a folder"),
    "stream a pairs model": (["{pairs}", "{good}", "--stream"],
                             "model of binary classifiers: they have no class for silence"),
    "stream the baseline": (["{baseline}", "{good}", "--stream"],
                            "is the log-Mel baseline: its features depend on where a word"),
    "stream a bad file": (["{model}", "{good}", "{cut}", "--stream", "--plots", "{root}/p"],
                          "cut.wav: cannot read as audio"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_input_is_a_named_user_error(env, tmp_path, case):
    root, _ = env
    names = {"model": root / "model", "pairs": root / "pairs", "baseline": root / "baseline",
             "root": tmp_path,
             **_inputs(tmp_path)}
    args, message = BAD[case]
    code, output, _ = run(*[a.format(**names) for a in args])
    assert code == 1, output
    assert message in output
    assert "Traceback" not in output and "INTERNAL" not in output
    assert not (tmp_path / "p").exists()  # no plot folder, no half-written output
    assert "streaming" not in output  # every file is checked before the first is streamed
