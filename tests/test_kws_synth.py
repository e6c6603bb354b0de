"""The offline corpus: speaker-disjoint splits, the plan, noise and echo against their
definitions, and a tiny corpus synthesised with the installed engines and read back."""

from __future__ import annotations

import csv
import re
import shutil
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from springc.errors import DataError, UsageError
from springc.kws.data.dataset import CLIP_SAMPLES, SAMPLE_RATE, open_dataset
from scipy.signal import butter, sosfreqz

from springc.kws.data.synth import (
    BAND_HIGH_HZ,
    BAND_LOW_HZ,
    CHANNEL_PROBABILITY,
    PARTIAL_MARK,
    SPEED_RANGE,
    TELEPHONE_BAND,
    TELEPHONE_SHARE,
    TILT_PROBABILITY,
    band_limit,
    coloured_noise,
    fit_word,
    make_plan,
    room_response,
    speaker_hash,
    split_speakers,
    synthesise,
    tilt,
)
from springc.kws.data.voices import Voice, installed_voices

RATE = SAMPLE_RATE
ESPEAK = [Voice(f"espeak:{a}+{v}", "espeak", f"espeak-{a}+{v}", f"{a}+{v}")
          for a in ("en-us", "en-gb-scotland") for v in ("m3", "f2")]
RECORDED = [Voice("flite:kal16", "flite", "kal", "kal16"),
            Voice("flite:awb", "flite", "awb", "awb"), Voice("flite:rms", "flite", "rms", "rms"),
            Voice("flite:slt", "flite", "slt", "slt"),
            Voice("festival:kal_diphone", "festival", "kal", "kal_diphone"),
            Voice("festival:ked_diphone", "festival", "ked", "ked_diphone"),
            Voice("festival:cmu_us_slt_arctic_hts", "festival", "slt", "cmu_us_slt_arctic_hts")]
ENGINES_HERE = all(shutil.which(p) for p in ("espeak-ng", "flite", "festival"))
needs_engines = pytest.mark.skipif(not ENGINES_HERE, reason="espeak-ng, flite, festival needed "
                                   "(scripts/install.sh installs them)")
WORDS = ("yes", "no", "marvin")


def _many_espeak(n: int) -> list[Voice]:
    return [Voice(f"espeak:en-us+v{i}", "espeak", f"espeak-en-us+v{i}", f"en-us+v{i}")
            for i in range(n)]


# -- splits and plan (no engine needed) --------------------------------------------------------


@pytest.mark.parametrize("seed", range(5))
def test_speaker_splits_are_disjoint_and_hold_every_engine(seed):
    voices = _many_espeak(40) + RECORDED
    split_of = split_speakers(voices, seed)
    assert set(split_of) == {v.speaker for v in voices}
    engines = {s: {v.engine for v in voices if split_of[v.speaker] == s}
               for s in ("train", "validation", "test")}
    assert all(e == {"espeak", "flite", "festival"} for e in engines.values())
    espeak = Counter(split_of[v.speaker] for v in voices if v.engine == "espeak")
    assert espeak == {"train": 32, "validation": 4, "test": 4}
    # The seven recorded voices are five speakers: one held out each, three train.
    recorded = {v.speaker: split_of[v.speaker] for v in RECORDED}
    assert sorted(Counter(recorded.values()).values()) == [1, 1, 3]


def test_plan_is_balanced_speaker_disjoint_and_seeded():
    voices = _many_espeak(60) + RECORDED
    plans, split_of = make_plan(voices, ("yes", "no", "cat", "dog"), 200, seed=5, babble=True)
    assert Counter(p.word for p in plans) == {"yes": 50, "no": 50, "cat": 50, "dog": 50}
    assert Counter(p.split for p in plans) == {"train": 160, "validation": 20, "test": 20}
    for p in plans:
        assert split_of[p.voice.speaker] == p.split
        assert re.fullmatch(rf"{p.word}/{speaker_hash(p.voice.speaker)}_nohash_\d+\.wav", p.name)
    assert len({p.name for p in plans}) == len(plans)
    same, _ = make_plan(voices, ("yes", "no", "cat", "dog"), 200, seed=5, babble=True)
    assert same == plans
    other, _ = make_plan(voices, ("yes", "no", "cat", "dog"), 200, seed=6, babble=True)
    assert other != plans
    without, _ = make_plan(voices, ("yes",), 100, seed=5, babble=False)
    assert "babble" not in {p.noise for p in without}


