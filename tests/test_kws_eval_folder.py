"""`springc eval MODEL --data DIR` on any labelled folder: without split lists every clip is a
test clip, a testing list alone is enough, only the test split is read and balanced, words
map to classes as the task maps them, `--protocol` as `train` has it, and every folder that
cannot be evaluated is a named user error."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from click.testing import CliRunner

from springc.kws.data.dataset import open_dataset
from springc.kws.training.model import load_model
from springc.kws.data.task import targets
from springc.kws.training.train import feature_matrices
from springc_cli.main import main
from kws_corpora import RATE, SPEAKERS, corpus_and_model, make_corpus, word_sound

TEST_SPEAKER = SPEAKERS[7]  # the speaker make_corpus lists in testing_list.txt


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    """A tiny corpus and a 4 x 2 digital model trained on it (seconds)."""
    root = tmp_path_factory.mktemp("evalfolder")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("SPRINGC_CACHE", str(root / "cache"))
        yield corpus_and_model(root)


def evaluate(model: Path, data: Path, *extra: str) -> dict:
    result = CliRunner().invoke(main, ["eval", str(model), "--data", str(data), "--json",
                                       "-j", "1", *extra])
    assert result.exit_code == 0, result.output
    return json.loads(result.stdout)


def copy_clips(root: Path, data: Path, words=("yes", "no", "cat"), noise: bool = True,
                speaker: str = TEST_SPEAKER) -> Path:
    """A folder of one speaker's clips of `words` copied from `data`, with no split list."""
    for word in words:
        (root / word).mkdir(parents=True)
        for path in sorted((data / word).glob(f"{speaker}_*.wav")):
            shutil.copy(path, root / word / path.name)
    if noise:
        shutil.copytree(data / "_background_noise_", root / "_background_noise_")
    return root


@pytest.mark.parametrize("protocol", ["balanced", "lists"])
def test_a_folder_without_lists_is_all_test_clips(env, tmp_path, protocol):
    """The test speaker's clips and the noise, copied without any split list, evaluate to
    exactly the report of the training folder's test split: same clips, same silence windows
    (cut from the noise files' test part), same decisions."""
    data, model = env
    folder = copy_clips(tmp_path / "t", data)
    assert not (folder / "testing_list.txt").exists()
    got, want = (evaluate(model, d, "--protocol", protocol) for d in (folder, data))
    assert got == want
    assert got["n"] == (12 if protocol == "balanced" else 10)  # 9 words + 3 or 1 silence


def test_a_testing_list_alone_selects_the_test_clips(env, tmp_path):
    """Clips the testing list does not name are not test clips; no validation list needed."""
    data, model = env
    folder = copy_clips(tmp_path / "t", data)
    copy_clips(tmp_path / "t", data, words=("up",), noise=False, speaker=SPEAKERS[0])
    (folder / "testing_list.txt").write_text((data / "testing_list.txt").read_text())
    assert evaluate(model, folder) == evaluate(model, data)


def test_eval_decisions_are_the_models_on_the_test_clips(env, tmp_path):
    """The reference: accuracy and per-class rates from the model's own decisions on the
    features of the folder's clips, every clip a test clip."""
    data, model = env
    folder = copy_clips(tmp_path / "t", data, noise=False)
    clips = open_dataset(folder, splits=("test",)).split("test")
    assert len(clips) == 9 and {c.split for c in clips} == {"test"}
    m = load_model(model)
    x = feature_matrices(clips, "test", "digital", [_settings(m)], noise_files=[], jobs=1)[0]
    predicted = m.models[0][1].predict(x)
    truth = targets(clips, "kws12")
    got = evaluate(model, folder, "--protocol", "lists")
    assert got["n"] == 9 and got["accuracy"] == pytest.approx(np.mean(predicted == truth))
    for label in ("yes", "no", "_unknown_"):
        rate = np.mean(predicted[truth == label] == label)
        assert got["per_class"][label] == pytest.approx(rate)


def _settings(model):
    from springc.kws.features.digital import FeatureSettings

    feats = {k: v for k, v in model.settings["features"].items() if k != "realisation"}
    return FeatureSettings(**feats)


def test_other_words_map_as_the_task_maps_them(env, tmp_path):
    """A GSCD word the model never heard (`four`) and a folder that is no GSCD word
    (`hello`) are `_unknown_`; a command it never heard (`up`) is its own class, scored as
    a miss (the model cannot answer it)."""
    data, model = env
    folder = tmp_path / "t"
    rng = np.random.default_rng(5)
    for word, sound in (("four", "four"), ("hello", "cat"), ("up", "up"), ("yes", "yes")):
        (folder / word).mkdir(parents=True)
        for k in range(2):
            sf.write(folder / word / f"abc_nohash_{k}.wav", word_sound(sound, rng), RATE)
    got = evaluate(model, folder, "--protocol", "lists")
    assert got["n"] == 8
    assert set(got["per_class"]) == {"yes", "no", "_unknown_", "_silence_", "up"}
    assert got["per_class"]["up"] == 0.0 and got["per_class"]["no"] is None


def test_a_validation_split_without_commands_no_longer_matters(env, tmp_path):
    """The issue's third refusal: clips in every split, but the validation list names no
    command clip. Only the test split is balanced now."""
    data, model = env
    folder = tmp_path / "t"
    shutil.copytree(data, folder)
    cats = [e for e in (data / "validation_list.txt").read_text().split() if e.startswith("cat")]
    (folder / "validation_list.txt").write_text("\n".join(cats) + "\n")
    assert evaluate(model, folder) == evaluate(model, data)


