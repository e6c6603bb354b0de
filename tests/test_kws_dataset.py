"""The GSCD-layout reader on hand-made folders: splits, the 12-class mapping, silence clips,
the balanced held-out protocol, augmentation, and every bad-input path (each reported by file
name)."""

from __future__ import annotations

import logging
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from kws_corpora import NOISE_S, finish_tree, make_gscd, tone

from springc.errors import DataError, UsageError
from springc.kws.data.dataset import (
    CLASSES,
    CLIP_SAMPLES,
    COMMANDS,
    HELD_OUT,
    NOISE_REGIONS,
    PROTOCOLS,
    SAMPLE_RATE,
    SPLITS,
    WORDS,
    Clip,
    NoiseBank,
    balanced,
    label_of,
    load_clip,
    open_dataset,
    speaker_of,
    spread_sample,
    with_protocol,
)

RATE = SAMPLE_RATE


@pytest.fixture
def gscd(tmp_path) -> Path:
    return make_gscd(tmp_path / "gscd")


def test_constants_describe_the_12_class_task():
    assert len(WORDS) == 35 and len(set(WORDS)) == 35
    assert COMMANDS == WORDS[:10]
    assert CLASSES == COMMANDS + ("_unknown_", "_silence_")
    assert label_of("yes") == "yes" and label_of("marvin") == "_unknown_"
    assert speaker_of("0a7c2a8d_nohash_3.wav") == "0a7c2a8d"


def test_splits_labels_and_speakers_follow_the_lists(gscd):
    ds = open_dataset(gscd)
    assert ds.problems == []
    words = [c for c in ds.clips if c.word != "_silence_"]
    assert len(words) == 4 * 5 * 2
    for clip in words:
        expected = {"3d4e5f60": "validation", "4e5f6071": "test"}.get(clip.speaker, "train")
        assert clip.split == expected
        assert clip.label == {"cat": "_unknown_", "zero": "_unknown_"}.get(clip.word, clip.word)
        assert clip.path.parent.name == clip.word
    assert {c.split for c in words} == {"train", "validation", "test"}
    counts = ds.counts()
    assert counts["train"]["yes"] == 6 and counts["train"]["_unknown_"] == 12
    assert counts["validation"]["no"] == 2 and counts["test"]["_unknown_"] == 4
    assert ds.noise_files == [gscd / "_background_noise_" / "white_noise.wav"]


def test_silence_clips_come_from_each_splits_own_part_of_the_noise(gscd):
    ds = open_dataset(gscd, silence_per_split=0.5, seed=3)
    n = NOISE_S * RATE
    for split in ("train", "validation", "test"):
        words = [c for c in ds.split(split) if c.word != "_silence_"]
        silence = [c for c in ds.split(split) if c.word == "_silence_"]
        assert len(silence) == round(0.5 * len(words))
        lo, hi = NOISE_REGIONS[split]
        for clip in silence:
            assert clip.label == "_silence_"
            assert lo * n <= clip.offset and clip.offset + CLIP_SAMPLES <= hi * n
            x = load_clip(clip, preprocess=False)
            noise, _ = sf.read(clip.path, start=clip.offset, frames=CLIP_SAMPLES)
            np.testing.assert_allclose(x, noise)
    again = open_dataset(gscd, silence_per_split=0.5, seed=3)
    assert again.clips == ds.clips
    assert open_dataset(gscd, silence_per_split=0.5, seed=4).clips != ds.clips


def test_clip_keys_are_stable_and_unique(gscd):
    ds = open_dataset(gscd, silence_per_split=0.5)
    keys = [c.key() for c in ds.clips]
    assert len(set(keys)) == len(keys)
    assert "yes/0a7c2a8d_nohash_0.wav@0" in keys


def test_subset_and_split(gscd):
    ds = open_dataset(gscd)
    digits = ds.subset(words=("zero",))
    assert {c.word for c in digits.clips} == {"zero"}
    assert {c.label for c in ds.subset(labels=("yes", "_silence_")).clips} == {"yes", "_silence_"}
    with pytest.raises(UsageError, match="unknown word"):
        ds.subset(words=("banana",))
    with pytest.raises(UsageError, match="unknown split"):
        ds.split("training")


