"""Reading a speech data set in the layout of the Google Speech Commands Dataset (GSCD).

One folder per word holding `<speaker>_nohash_<k>.wav`, `validation_list.txt` and
`testing_list.txt` naming the held-out clips as `word/file.wav` (everything else trains), and
`_background_noise_/` with long noise recordings. The corpus from `springc data synth` has the
same layout. The 12-class task maps the 10 commands to themselves, the other 25 words to
`_unknown_`, and adds `_silence_` clips cut from the noise files.

Two protocols for the held-out splits of the 12-class task: "lists" keeps the split lists as
they are (GSCD's word mix: `_unknown_` is about two thirds of every split), "balanced" (the
paper's Sec. 4, TensorFlow's speech_commands recipe) holds the same number of clips per class
in validation and test: every command clip, `_unknown_` subsampled to the mean command count,
as many `_silence_` clips. Training keeps every clip in both.

A caller that needs only some splits says so (`open_dataset(splits=...)`): evaluating needs the
test split alone, so a folder without split lists is read with every clip a test clip, and
the files of other splits are not opened.

Bad files are never dropped silently: unreadable, truncated or empty ones, those holding NaN or
infinite samples and those sampled below MIN_RATE are skipped, resampled or multi-channel ones
converted, and each is named in `Dataset.problems` and logged as a warning. A data set left
with no usable word clip is a DataError.
"""

from __future__ import annotations

import logging
import sys
import zlib
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import soundfile as sf
from tqdm import tqdm

from springc.sim.audio import (AUDIO_SUFFIXES, non_finite, read_checked, resample,
                               wav_truncation)
from springc.errors import DataError, UsageError
from springc.kws.data.preprocess import preprocess as paper_preprocess

COMMANDS: tuple[str, ...] = ("yes", "no", "up", "down", "left", "right", "on", "off", "stop", "go")
WORDS: tuple[str, ...] = COMMANDS + (
    "zero", "one", "two", "three", "four", "five", "six", "seven", "eight", "nine",
    "bed", "bird", "cat", "dog", "happy", "house", "marvin", "sheila", "tree", "wow",
    "backward", "forward", "follow", "learn", "visual",
)
UNKNOWN, SILENCE = "_unknown_", "_silence_"
CLASSES: tuple[str, ...] = COMMANDS + (UNKNOWN, SILENCE)
SPLITS: tuple[str, ...] = ("train", "validation", "test")
SAMPLE_RATE = 16000
CLIP_SAMPLES = 16000
# Below this rate a file cannot hold speech (telephone band, 8 kHz, keeps the formants): a
# 1 Hz "recording" is a broken header, not a clip to resample 16000-fold.
MIN_RATE = 8000
FLOAT_SUBTYPES = {"FLOAT", "DOUBLE"}  # the only WAV/FLAC sample formats that hold NaN or inf
NOISE_FOLDER = "_background_noise_"
DOCUMENTS = {"README", "LICENSE"}  # GSCD ships _background_noise_/README.md
LIST_FILES = {"validation": "validation_list.txt", "test": "testing_list.txt"}
# Each noise file is cut by time into a training, a validation and a test part, so that
# held-out silence clips never overlap the noise heard in training.
NOISE_REGIONS = {"train": (0.0, 0.8), "validation": (0.8, 0.9), "test": (0.9, 1.0)}
NOISE_PROBABILITY = 0.8  # the paper: noise is added to training clips with probability 0.8
NOISE_MAX_GAIN = 0.1  # uniform gain in [0, 0.1], as in TensorFlow's speech_commands recipe
PROTOCOLS: tuple[str, ...] = ("lists", "balanced")
HELD_OUT: tuple[str, ...] = ("validation", "test")

log = logging.getLogger("springc.data")


def warn(message: str) -> None:
    """Print a data warning (to stderr unless logging is configured otherwise)."""
    log.warning("warning: %s", message)


def label_of(word: str) -> str:
    """The 12-class label of a spoken word."""
    if word == SILENCE or word in COMMANDS:
        return word
    return UNKNOWN