@needs_engines
def test_installed_voices_share_speakers_across_engines():
    voices, notes = installed_voices(("flite", "festival"))
    speaker = {v.id: v.speaker for v in voices}
    assert speaker["flite:slt"] == speaker["festival:cmu_us_slt_arctic_hts"] == "slt"
    assert speaker["flite:kal16"] == speaker["festival:kal_diphone"] == "kal"
    assert len({speaker["flite:awb"], speaker["flite:rms"], speaker["festival:ked_diphone"],
                "slt", "kal"}) == 5
    assert notes == []


# -- sound pieces --------------------------------------------------------------------------------


@pytest.mark.parametrize("kind, slope", [("white", 0.0), ("pink", -1.0), ("brown", -2.0)])
def test_coloured_noise_has_its_spectral_slope(kind, slope):
    x = coloured_noise(kind, 8 * RATE, np.random.default_rng(0))
    assert np.sqrt(np.mean(x * x)) == pytest.approx(1.0)
    power = np.abs(np.fft.rfft(x)) ** 2
    f = np.fft.rfftfreq(len(x), 1.0 / RATE)
    band = (f > 50) & (f < 5000)
    fitted = np.polyfit(np.log(f[band]), np.log(power[band]), 1)[0]
    assert fitted == pytest.approx(slope, abs=0.05)


def test_room_response_decays_60_db_in_rt60_at_the_asked_ratio():
    rt60, drr_db = 0.4, 6.0
    h = room_response(rt60, drr_db, np.random.default_rng(1))
    assert h[0] == 1.0 and len(h) == int(rt60 * RATE)
    tail = h[1:]
    assert 10 * np.log10(1.0 / np.sum(tail * tail)) == pytest.approx(drr_db, abs=1e-9)
    # Energy in 50 ms frames falls on a straight line in dB: -60 dB per rt60.
    frame = int(0.05 * RATE)
    energy = [np.sum(h[k:k + frame] ** 2) for k in range(frame, len(h) - frame, frame)]
    t = np.arange(len(energy)) * 0.05
    slope = np.polyfit(t, 10 * np.log10(energy), 1)[0]
    assert slope == pytest.approx(-60.0 / rt60, rel=0.15)


def test_fit_word_trims_silence_and_squeezes_long_words():
    word = np.sin(2 * np.pi * 300 * np.arange(4000) / RATE)
    padded = np.concatenate([np.zeros(3000), word, np.zeros(5000)])
    trimmed = fit_word(padded, CLIP_SAMPLES)
    assert abs(len(trimmed) - 4000) < 0.01 * RATE
    long = np.sin(2 * np.pi * 300 * np.arange(2 * RATE) / RATE)
    assert len(fit_word(long, 15000)) == 15000


# -- the channel: band limit and tilt --------------------------------------------------------------


def _gain_db(filtered: np.ndarray, tone: np.ndarray) -> float:
    """The steady-state gain of a filter on a tone: RMS ratio over the last half second."""
    half = len(tone) // 2
    return 20 * np.log10(np.sqrt(np.mean(filtered[half:] ** 2) / np.mean(tone[half:] ** 2)))


@pytest.mark.parametrize("freq, expected_db", [(300.0, -3.01), (1000.0, 0.0), (3400.0, -3.01),
                                               (100.0, -38.0), (7000.0, -40.0)])
def test_telephone_band_passes_speech_and_stops_the_rest(freq, expected_db):
    t = np.arange(RATE) / RATE
    tone = np.sin(2 * np.pi * freq * t)
    measured = _gain_db(band_limit(tone, *TELEPHONE_BAND), tone)
    # Against scipy's response of the 4th-order Butterworth band-pass at that frequency ...
    sos = butter(4, TELEPHONE_BAND, btype="bandpass", fs=RATE, output="sos")
    _, h = sosfreqz(sos, worN=[freq], fs=RATE)
    assert measured == pytest.approx(20 * np.log10(abs(h[0])), abs=0.05)
    # ... and against the band's definition: 3 dB at the corners, flat inside, deep outside.
    if expected_db > -10:
        assert measured == pytest.approx(expected_db, abs=0.2)
    else:
        assert measured < expected_db