def test_load_clip_pads_short_clips_and_preprocesses(tmp_path):
    root = make_gscd(tmp_path / "d")
    short = root / "yes" / "5f607182_nohash_0.wav"
    sf.write(short, tone(500, 0.5), RATE, subtype="PCM_16")
    clip = next(c for c in open_dataset(root).clips if c.path == short)
    raw = load_clip(clip, preprocess=False)
    assert raw.shape == (CLIP_SAMPLES,) and raw.dtype == np.float64
    assert np.all(raw[RATE // 2:] == 0.0)
    centred = load_clip(clip)
    e = centred ** 2
    assert np.dot(np.arange(RATE), e) / e.sum() == pytest.approx(RATE / 2, abs=0.005 * RATE)


def test_augmentation_adds_noise_to_training_clips_only(gscd):
    ds = open_dataset(gscd)
    bank = NoiseBank(ds.noise_files)
    train = ds.split("train")[0]
    clean = load_clip(train, preprocess=False)
    mixed = [load_clip(train, augment=True, rng=np.random.default_rng(i), noise=bank,
                       preprocess=False) for i in range(300)]
    noisy = np.mean([not np.array_equal(m, clean) for m in mixed])
    # Binomial(300, 0.8): 0.8 +- 4.5 standard deviations.
    assert abs(noisy - 0.8) < 4.5 * np.sqrt(0.8 * 0.2 / 300)
    gains = [np.std(m - clean) / 0.1 for m in mixed if not np.array_equal(m, clean)]
    assert 0.0 < min(gains) and max(gains) <= 0.1 * 1.05
    same = load_clip(train, augment=True, rng=np.random.default_rng(7), noise=bank)
    np.testing.assert_array_equal(same, load_clip(train, augment=True,
                                                  rng=np.random.default_rng(7), noise=bank))
    held = ds.split("validation")[0]
    np.testing.assert_array_equal(load_clip(held, augment=True, noise=bank), load_clip(held))


def test_noise_bank_plays_only_the_training_part(tmp_path):
    path = tmp_path / "steps.wav"
    # +0.5 in the training 80 %, -0.5 in the held-out 20 %.
    x = np.where(np.arange(20 * RATE) < 16 * RATE, 0.5, -0.5)
    sf.write(path, x, RATE, subtype="FLOAT")
    bank = NoiseBank([path], probability=1.0, max_gain=1.0)
    rng = np.random.default_rng(0)
    for _ in range(50):
        assert np.all(bank.mix(np.zeros(CLIP_SAMPLES), rng) >= 0.0)
    with pytest.raises(DataError, match="no noise recording"):
        sf.write(tmp_path / "short.wav", np.zeros(RATE), RATE)
        NoiseBank([tmp_path / "short.wav"])


# -- bad input ---------------------------------------------------------------------------------


def test_bad_files_are_named_and_skipped_or_converted(gscd, caplog):
    slow = gscd / "yes" / "5f607182_nohash_0.wav"
    sf.write(slow, tone(400, rate=8000), 8000, subtype="PCM_16")
    stereo = gscd / "no" / "5f607182_nohash_0.wav"
    two = np.stack([tone(400), tone(2000)], axis=1)
    sf.write(stereo, two, RATE, subtype="FLOAT")
    empty = gscd / "cat" / "5f607182_nohash_0.wav"
    sf.write(empty, np.zeros(0), RATE, subtype="PCM_16")
    garbage = gscd / "zero" / "5f607182_nohash_0.wav"
    garbage.write_bytes(b"this is not a sound file\n" * 10)
    notes = gscd / "zero" / "notes.txt"
    notes.write_text("hello")
    (gscd / "_background_noise_" / "README.md").write_text("as in GSCD: not a problem")
    with caplog.at_level(logging.WARNING, logger="springc.data"):
        ds = open_dataset(gscd)
    by_file = {Path(p.split(": ")[0]): p for p in ds.problems}
    assert "resampled" in by_file[slow] and "8000 Hz" in by_file[slow]
    assert "2 channels; the first is used" in by_file[stereo]
    assert "no samples; skipped" in by_file[empty]
    assert "cannot read as audio" in by_file[garbage] and "skipped" in by_file[garbage]
    assert "not a sound file" in by_file[notes]
    assert len(ds.problems) == 5
    for problem in ds.problems:
        assert problem in caplog.text
    paths = {c.path for c in ds.clips}
    assert slow in paths and stereo in paths and empty not in paths and garbage not in paths
    # Conversions happen on loading, with a warning naming the file.
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="springc.data"):
        x = load_clip(next(c for c in ds.clips if c.path == stereo), preprocess=False)
    np.testing.assert_allclose(x, two[:, 0], atol=1e-7)
    assert str(stereo) in caplog.text
    y = load_clip(next(c for c in ds.clips if c.path == slow), preprocess=False)
    assert y.shape == (CLIP_SAMPLES,)
    spectrum = np.abs(np.fft.rfft(y))
    assert np.argmax(spectrum) == 400  # a 400 Hz tone stays at 400 Hz after resampling


def test_loading_a_file_that_went_bad_names_it(gscd):
    clip = open_dataset(gscd).clips[0]
    clip.path.write_bytes(b"")
    with pytest.raises(DataError, match=str(clip.path)):
        load_clip(clip)


def test_missing_or_empty_folders(tmp_path):
    with pytest.raises(DataError, match="no such data folder"):
        open_dataset(tmp_path / "absent")
    (tmp_path / "file").write_text("x")
    with pytest.raises(DataError, match="not a folder"):
        open_dataset(tmp_path / "file")
    (tmp_path / "empty" / "_background_noise_").mkdir(parents=True)
    with pytest.raises(DataError, match="no word folders"):
        open_dataset(tmp_path / "empty")


def test_missing_noise_folder_is_a_problem_not_an_error(gscd):
    for f in (gscd / "_background_noise_").iterdir():
        f.unlink()
    (gscd / "_background_noise_").rmdir()
    ds = open_dataset(gscd)
    assert ds.noise_files == [] and not any(c.word == "_silence_" for c in ds.clips)
    assert any("no background-noise folder" in p for p in ds.problems)


def test_missing_split_list_is_named(gscd):
    (gscd / "testing_list.txt").unlink()
    with pytest.raises(DataError) as err:
        open_dataset(gscd)
    assert err.value.path == str(gscd / "testing_list.txt")
    assert "split list missing" in err.value.format()


@pytest.mark.parametrize("line", ["yes", "yes/a/b.wav", "yes/notes.txt", "/yes.wav"])
def test_malformed_split_list_line_is_named_with_its_line(gscd, line):
    path = gscd / "validation_list.txt"
    path.write_text(path.read_text() + line + "\n")
    count = len(path.read_text().splitlines())
    with pytest.raises(DataError) as err:
        open_dataset(gscd)
    assert err.value.path == f"{path}:{count}"
    assert repr(line) in err.value.reason


def test_unreadable_split_list_is_named(gscd):
    (gscd / "validation_list.txt").write_bytes(b"\xff\xfe\x00bad")
    with pytest.raises(DataError, match="cannot read the split list"):
        open_dataset(gscd)


def test_a_clip_in_both_lists_is_an_error(gscd):
    entry = (gscd / "validation_list.txt").read_text().splitlines()[0]
    with open(gscd / "testing_list.txt", "a") as f:
        f.write(entry + "\n")
    with pytest.raises(DataError, match="also in validation_list.txt"):
        open_dataset(gscd)


def test_list_entries_without_files_are_problems(gscd):
    with open(gscd / "testing_list.txt", "a") as f:
        f.write("yes/ffffffff_nohash_0.wav\n")
    ds = open_dataset(gscd)
    assert len(ds.problems) == 1
    assert "yes/ffffffff_nohash_0.wav names no file" in ds.problems[0]
    assert "testing_list.txt:" in ds.problems[0]


def test_folders_that_are_not_gscd_words_are_unknown(gscd, caplog):
    (gscd / "banana").mkdir()
    sf.write(gscd / "banana" / "0a7c2a8d_nohash_0.wav", tone(700), RATE)
    with caplog.at_level(logging.WARNING, logger="springc.data"):
        ds = open_dataset(gscd)
    assert {c.label for c in ds.clips if c.word == "banana"} == {"_unknown_"}
    assert "banana: not one of the 35 GSCD words" in caplog.text


def test_clip_is_hashable_and_frozen():
    clip = Clip(Path("yes/a_nohash_0.wav"), "yes", "yes", "train", "a")
    assert {clip: 1}[clip] == 1
    with pytest.raises(AttributeError):
        clip.word = "no"  # type: ignore[misc]


def test_noise_bank_from_a_data_set_folder(gscd):
    bank = NoiseBank.from_folder(gscd)
    assert len(bank.noises) == 1
    assert len(bank.noises[0]) == int(0.8 * NOISE_S * RATE)  # the training part only
    with pytest.raises(DataError, match="no noise recording"):
        NoiseBank.from_folder(gscd / "yes")


# -- the balanced held-out protocol --------------------------------------------------------------

MIXED_COMMANDS = ("yes", "no", "up", "down")
MIXED_UNKNOWN = ("cat", "dog", "bird", "zero", "one")  # 5 unknown words


def make_mixed(root: Path, held_speakers: int = 3, per_speaker: int = 2) -> Path:
    """A GSCD tree with GSCD's imbalance: 4 commands and 5 unknown words, 4 training speakers
    and `held_speakers` per held-out split; clips are 0.1 s (the reader only reads headers)."""
    names = {"train": [f"a{i:07x}" for i in range(4)],
             "validation": [f"b{i:07x}" for i in range(held_speakers)],
             "test": [f"c{i:07x}" for i in range(held_speakers)]}
    lists: dict[str, list[str]] = {"validation": [], "test": []}
    for w, word in enumerate(MIXED_COMMANDS + MIXED_UNKNOWN):
        (root / word).mkdir(parents=True)
        for split, speakers in names.items():
            for spk in speakers:
                for k in range(per_speaker):
                    name = f"{word}/{spk}_nohash_{k}.wav"
                    sf.write(root / name, tone(300 + 50 * w, 0.1), RATE, subtype="PCM_16")
                    lists.get(split, []).append(name)
    return finish_tree(root, lists["validation"], lists["test"])


@pytest.fixture
def mixed(tmp_path) -> Path:
    return make_mixed(tmp_path / "mixed")


def test_balanced_held_out_splits_hold_equal_counts_per_class(mixed):
    raw = open_dataset(mixed, seed=1)
    assert raw.counts()["test"]["_unknown_"] == 5 * 3 * 2  # 5 words x 3 speakers x 2 clips
    ds = balanced(raw, seed=1)
    for split in HELD_OUT:
        counts = ds.counts()[split]
        present = {k: v for k, v in counts.items() if v}
        assert present == dict.fromkeys(MIXED_COMMANDS + ("_unknown_", "_silence_"), 6)
    assert ds.split("train") == raw.split("train")  # training keeps every clip, silence too
    for split in HELD_OUT:  # every command clip kept, only subsampling otherwise
        commands = [c for c in raw.split(split) if c.label in COMMANDS]
        assert [c for c in ds.split(split) if c.label in COMMANDS] == commands
        words = {c for c in ds.split(split) if c.label != "_silence_"}
        assert words <= set(raw.split(split))


def test_balancing_rounds_to_the_mean_command_count(mixed):
    for path in sorted((mixed / "yes").glob("b*_nohash_*.wav"))[:3]:
        path.unlink()  # yes: 3 validation clips left, the others 6: mean 5.25
    entries = [e for e in (mixed / "validation_list.txt").read_text().split()
               if (mixed / e).exists()]
    (mixed / "validation_list.txt").write_text("\n".join(entries) + "\n")
    counts = balanced(open_dataset(mixed)).counts()["validation"]
    assert counts["yes"] == 3 and counts["no"] == 6
    assert counts["_unknown_"] == counts["_silence_"] == 5


def test_balancing_is_deterministic_for_a_seed(mixed):
    raw = open_dataset(mixed, seed=2)
    first, again = balanced(raw, seed=2), balanced(open_dataset(mixed, seed=2), seed=2)
    assert first.clips == again.clips
    other = balanced(open_dataset(mixed, seed=3), seed=3)
    assert _held_out_unknown(other) != _held_out_unknown(first)


def _held_out_unknown(ds) -> set:
    return {c for c in ds.clips if c.label == "_unknown_" and c.split != "train"}


def test_balancing_keeps_the_splits_speaker_disjoint(mixed):
    ds = balanced(open_dataset(mixed), seed=0)
    speakers = {s: {c.speaker for c in ds.split(s) if c.label != "_silence_"} for s in SPLITS}
    assert not speakers["train"] & speakers["validation"]
    assert not speakers["train"] & speakers["test"]
    assert not speakers["validation"] & speakers["test"]
    n = NOISE_S * RATE
    for clip in ds.clips:  # held-out silence from the split's own part of the noise
        if clip.label == "_silence_":
            lo, hi = NOISE_REGIONS[clip.split]
            assert lo * n <= clip.offset and clip.offset + CLIP_SAMPLES <= hi * n


def test_unknown_subsample_spreads_over_words_and_speakers(mixed):
    for seed in range(5):
        ds = balanced(open_dataset(mixed, seed=seed), seed=seed)
        for split in HELD_OUT:
            unknown = [c for c in ds.split(split) if c.label == "_unknown_"]
            per_word = Counter(c.word for c in unknown)  # 6 clips over 5 words
            assert set(per_word) == set(MIXED_UNKNOWN) and max(per_word.values()) == 2
            for word, n in per_word.items():  # a word's picks come from distinct speakers
                assert len({c.speaker for c in unknown if c.word == word}) == n


def test_spread_sample_on_many_words_and_speakers():
    clips = [Clip(Path(f"w{w}/s{s}_nohash_{k}.wav"), f"w{w}", "_unknown_", "test", f"s{s}")
             for w in range(25) for s in range(8) for k in range(3)]
    picked = spread_sample(clips, 60, np.random.default_rng(0))
    assert len(set(picked)) == 60
    per_word = Counter(c.word for c in picked)
    assert len(per_word) == 25 and set(per_word.values()) == {2, 3}
    for word in per_word:
        assert len({c.speaker for c in picked if c.word == word}) == per_word[word]
    per_speaker = Counter(c.speaker for c in picked)  # 60 clips over 8 speakers: 7 or 8
    assert len(per_speaker) == 8 and max(per_speaker.values()) - min(per_speaker.values()) <= 1
    few = spread_sample(clips[:5], 60, np.random.default_rng(0))
    assert sorted(few, key=Clip.key) == sorted(clips[:5], key=Clip.key)  # fewer: all of them


def test_balancing_needs_command_clips_in_each_held_out_split(gscd):
    ds = open_dataset(gscd).subset(words=("cat", "zero"))
    with pytest.raises(DataError, match="validation split holds no command clip") as err:
        balanced(ds)
    assert "--protocol lists" in err.value.format()


def test_protocols_by_name(gscd):
    ds = open_dataset(gscd)
    assert with_protocol(ds, "lists") is ds
    assert with_protocol(ds, "balanced", 4).clips == balanced(ds, 4).clips
    assert PROTOCOLS == ("lists", "balanced")
    with pytest.raises(UsageError, match="unknown protocol 'even'"):
        with_protocol(ds, "even")