def speaker_of(filename: str) -> str:
    """The speaker id of a GSCD file name `<speaker>_nohash_<k>.wav` (the stem otherwise)."""
    stem = Path(filename).stem
    return stem.split("_nohash_")[0] if "_nohash_" in stem else stem


@dataclass(frozen=True)
class Clip:
    """One 1 s example: a word recording, or a window of a noise file for `_silence_`."""

    path: Path
    word: str
    label: str
    split: str
    speaker: str
    offset: int = 0

    def key(self) -> str:
        """A stable id for caching: `folder/file.wav@offset`."""
        return f"{self.path.parent.name}/{self.path.name}@{self.offset}"


@dataclass
class Dataset:
    """The clips of a data set with their splits, its noise files and the bad files found."""

    root: Path
    clips: list[Clip]
    noise_files: list[Path]
    problems: list[str] = field(default_factory=list)

    def split(self, name: str) -> list[Clip]:
        """The clips of one split: 'train', 'validation' or 'test'."""
        if name not in SPLITS:
            raise UsageError(f"unknown split {name!r}; use one of {', '.join(SPLITS)}")
        return [c for c in self.clips if c.split == name]

    def subset(self, words=None, labels=None) -> Dataset:
        """The clips whose word is in `words` and whose label is in `labels` (None: any)."""
        for given, known, what in ((words, WORDS + (SILENCE,), "word"), (labels, CLASSES, "label")):
            unknown = sorted(set(given or ()) - set(known))
            if unknown:
                raise UsageError(f"unknown {what}(s): {', '.join(unknown)}")
        keep = [c for c in self.clips
                if (words is None or c.word in words) and (labels is None or c.label in labels)]
        return Dataset(self.root, keep, self.noise_files, list(self.problems))

    def counts(self) -> dict[str, dict[str, int]]:
        """{split: {label: number of clips}} with every class listed."""
        table = {s: dict.fromkeys(CLASSES, 0) for s in SPLITS}
        for c in self.clips:
            table[c.split][c.label] += 1
        return table


# -- files ------------------------------------------------------------------------------------


def inspect_audio(path: Path) -> tuple[str | None, str | None]:
    """(reason to skip, conversion note) for one sound file, from its header alone."""
    try:
        info = sf.info(str(path))
    except Exception as exc:  # soundfile raises several types for corrupt files
        return f"cannot read as audio ({exc})", None
    if info.frames == 0:
        return "the file holds no samples", None
    bad = wav_truncation(path) or too_slow(info.samplerate) or _float_samples(path, info)
    if bad:
        return bad, None
    notes = []
    if info.channels != 1:
        notes.append(f"has {info.channels} channels; the first is used")
    if info.samplerate != SAMPLE_RATE:
        notes.append(f"is at {info.samplerate} Hz; resampled to {SAMPLE_RATE} Hz")
    return None, "; ".join(notes) or None


def too_slow(rate: int) -> str | None:
    """Why a sample rate cannot carry speech, or None."""
    if rate < MIN_RATE:
        return f"sample rate {rate} Hz is below {MIN_RATE} Hz, too low for speech"
    return None


def _float_samples(path: Path, info) -> str | None:
    """Where a float-format file holds its first NaN or infinite sample, or None (integer
    formats cannot hold one, so GSCD's PCM files are not read twice)."""
    if info.subtype not in FLOAT_SUBTYPES:
        return None
    try:
        data, rate = sf.read(str(path), dtype="float64", always_2d=True)
    except Exception as exc:  # soundfile raises several types for corrupt files
        return f"cannot read as audio ({exc})"
    return non_finite(data, rate)


_WARNED: set[str] = set()


def read_converted(path: Path) -> np.ndarray:
    """A sound file as float64 mono at SAMPLE_RATE: the first channel of a multi-channel file,
    resampled if needed, each conversion warned once per file and process."""
    data, rate = read_checked(path)
    slow = too_slow(rate)
    if slow:
        raise DataError(str(path), slow)
    notes = []
    if data.shape[1] != 1:
        notes.append(f"has {data.shape[1]} channels; the first is used")
    if rate != SAMPLE_RATE:
        notes.append(f"is at {rate} Hz; resampled to {SAMPLE_RATE} Hz")
    if notes and str(path) not in _WARNED:
        _WARNED.add(str(path))
        warn(f"{path}: {'; '.join(notes)}")
    return resample(data[:, 0], rate, SAMPLE_RATE)


