"""Tiny generated GSCD-layout corpora for the keyword-spotting tests (tones and chirps as
"words") and a 4 x 2 model trained on one, shared by the test modules that need them; and the
smaller hand-made GSCD folders of plain tones (`make_gscd`, with `finish_tree` and `tone`) of
the dataset reader's tests, shared by test_kws_dataset and test_cli_data."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import soundfile as sf
from scipy.signal import chirp

RATE = 16000
SPEAKERS = [f"{i:08x}" for i in range(0x1a2b3c40, 0x1a2b3c48)]  # 6 train, 1 val, 1 test
# the speakers of `make_gscd`'s folders: 3 train, 1 val, 1 test
GSCD_SPEAKERS = ["0a7c2a8d", "1b2c3d4e", "2c3d4e5f", "3d4e5f60", "4e5f6071"]
NOISE_S = 15  # s: the held-out tenths are 1.5 s, enough for a 1 s silence clip


def word_sound(word: str, rng: np.random.Generator) -> np.ndarray:
    """A distinctive 1 s "word": chirps up or down, a two-tone beep, a noise burst."""
    t = np.arange(RATE) / RATE
    dur, start = rng.uniform(0.35, 0.5), rng.uniform(0.15, 0.35)
    tt = np.clip(t - start, 0, dur)
    env = np.where((t > start) & (t < start + dur), np.sin(np.pi * tt / dur) ** 2, 0.0)
    shapes = {
        "yes": lambda: chirp(tt, 300, dur, 3000, method="logarithmic"),
        "no": lambda: chirp(tt, 3000, dur, 300, method="logarithmic"),
        "one": lambda: chirp(tt, 400, dur, 2500, method="logarithmic"),
        "two": lambda: chirp(tt, 2500, dur, 400, method="logarithmic"),
        "three": lambda: np.sin(2 * np.pi * 700 * tt) + np.sin(2 * np.pi * 1800 * tt),
        "four": lambda: np.sin(2 * np.pi * 300 * tt) * np.sin(2 * np.pi * 9 * tt),
        "up": lambda: np.sin(2 * np.pi * 500 * tt),
        "cat": lambda: np.sin(2 * np.pi * (1200 + 800 * (tt > dur / 2)) * tt),
    }
    sig = env * shapes[word]() * rng.uniform(0.2, 0.6)
    return sig + 0.003 * rng.normal(size=RATE)


def corpus_and_model(root: Path, *train_args: str) -> tuple[Path, Path]:
    """make_corpus under `root` and a 4 x 2 model trained on it by `springc train` (with
    `train_args`): (data, model)."""
    from click.testing import CliRunner

    from springc_cli.main import main

    data, model = make_corpus(root / "data"), root / "model"
    result = CliRunner().invoke(main, ["train", "--data", str(data), "-n", "4", "-m", "2",
                                       "-j", "1", *train_args, "-o", str(model)])
    assert result.exit_code == 0, result.output
    return data, model


def shared_corpus_and_model(tmp_path_factory, *train_args: str) -> tuple[Path, Path]:
    """`corpus_and_model` made once per test run and shared by the modules that only read
    the model (the pytest-xdist workers of one run share the folder; a lock makes one of
    them train while the other waits): the tests that tune, refit and evaluate it write
    folders of their own beside it."""
    import fcntl
    import hashlib
    import os

    base = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        base = base.parent  # the run's folder, above each worker's own
    key = hashlib.sha256("\0".join(train_args).encode()).hexdigest()[:12]
    root = base / f"shared-model-{key}"
    root.mkdir(exist_ok=True)
    with open(root / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (root / ".done").exists():
            corpus_and_model(root, *train_args)
            (root / ".done").touch()
    return root / "data", root / "model"


def make_corpus(root: Path, words: tuple[str, ...] = ("yes", "no", "cat"), per_speaker: int = 3,
                seed: int = 0, empty_test: bool = False) -> Path:
    """A GSCD-layout folder: <word>/<speaker>_nohash_<k>.wav, split lists, background noise."""
    rng = np.random.default_rng(seed)
    val, test = [], []
    for word in words:
        (root / word).mkdir(parents=True)
        for s, spk in enumerate(SPEAKERS):
            for k in range(per_speaker):
                name = f"{word}/{spk}_nohash_{k}.wav"
                sf.write(root / name, word_sound(word, rng), RATE, subtype="PCM_16")
                (val if s == 6 else test if s == 7 else []).append(name)
    (root / "validation_list.txt").write_text("\n".join(val) + "\n")
    (root / "testing_list.txt").write_text("" if empty_test else "\n".join(test) + "\n")
    (root / "_background_noise_").mkdir()
    noise = 0.05 * np.random.default_rng(seed + 1).normal(size=30 * RATE)
    sf.write(root / "_background_noise_" / "white_noise.wav", noise, RATE, subtype="PCM_16")
    return root


def tone(hz: float, seconds: float = 1.0, rate: int = RATE) -> np.ndarray:
    """`seconds` of a Hann-windowed sine at `hz`, amplitude 0.3, sampled at `rate`."""
    t = np.arange(int(seconds * rate)) / rate
    return 0.3 * np.sin(2 * np.pi * hz * t) * np.hanning(len(t))


def make_gscd(root: Path, words=("yes", "no", "cat", "zero"), per_speaker: int = 2) -> Path:
    """word/<speaker>_nohash_<k>.wav, split lists (speaker 3 validation, 4 test), a noise file."""
    val, test = [], []
    for w, word in enumerate(words):
        (root / word).mkdir(parents=True)
        for s, spk in enumerate(GSCD_SPEAKERS):
            for k in range(per_speaker):
                name = f"{word}/{spk}_nohash_{k}.wav"
                sf.write(root / name, tone(300 + 100 * w + 10 * s), RATE, subtype="PCM_16")
                (val if s == 3 else test if s == 4 else []).append(name)
    return finish_tree(root, val, test)


def finish_tree(root: Path, val: list[str], test: list[str]) -> Path:
    """The split lists and a white-noise `_background_noise_` of a fake GSCD tree."""
    (root / "validation_list.txt").write_text("\n".join(val) + "\n")
    (root / "testing_list.txt").write_text("\n".join(test) + "\n")
    (root / "_background_noise_").mkdir()
    noise = 0.1 * np.random.default_rng(0).standard_normal(NOISE_S * RATE)
    sf.write(root / "_background_noise_" / "white_noise.wav", noise, RATE, subtype="PCM_16")
    return root