@pytest.mark.parametrize("a", [-0.5, 0.0, 0.8])
def test_tilt_has_gain_one_minus_a_at_dc_and_one_plus_a_at_nyquist(a):
    n = np.arange(4096)
    assert np.mean(tilt(np.ones(4096), a)[1:]) == pytest.approx(1 - a, abs=1e-12)
    alternating = (-1.0) ** n
    assert np.mean(np.abs(tilt(alternating, a)[1:])) == pytest.approx(1 + a, abs=1e-12)


def test_plans_draw_channels_and_speeds_in_their_ranges():
    plans, _ = make_plan(_many_espeak(40) + RECORDED, ("yes", "no"), 2000, seed=3, babble=True)
    bands = Counter("none" if p.band_hz == (0.0, 0.0) else
                    "telephone" if p.band_hz == TELEPHONE_BAND else "band" for p in plans)
    # Three-sigma binomial bounds around the shares asked for.
    share = {"none": 1 - CHANNEL_PROBABILITY,
             "telephone": CHANNEL_PROBABILITY * TELEPHONE_SHARE,
             "band": CHANNEL_PROBABILITY * (1 - TELEPHONE_SHARE)}
    for kind, p in share.items():
        assert abs(bands[kind] - 2000 * p) <= 3 * np.sqrt(2000 * p * (1 - p)) + 1
    for p in plans:
        assert SPEED_RANGE[0] <= p.speed <= SPEED_RANGE[1]
        if p.band_hz not in ((0.0, 0.0), TELEPHONE_BAND):
            assert BAND_LOW_HZ[0] <= p.band_hz[0] <= BAND_LOW_HZ[1]
            assert BAND_HIGH_HZ[0] <= p.band_hz[1] <= BAND_HIGH_HZ[1]
    tilted = sum(p.tilt != 0 for p in plans)
    assert abs(tilted - 2000 * TILT_PROBABILITY) <= 3 * np.sqrt(2000 * 0.25) + 1

# -- a tiny corpus from the real engines ---------------------------------------------------------