def fit_length(x: np.ndarray, n: int = CLIP_SAMPLES) -> np.ndarray:
    """`x` zero-padded at the end or cut to `n` samples."""
    out = np.zeros(n)
    out[: min(n, len(x))] = x[:n]
    return out


# -- split lists -------------------------------------------------------------------------------


def read_split_list(root: Path, split: str, optional: bool = False) -> list[tuple[str, int]] | None:
    """The (`word/file.wav`, line number) entries of a split list; None for an absent list
    when `optional`; DataError if the list is missing (and needed), not a file, unreadable
    or has a line of another form."""
    path = root / LIST_FILES[split]
    if optional and not path.exists():
        return None
    if path.exists() and not path.is_file():
        raise DataError(str(path), "is a folder, not a split list")
    if not path.is_file():
        raise DataError(str(path), "split list missing",
                        hint="a GSCD-layout folder needs validation_list.txt and "
                        "testing_list.txt (either may be empty)")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError(str(path), f"cannot read the split list ({exc})") from None
    entries = []
    for number, line in enumerate(text.splitlines(), 1):
        entry = line.strip()
        if not entry:
            continue
        parts = entry.split("/")
        if len(parts) != 2 or not all(parts) or Path(entry).suffix.lower() not in AUDIO_SUFFIXES:
            raise DataError(f"{path}:{number}", f"expected 'word/file.wav', got {entry!r}")
        entries.append((entry, number))
    return entries


def held_out(root: Path, problems: list[str], optional: bool = False) -> tuple[dict[str, str], str]:
    """{`word/file.wav`: split} for the validation and test lists, and the split of the clips
    no list names: "train", or "test" where the lists are `optional` and testing_list.txt is
    absent (a folder of recordings to test on). Entries naming no file are problems, an entry
    in both lists is a DataError."""
    where: dict[str, str] = {}
    unlisted = "train"
    for split in ("validation", "test"):
        entries = read_split_list(root, split, optional)
        if entries is None:
            unlisted = "test" if split == "test" else unlisted
            continue
        for entry, number in entries:
            listed = f"{root / LIST_FILES[split]}:{number}"
            if where.get(entry, split) != split:
                raise DataError(listed, f"{entry} is also in {LIST_FILES[where[entry]]}",
                                hint="a clip belongs to one split only")
            if not (root / entry).is_file():
                problems.append(f"{listed}: {entry} names no file; entry ignored")
                continue
            where[entry] = split
    return where, unlisted


# -- word clips and silence --------------------------------------------------------------------


def word_folders(root: Path) -> list[Path]:
    """The word folders of a data set (not `_background_noise_`, nothing hidden)."""
    if not root.exists():
        raise DataError(str(root), "no such data folder",
                        hint="make one with `springc data synth DIR` or point at GSCD")
    if not root.is_dir():
        raise DataError(str(root), "not a folder")
    folders = sorted(p for p in root.iterdir()
                     if p.is_dir() and not p.name.startswith(("_", ".")))
    if not folders:
        raise DataError(str(root), "no word folders (expected one folder per word, as in GSCD)")
    for folder in folders:
        if folder.name not in WORDS:
            warn(f"{folder}: not one of the 35 GSCD words; its clips are labelled {UNKNOWN}")
    return folders