def test_the_human_summary_names_the_clips(env, tmp_path, caplog):
    data, model = env
    folder = copy_clips(tmp_path / "t", data, noise=False)
    result = CliRunner().invoke(main, ["eval", str(model), "--data", str(folder), "-j", "1"])
    assert result.exit_code == 0, result.output
    assert "test accuracy" in result.stdout and "on 9 clips" in result.stdout
    # the folder lacks the noise: said once, for the silence clips only (no augmentation here)
    warned = [m for m in caplog.messages if "no background-noise folder" in m]
    assert len(warned) == 1 and warned[0].endswith("no background-noise folder; no _silence_ "
                                                   "clips")


def _only_cats(root: Path, data: Path) -> Path:
    return copy_clips(root, data, words=("cat",), noise=False)


def _empty_list(root: Path, data: Path) -> Path:
    folder = copy_clips(root, data, noise=False)
    (folder / "testing_list.txt").write_text("\n")
    return folder


def _list_folder(root: Path, data: Path) -> Path:
    folder = copy_clips(root, data, noise=False)
    (folder / "testing_list.txt").mkdir()
    return folder


def _bad_line(root: Path, data: Path) -> Path:
    folder = copy_clips(root, data, noise=False)
    (folder / "testing_list.txt").write_text(f"yes/{TEST_SPEAKER}_nohash_0.wav\nnot a path\n")
    return folder


def _in_both(root: Path, data: Path) -> Path:
    folder = copy_clips(root, data, noise=False)
    entry = f"yes/{TEST_SPEAKER}_nohash_0.wav\n"
    (folder / "testing_list.txt").write_text(entry)
    (folder / "validation_list.txt").write_text(entry)
    return folder


def _no_words(root: Path, data: Path) -> Path:
    (root / "_background_noise_").mkdir(parents=True)
    return root


def _broken_clips(root: Path, data: Path) -> Path:
    (root / "yes").mkdir(parents=True)
    (root / "yes" / "a_nohash_0.wav").write_bytes(b"RIFF")
    return root


# (folder maker, extra arguments, text of the message, hint)
BAD = {
    "no command to balance": (_only_cats, [], "the test split holds no command clip, so it "
                              "cannot be balanced", "--protocol lists"),
    "empty testing list": (_empty_list, [], "the test split of task kws12 holds no clips",
                           "testing_list.txt names the test clips"),
    "testing list is a folder": (_list_folder, [], "testing_list.txt: is a folder, not a "
                                 "split list", ""),
    "malformed testing list": (_bad_line, [], "testing_list.txt:2: expected 'word/file.wav'",
                               ""),
    "a clip in both lists": (_in_both, [], "is also in validation_list.txt", ""),
    "no word folders": (_no_words, [], "no word folders", ""),
    "no usable clip": (_broken_clips, [], "no usable sound file in the word folders", ""),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_a_folder_that_cannot_be_evaluated_is_a_named_error(env, tmp_path, case):
    data, model = env
    make, extra, message, hint = BAD[case]
    folder = make(tmp_path / "t", data)
    result = CliRunner().invoke(main, ["eval", str(model), "--data", str(folder), "-j", "1",
                                       *extra])
    assert result.exit_code == 1, result.output
    assert message in result.output and hint in result.output
    assert str(tmp_path / "t") in result.output
    assert "Traceback" not in result.output and "INTERNAL" not in result.output


def test_only_cats_evaluate_as_listed(env, tmp_path):
    """The hint of the refusal above works: `--protocol lists` evaluates the same folder."""
    data, model = env
    got = evaluate(model, _only_cats(tmp_path / "t", data), "--protocol", "lists")
    assert got["n"] == 3 and set(k for k, v in got["per_class"].items() if v is not None) == {
        "_unknown_"}


def test_a_digit_pairs_model_on_a_folder_without_digits(env, tmp_path):
    """A digits-pairs model reads only one/two/three/four: a folder of other words holds no
    test clip of its task, and the message says which words it reads; the balanced protocol
    is refused for it with the option that works."""
    data, _ = env
    digits = make_corpus(tmp_path / "digits", words=("one", "two", "three", "four"),
                         per_speaker=2)
    model = tmp_path / "pairs"
    result = CliRunner().invoke(main, ["train", "--data", str(digits), "-n", "4", "-m", "2",
                                       "-j", "1", "--task", "digits-pairs", "-o", str(model)])
    assert result.exit_code == 0, result.output
    folder = copy_clips(tmp_path / "t", data, noise=False)
    result = CliRunner().invoke(main, ["eval", str(model), "--data", str(folder), "-j", "1"])
    assert result.exit_code == 1
    assert "the test split of task digits-pairs holds no clips" in result.output
    assert "digits-pairs reads the words one, two, three, four" in result.output
    result = CliRunner().invoke(main, ["eval", str(model), "--data", str(digits), "-j", "1",
                                       "--protocol", "balanced"])
    assert result.exit_code == 1
    assert "the balanced protocol is for the kws12 task" in result.output
    assert "--protocol lists" in result.output
    saved = json.loads((model / "report.json").read_text())
    assert evaluate(model, digits)["accuracy"] == saved["accuracy"]