@pytest.fixture(scope="module")
def corpus(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("synth") / "corpus"
    synthesise(out, clips=30, seed=11, jobs=1, words=WORDS, voices=ESPEAK + RECORDED)
    return out


def _wavs(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*.wav"))}


@needs_engines
def test_corpus_has_the_gscd_layout(corpus):
    names = {p.name for p in corpus.iterdir()}
    assert names == set(WORDS) | {"_background_noise_", "validation_list.txt",
                                  "testing_list.txt", "voices.csv"}
    assert sum(1 for _ in corpus.rglob("*.wav")) == 30 + 5
    for path in (corpus / "_background_noise_").iterdir():
        info = sf.info(str(path))
        assert 30 <= info.duration <= 60 and info.samplerate == RATE and info.channels == 1
    for word in WORDS:
        for path in (corpus / word).iterdir():
            assert re.fullmatch(r"[0-9a-f]{8}_nohash_\d+\.wav", path.name)
            info = sf.info(str(path))
            assert (info.samplerate, info.channels, info.frames) == (RATE, 1, CLIP_SAMPLES)
            assert info.subtype == "PCM_16"


@needs_engines
def test_corpus_reads_back_with_disjoint_speakers(corpus):
    ds = open_dataset(corpus)
    assert ds.problems == []
    words = [c for c in ds.clips if c.word != "_silence_"]
    assert Counter(c.word for c in words) == {w: 10 for w in WORDS}
    assert Counter(c.split for c in words) == {"train": 24, "validation": 3, "test": 3}
    speakers = {s: {c.speaker for c in words if c.split == s} for s in ("train", "validation",
                                                                       "test")}
    assert not speakers["train"] & speakers["validation"]
    assert not speakers["train"] & speakers["test"]
    assert not speakers["validation"] & speakers["test"]
    for clip in words:  # every clip holds a word: its peak is well above its noise floor
        x, _ = sf.read(clip.path)
        assert np.max(np.abs(x)) > 10 * np.median(np.abs(x))


@needs_engines
def test_voices_csv_matches_the_files(corpus):
    with open(corpus / "voices.csv") as f:
        rows = list(csv.DictReader(f))
    assert [r["voice"] for r in rows] == [v.id for v in ESPEAK + RECORDED]
    assert sum(int(r["count"]) for r in rows) == 30
    per_id = Counter()
    for r in rows:
        per_id[r["speaker_id"]] += int(r["count"])
        assert r["speaker_id"] == speaker_hash(r["speaker"])
    files = Counter(p.name.split("_nohash_")[0] for w in WORDS for p in (corpus / w).iterdir())
    assert files == +per_id
    split_of = {r["speaker"]: r["split"] for r in rows}
    assert split_of["slt"] == next(r["split"] for r in rows if r["voice"] == "flite:slt")
    engines = {s: {r["engine"] for r in rows if r["split"] == s} for s in set(split_of.values())}
    assert all(e == {"espeak", "flite", "festival"} for e in engines.values())


@needs_engines
def test_same_seed_gives_identical_bytes_whatever_the_workers(corpus, tmp_path):
    again = tmp_path / "again"
    synthesise(again, clips=30, seed=11, jobs=2, words=WORDS, voices=ESPEAK + RECORDED)
    assert _wavs(again) == _wavs(corpus)
    for name in ("validation_list.txt", "testing_list.txt", "voices.csv"):
        assert (again / name).read_bytes() == (corpus / name).read_bytes()
    other = tmp_path / "other"
    synthesise(other, clips=30, seed=12, jobs=1, words=WORDS, voices=ESPEAK + RECORDED)
    assert _wavs(other) != _wavs(corpus)
    assert not list(tmp_path.glob("*.tmp"))


@needs_engines
def test_a_failing_voice_is_left_out_and_named(tmp_path, caplog):
    broken = Voice("flite:nonexistent", "flite", "nobody", "/nonexistent/voice.flitevox")
    out = tmp_path / "c"
    report = synthesise(out, clips=6, seed=0, jobs=1, words=("yes", "no"),
                        voices=ESPEAK[:1] + [broken])
    failed = [n for n in report.notes if "flite:nonexistent" in n]
    assert failed and all("left out" in n for n in failed)
    assert report.clips == 6 - len(failed)
    assert sum(1 for w in ("yes", "no") for _ in (out / w).iterdir()) == report.clips
    assert failed[0] in caplog.text


def test_no_engine_installed_is_a_data_error(tmp_path, monkeypatch):
    monkeypatch.setenv("PATH", str(tmp_path))
    voices, notes = installed_voices()
    assert voices == []
    assert [n.split(":")[0] for n in notes] == ["espeak-ng", "flite", "festival"]
    assert all("not installed (apt-get install" in n for n in notes)
    with pytest.raises(DataError, match="no usable voice"):
        synthesise(tmp_path / "out", clips=10, words=("yes",))
    assert not (tmp_path / "out").exists() and not (tmp_path / "out.tmp").exists()


def test_bad_requests_are_usage_errors(tmp_path):
    (tmp_path / "exists").mkdir()
    with pytest.raises(UsageError, match="already exists"):
        synthesise(tmp_path / "exists", clips=5, words=("yes",), voices=ESPEAK)
    with pytest.raises(UsageError, match="not GSCD words: banana"):
        synthesise(tmp_path / "x", words=("yes", "banana"), voices=ESPEAK)
    with pytest.raises(UsageError, match="fewer than the 2 words"):
        synthesise(tmp_path / "x", clips=1, words=("yes", "no"), voices=ESPEAK)
    (tmp_path / "y.tmp").mkdir()
    with pytest.raises(UsageError, match="not an unfinished springc corpus"):
        synthesise(tmp_path / "y", clips=5, words=("yes",), voices=ESPEAK)


@needs_engines
def test_an_interrupted_run_is_replaced(tmp_path):
    leftover = tmp_path / "z.tmp"
    (leftover / "yes").mkdir(parents=True)
    (leftover / PARTIAL_MARK).write_text("")
    (leftover / "yes" / "half.wav").write_bytes(b"RIFF")
    synthesise(tmp_path / "z", clips=2, words=("yes",), voices=ESPEAK[:1], jobs=1)
    assert not leftover.exists()
    assert not (tmp_path / "z" / "yes" / "half.wav").exists()
    assert not (tmp_path / "z" / PARTIAL_MARK).exists()


@needs_engines
def test_festival_that_hangs_or_dies_is_a_synthesis_error(monkeypatch):
    from springc.kws.data import voices

    monkeypatch.setattr(voices, "FESTIVAL_TIMEOUT_S", 1.0)
    with voices.Speaker() as speaker:
        with pytest.raises(voices.SynthesisError, match="festival exited or hung"):
            speaker.festival_command("(read)")  # waits for input that never comes
        # The next word starts a fresh festival.
        x, rate = speaker.say(RECORDED[4], "yes", 1.0, 1.0)
        assert rate == 16000 and len(x) > 0.2 * rate