def folder_audio(folder: Path, problems: list[str],
                 wanted=lambda path: True) -> list[tuple[Path, str | None]]:
    """(sound file, conversion note) in a folder, of the files `wanted` (a predicate on the
    path, asked before the file is opened); unusable files are problems and skipped."""
    found = []
    for path in sorted(folder.iterdir()):
        if path.name.startswith(".") or path.stem.upper() in DOCUMENTS:
            continue
        if path.suffix.lower() not in AUDIO_SUFFIXES or not path.is_file():
            problems.append(f"{path}: not a sound file ({', '.join(AUDIO_SUFFIXES)}); ignored")
            continue
        if not wanted(path):
            continue
        skip, note = inspect_audio(path)
        if skip:
            problems.append(f"{path}: {skip}; skipped")
            continue
        if note:
            problems.append(f"{path}: {note}")
        found.append((path, note))
    return found


def word_clips(root: Path, problems: list[str], splits: tuple[str, ...] = SPLITS) -> list[Clip]:
    """Every usable recording of the `splits` under the word folders, with its split. The
    split lists are needed only where training or validation clips are (see `held_out`)."""
    folders = word_folders(root)
    where, unlisted = held_out(root, problems, optional=set(splits) <= {"test"})

    def split_of(folder: Path, path: Path) -> str:
        return where.get(f"{folder.name}/{path.name}", unlisted)

    clips, passed = [], 0
    # GSCD has 105,829 files: reading their headers takes a while, so show progress.
    for folder in tqdm(folders, desc="reading headers", unit="word", file=sys.stderr,
                       disable=None, leave=False):
        for path, _ in folder_audio(folder, problems,
                                    lambda p, f=folder: split_of(f, p) in splits):
            clips.append(Clip(path, folder.name, label_of(folder.name), split_of(folder, path),
                              speaker_of(path.name)))
        passed += sum(1 for p in folder.iterdir() if split_of(folder, p) not in splits)
    if not clips and not passed:
        shown = "; ".join(problems[:3]) + ("; ..." if len(problems) > 3 else "")
        raise DataError(str(root), "no usable sound file in the word folders"
                        + (f" ({shown})" if shown else ""))
    return clips


def noise_lengths(root: Path, problems: list[str],
                  splits: tuple[str, ...] = SPLITS) -> dict[Path, int]:
    """{noise file: length in samples at SAMPLE_RATE} of `_background_noise_` (its absence is
    a problem worded for the `splits` read: augmentation concerns training only)."""
    folder = root / NOISE_FOLDER
    if not folder.is_dir():
        lost = "" if "train" not in splits else " and no noise augmentation"
        problems.append(f"{folder}: no background-noise folder; no {SILENCE} clips{lost}")
        return {}
    return {path: noise_length(path) for path, _ in folder_audio(folder, problems)}


def noise_length(path: Path) -> int:
    """The length of a noise file in samples at SAMPLE_RATE, from its header."""
    try:
        info = sf.info(str(path))
    except Exception as exc:  # the file changed since the data set was opened
        raise DataError(str(path), f"cannot read as audio ({exc})") from None
    return int(info.frames * SAMPLE_RATE // info.samplerate)


def silence_clips(lengths: dict[Path, int], per_split: dict[str, int], seed: int) -> list[Clip]:
    """`per_split[split]` windows of CLIP_SAMPLES cut at random from that split's part of the
    noise files (taken in turn), so held-out silence never overlaps training noise."""
    clips = []
    for index, split in enumerate(SPLITS):
        lo, hi = NOISE_REGIONS[split]
        spans = [(path, int(lo * n), int(hi * n) - CLIP_SAMPLES) for path, n in lengths.items()
                 if int(hi * n) - int(lo * n) >= CLIP_SAMPLES]
        if not spans:
            continue
        rng = np.random.default_rng([seed, index])
        for k in range(per_split.get(split, 0)):
            path, start, last = spans[k % len(spans)]
            offset = int(rng.integers(start, last + 1))
            clips.append(Clip(path, SILENCE, SILENCE, split, f"noise-{path.stem}", offset))
    return clips


def open_dataset(root, *, silence_per_split: float = 0.1, seed: int = 0,
                 splits: tuple[str, ...] = SPLITS) -> Dataset:
    """Read a GSCD-layout data set: word clips with their splits, noise files, and
    `silence_per_split` times as many `_silence_` clips as each split has word clips.
    `splits`: the splits the caller needs; the others' files are not opened, and with the
    test split alone the split lists may be absent (`held_out`).

    Raises DataError for a missing folder, no word folders, no usable word clip, or an
    unreadable split list; bad sound files are skipped or converted and listed in `problems`
    (and warned)."""
    root = Path(root)
    unknown = sorted(set(splits) - set(SPLITS))
    if unknown:
        raise UsageError(f"unknown split(s) {', '.join(unknown)}; use {', '.join(SPLITS)}")
    problems: list[str] = []
    clips = word_clips(root, problems, tuple(splits))
    lengths = noise_lengths(root, problems, tuple(splits))
    want = {s: round(silence_per_split * sum(c.split == s for c in clips)) for s in SPLITS}
    clips += silence_clips(lengths, want, seed)
    for problem in problems:
        warn(problem)
    return Dataset(root, clips, list(lengths), problems)


# -- the balanced held-out protocol ------------------------------------------------------------


def balanced(ds: Dataset, seed: int = 0, splits: tuple[str, ...] = HELD_OUT) -> Dataset:
    """The paper's held-out protocol for the 12-class task: in the held-out `splits`
    (validation and test) every command clip is kept, `_unknown_` is subsampled to the mean
    command count of the split (spread over its words and speakers, drawn from `seed`) and
    `_silence_` is cut in the same number from the split's part of the noise files. Other
    splits are unchanged. A split's draw does not depend on which others are balanced, so
    evaluating gives the test split that training did.

    Raises DataError when a balanced split holds no command clip (nothing to balance to)."""
    todo = [s for s in HELD_OUT if s in splits]
    keep = [c for c in ds.clips if c.split not in todo]
    want: dict[str, int] = {}
    for split in todo:
        index = HELD_OUT.index(split) + 1
        clips = [c for c in ds.clips if c.split == split]
        want[split] = command_mean(clips, ds.root, split)
        unknown = [c for c in clips if c.label == UNKNOWN]
        chosen = set(spread_sample(unknown, want[split], np.random.default_rng([seed, index])))
        keep += [c for c in clips if c.label in COMMANDS or c in chosen]
    lengths = {path: noise_length(path) for path in ds.noise_files}
    keep += [c for c in silence_clips(lengths, want, seed) if c.split in todo]
    return Dataset(ds.root, keep, ds.noise_files, list(ds.problems))


def command_mean(clips: list[Clip], root: Path, split: str) -> int:
    """The mean number of clips per command among the commands present in `clips`, rounded."""
    counts = [sum(c.label == w for c in clips) for w in COMMANDS]
    present = [n for n in counts if n]
    if not present:
        raise DataError(str(root), f"the {split} split holds no command clip, so it cannot "
                        "be balanced", hint="use the split lists as they are: --protocol lists")
    return round(sum(present) / len(present))


def spread_sample(clips: list[Clip], k: int, rng: np.random.Generator) -> list[Clip]:
    """`k` of `clips` (all if there are fewer), spread evenly over their words and speakers:
    the words take turns (in a random order) and each gives, of its clips not yet taken (in a
    random order), one by the speaker it has given least so far, among those by the speaker
    taken least overall."""
    by_word: dict[str, list[Clip]] = {}
    for clip in clips:
        by_word.setdefault(clip.word, []).append(clip)
    words = sorted(by_word)
    pools = {w: [by_word[w][i] for i in rng.permutation(len(by_word[w]))] for w in words}
    order = [words[i] for i in rng.permutation(len(words))]
    overall: Counter[str] = Counter()
    given = {w: Counter() for w in words}
    picked: list[Clip] = []
    while len(picked) < min(k, len(clips)):
        for word in order:
            pool = pools[word]
            if not pool or len(picked) == k:
                continue
            best = min(range(len(pool)), key=lambda i: (given[word][pool[i].speaker],
                                                        overall[pool[i].speaker]))
            clip = pool.pop(best)
            given[word][clip.speaker] += 1
            overall[clip.speaker] += 1
            picked.append(clip)
    return picked


def with_protocol(ds: Dataset, protocol: str, seed: int = 0,
                  splits: tuple[str, ...] = HELD_OUT) -> Dataset:
    """`ds` under a held-out protocol: "lists" (as read) or "balanced" (see `balanced`, on the
    held-out `splits`)."""
    if protocol == "lists":
        return ds
    if protocol == "balanced":
        return balanced(ds, seed, splits)
    raise UsageError(f"unknown protocol {protocol!r}; use one of {', '.join(PROTOCOLS)}")


# -- loading one clip --------------------------------------------------------------------------


def read_window(path: Path, offset: int, n: int = CLIP_SAMPLES) -> np.ndarray:
    """`n` samples from `offset` (at SAMPLE_RATE) of a sound file."""
    try:
        info = sf.info(str(path))
        if info.samplerate != SAMPLE_RATE or info.channels != 1:
            return fit_length(read_converted(path)[offset:offset + n], n)
        data, _ = sf.read(str(path), start=offset, frames=n, dtype="float64")
    except DataError:
        raise
    except Exception as exc:  # the file changed since the data set was opened
        raise DataError(str(path), f"cannot read as audio ({exc})") from None
    bad = non_finite(data[:, None], SAMPLE_RATE)
    if bad:
        raise DataError(str(path), bad)
    return fit_length(data, n)


class NoiseBank:
    """Background-noise recordings held in memory for training augmentation.

    Only the training part of each file (NOISE_REGIONS['train']) is used, so augmentation
    never plays the noise that held-out silence clips are cut from."""

    def __init__(self, files, region: tuple[float, float] = NOISE_REGIONS["train"],
                 probability: float = NOISE_PROBABILITY, max_gain: float = NOISE_MAX_GAIN):
        self.probability = probability
        self.max_gain = max_gain
        self.noises = []
        for path in files:
            x = read_converted(Path(path))
            part = x[int(region[0] * len(x)):int(region[1] * len(x))]
            if len(part) >= CLIP_SAMPLES:
                self.noises.append(part)
        if not self.noises:
            raise DataError(", ".join(map(str, files)) or NOISE_FOLDER,
                            f"no noise recording of at least {CLIP_SAMPLES / SAMPLE_RATE:g} s")

    @classmethod
    def from_folder(cls, root) -> NoiseBank:
        """The noise bank of a data set folder's `_background_noise_`."""
        problems: list[str] = []
        files = list(noise_lengths(Path(root), problems))
        for problem in problems:
            warn(problem)
        return cls(files)

    def mix(self, signal: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """With probability `probability`, `signal` plus a random window of a random noise
        file at a gain uniform in [0, max_gain], clipped to [-1, 1]; else `signal` itself."""
        if rng.random() >= self.probability:
            return signal
        noise = self.noises[rng.integers(len(self.noises))]
        start = rng.integers(len(noise) - len(signal) + 1)
        gain = rng.uniform(0.0, self.max_gain)
        return np.clip(signal + gain * noise[start:start + len(signal)], -1.0, 1.0)


def _clip_rng(seed: int, key: str) -> np.random.Generator:
    """One generator per clip, so augmentation does not depend on scheduling."""
    return np.random.default_rng([seed, zlib.crc32(key.encode())])


def load_clip(clip: Clip, *, augment: bool = False, rng: np.random.Generator | None = None,
              noise: NoiseBank | None = None, preprocess: bool = True) -> np.ndarray:
    """One clip as float64 (CLIP_SAMPLES,) at SAMPLE_RATE: read and convert, pad or cut to
    1 s, add background noise when `augment` and the clip trains, then the paper's
    pre-processing (centre the utterance, remove the background below about 75 Hz)."""
    if clip.word == SILENCE:
        x = read_window(clip.path, clip.offset)
    else:
        x = fit_length(read_converted(clip.path))
    if augment and clip.split == "train" and noise is not None:
        if rng is None:
            rng = np.random.default_rng(zlib.crc32(clip.key().encode()))
        x = noise.mix(x, rng)
    if preprocess:
        x = paper_preprocess(x, SAMPLE_RATE)
    return x
