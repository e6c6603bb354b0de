"""The built-in offline speech corpus: the 35 GSCD words spoken by the text-to-speech voices
installed here, written in the GSCD layout so that `open_dataset` reads it like the real one.

Every clip is planned up front from the seed (word, voice, split, speaking rate, pitch,
tape speed, loudness, placement, room echo, channel band and spectral tilt, background
noise), then rendered by worker processes, each with its own persistent festival. A clip's
bytes depend only on the seed and its plan, never on scheduling, so the same seed gives the
same corpus. Splits are speaker-disjoint: every voice of a speaker (flite slt and festival
slt, say) lands in the same split.
"""

from __future__ import annotations

import csv
import hashlib
import multiprocessing
import multiprocessing.util
import os
import shutil
import sys
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import soundfile as sf
from scipy.ndimage import uniform_filter1d
from scipy.signal import butter, fftconvolve, lfilter, sosfilt
from tqdm import tqdm

from springc.sim.audio import resample
from springc.errors import DataError, UsageError
from springc.kws.data.dataset import (
    CLIP_SAMPLES,
    LIST_FILES,
    NOISE_FOLDER,
    SAMPLE_RATE,
    SPLITS,
    WORDS,
    warn,
)
from springc.kws.data.voices import ENGINES, Speaker, SynthesisError, Voice, installed_voices

DEFAULT_CLIPS = 2400
SPLIT_SHARES = {"train": 0.8, "validation": 0.1, "test": 0.1}
# Share of clips per engine: espeak-ng has hundreds of synthetic speakers, flite and festival a
# handful of recorded ones that sound the most natural; both matter.
ENGINE_SHARES = {"espeak": 0.6, "flite": 0.2, "festival": 0.2}
CLIP_NOISE_PROBABILITY = 0.6
ECHO_PROBABILITY = 0.5
NOISE_KINDS = ("white", "pink", "brown", "babble")
# The engines differ in bandwidth and spectral balance (espeak-ng's formant voices are brighter
# than the diphone and HTS ones), and a model hears only the voices of the engines it trained
# on: clips pass through a random channel (band limit, tilt) and a wide tape-speed range
# (formants shift with it, as with another vocal-tract length), measured in
# docs/results-voices.md.
SPEED_RANGE = (0.85, 1.18)
PITCH_RANGE = (0.6, 1.6)
CHANNEL_PROBABILITY = 0.5  # a clip passes through a band limit
TELEPHONE_SHARE = 0.3  # of those, the telephone band; the others a random band
TELEPHONE_BAND = (300.0, 3400.0)
BAND_LOW_HZ = (50.0, 400.0)  # random band: high-pass corner
BAND_HIGH_HZ = (3000.0, 7500.0)  # and low-pass corner
CHANNEL_ORDER = 4  # Butterworth order of each side of the band
TILT_PROBABILITY = 0.5  # a clip passes through y[n] = x[n] - a x[n-1]
TILT_RANGE = (-0.5, 0.8)  # a: negative darkens, positive brightens
# Real speech recordings shipped in Debian packages (codec2-examples, alsa-utils): babble.
BABBLE_SOURCES = (Path("/usr/share/codec2/wav"), Path("/usr/share/sounds/alsa"))
NOISE_FILES = {"white_noise": 45, "pink_noise": 50, "brown_noise": 40, "babble": 60,
               "hum": 35}  # seconds each
PARTIAL_MARK = ".springc-partial"
SCRATCH = ".scratch"


@dataclass(frozen=True)
class ClipPlan:
    """Everything needed to render one clip, drawn from the seed before any work starts."""

    index: int
    name: str  # word/file.wav
    word: str
    voice: Voice
    split: str
    stretch: float  # engine speaking-rate factor (>1 slower)
    pitch: float  # engine pitch factor
    speed: float  # tape-speed change applied afterwards (shifts pitch and tempo together)
    level_db: float  # peak level, dBFS
    position: float  # where in the window the word sits, 0 (start) .. 1 (end)
    echo_rt60: float  # room reverberation time in s; 0 for none
    echo_drr_db: float  # direct-to-reverberant ratio
    band_hz: tuple[float, float]  # channel band (low, high corner); (0, 0) for none
    tilt: float  # first-order tilt coefficient a; 0 for none
    noise: str  # "" or one of NOISE_KINDS
    snr_db: float
    floor_db: float  # a faint noise floor so no clip is digital silence
    seed: int


# -- speakers and splits -----------------------------------------------------------------------


def speaker_hash(speaker: str) -> str:
    """The 8-hex-digit speaker id used in file names, as GSCD does."""
    return hashlib.sha1(speaker.encode()).hexdigest()[:8]


def split_speakers(voices: list[Voice], seed: int) -> dict[str, str]:
    """{speaker: split}: every split gets a speaker of every engine where there are enough
    (validation and test are served first; train keeps at least one of each), then each group
    of speakers with the same engines is held out 10 % / 10 %, the rest trains. The few
    recorded voices thus mostly train, the hundreds of espeak-ng ones split 80/10/10."""
    engines: dict[str, frozenset[str]] = {}
    for v in voices:
        engines[v.speaker] = engines.get(v.speaker, frozenset()) | {v.engine}
    order = sorted(engines)
    np.random.default_rng(seed).shuffle(order)
    split_of = cover_engines(order, engines)
    for group in sorted(set(engines.values()), key=sorted):
        members = [s for s in order if engines[s] == group]
        held = round(SPLIT_SHARES["test"] * len(members)) if len(members) >= 3 else 0
        for speaker in members:
            if speaker not in split_of:
                count = Counter(split_of[s] for s in members if s in split_of)
                split_of[speaker] = next((h for h in ("test", "validation") if count[h] < held),
                                         "train")
    return split_of


def cover_engines(order: list[str], engines: dict[str, frozenset[str]]) -> dict[str, str]:
    """{speaker: test or validation}: for each held-out split and engine it lacks, the free
    speaker covering most missing engines, as long as another is left for training."""
    split_of: dict[str, str] = {}
    for split in ("test", "validation"):
        for engine in ENGINES:
            have = {e for s, sp in split_of.items() if sp == split for e in engines[s]}
            free = [s for s in order if s not in split_of and engine in engines[s]]
            if engine in have or len(free) < 2:
                continue
            split_of[max(free, key=lambda s: len(engines[s] - have))] = split
    return split_of


def word_splits(n: int, rng: np.random.Generator) -> list[str]:
    """Splits for the `n` clips of one word: 80/10/10, at least one held out each when n >= 3."""
    held = max(round(0.1 * n), 1) if n >= 3 else 0
    splits = ["validation"] * held + ["test"] * held + ["train"] * (n - 2 * held)
    rng.shuffle(splits)
    return splits


def pick_voice(split: str, by_split: dict[str, dict[str, list[Voice]]],
               rng: np.random.Generator) -> Voice:
    """An engine by ENGINE_SHARES (among those the split has), then one of its voices."""
    engines = sorted(by_split[split])
    shares = np.array([ENGINE_SHARES[e] for e in engines])
    engine = engines[rng.choice(len(engines), p=shares / shares.sum())]
    pool = by_split[split][engine]
    return pool[rng.integers(len(pool))]


# -- the plan ----------------------------------------------------------------------------------


def draw_plan(rng: np.random.Generator) -> dict:
    """The random rendering settings of one clip."""
    noisy = rng.random() < CLIP_NOISE_PROBABILITY
    echo = rng.random() < ECHO_PROBABILITY
    return {"stretch": rng.uniform(0.8, 1.3), "pitch": rng.uniform(*PITCH_RANGE),
            "speed": rng.uniform(*SPEED_RANGE), "level_db": rng.uniform(-26.0, -2.0),
            "band_hz": draw_band(rng),
            "tilt": rng.uniform(*TILT_RANGE) if rng.random() < TILT_PROBABILITY else 0.0,
            "position": rng.uniform(0.0, 1.0),
            "echo_rt60": rng.uniform(0.15, 0.6) if echo else 0.0,
            "echo_drr_db": rng.uniform(-2.0, 12.0),
            "noise": NOISE_KINDS[rng.integers(len(NOISE_KINDS))] if noisy else "",
            "snr_db": rng.uniform(5.0, 35.0), "floor_db": rng.uniform(-75.0, -50.0),
            "seed": int(rng.integers(2**32))}


def draw_band(rng: np.random.Generator) -> tuple[float, float]:
    """The channel band of one clip: (0, 0) for none, the telephone band, or a random one."""
    if rng.random() >= CHANNEL_PROBABILITY:
        return (0.0, 0.0)
    if rng.random() < TELEPHONE_SHARE:
        return TELEPHONE_BAND
    return (float(rng.uniform(*BAND_LOW_HZ)), float(rng.uniform(*BAND_HIGH_HZ)))


def make_plan(voices: list[Voice], words: tuple[str, ...], clips: int, seed: int,
              babble: bool) -> tuple[list[ClipPlan], dict[str, str]]:
    """(clip plans, {speaker: split}) for `clips` clips spread evenly over `words`."""
    split_of = split_speakers(voices, seed)
    by_split: dict[str, dict[str, list[Voice]]] = {s: {} for s in SPLITS}
    for v in voices:
        by_split[split_of[v.speaker]].setdefault(v.engine, []).append(v)
    rng = np.random.default_rng(seed)
    plans, taken = [], Counter()
    per_word = [clips // len(words) + (i < clips % len(words)) for i in range(len(words))]
    for word, n in zip(words, per_word):
        for split in word_splits(n, rng):
            if not by_split[split]:
                split = "train"  # too few speakers to hold any out
            voice = pick_voice(split, by_split, rng)
            stem = speaker_hash(voice.speaker)
            name = f"{word}/{stem}_nohash_{taken[word, stem]}.wav"
            taken[word, stem] += 1
            settings = draw_plan(rng)
            if not babble and settings["noise"] == "babble":
                settings["noise"] = "pink"
            plans.append(ClipPlan(len(plans), name, word, voice, split, **settings))
    return plans, split_of


# -- sound -------------------------------------------------------------------------------------


def coloured_noise(kind: str, n: int, rng: np.random.Generator) -> np.ndarray:
    """Unit-RMS white, pink (1/f power) or brown (1/f^2) noise, shaped in the frequency domain;
    brown keeps its slow drift down to 5 Hz, as wind and handling noise do."""
    spectrum = np.fft.rfft(rng.standard_normal(n))
    f = np.fft.rfftfreq(n, 1.0 / SAMPLE_RATE)
    f[0] = f[1]
    exponent = {"white": 0.0, "pink": 0.5, "brown": 1.0}[kind]
    shaped = spectrum / np.maximum(f, 5.0) ** exponent
    x = np.fft.irfft(shaped, n)
    return x / (np.sqrt(np.mean(x * x)) + 1e-300)


def babble_sources() -> list[np.ndarray]:
    """Real speech recordings found on this machine, at SAMPLE_RATE, each unit RMS."""
    found = []
    for folder in BABBLE_SOURCES:
        if not folder.is_dir():
            continue
        for path in sorted(folder.glob("*.wav")):
            if path.stem == "Noise":
                continue
            try:
                x, rate = sf.read(str(path), dtype="float64", always_2d=True)
            except Exception:  # noqa: BLE001 - a broken system file is just not used
                continue
            x = resample(x[:, 0], rate, SAMPLE_RATE)
            if len(x) >= SAMPLE_RATE and np.any(x):
                found.append(x / np.sqrt(np.mean(x * x)))
    return found


def babble(sources: list[np.ndarray], n: int, rng: np.random.Generator) -> np.ndarray:
    """Unit-RMS babble: 3 to 6 talkers, each a random stretch of a recording (looped)."""
    out = np.zeros(n)
    for _ in range(int(rng.integers(3, 7))):
        src = sources[rng.integers(len(sources))]
        start = int(rng.integers(len(src)))
        out += np.resize(np.roll(src, -start), n) * rng.uniform(0.5, 1.0)
    return out / (np.sqrt(np.mean(out * out)) + 1e-300)


def hum(n: int, rng: np.random.Generator) -> np.ndarray:
    """Unit-RMS mains hum (50 or 60 Hz and harmonics) over faint pink noise."""
    t = np.arange(n) / SAMPLE_RATE
    base = 50.0 if rng.random() < 0.5 else 60.0
    x = sum(rng.uniform(0.2, 1.0) / k * np.sin(2 * np.pi * k * base * t + rng.uniform(0, 6.3))
            for k in range(1, 8))
    x = x / np.sqrt(np.mean(x * x)) + 0.3 * coloured_noise("pink", n, rng)
    return x / np.sqrt(np.mean(x * x))


def noise_of(kind: str, n: int, rng: np.random.Generator, sources: list[np.ndarray]):
    """Unit-RMS noise of a kind."""
    if kind == "babble":
        return babble(sources, n, rng)
    if kind == "hum":
        return hum(n, rng)
    return coloured_noise(kind, n, rng)


def room_response(rt60: float, drr_db: float, rng: np.random.Generator) -> np.ndarray:
    """A synthetic room impulse response: the direct sound, then from 3 ms on exponentially
    decaying noise (60 dB in `rt60` s) at the given direct-to-reverberant energy ratio."""
    n = int(rt60 * SAMPLE_RATE)
    t = np.arange(n) / SAMPLE_RATE
    tail = rng.standard_normal(n) * 10.0 ** (-3.0 * t / rt60)
    tail[: int(0.003 * SAMPLE_RATE)] = 0.0
    tail *= 10.0 ** (-drr_db / 20.0) / np.sqrt(np.sum(tail * tail))
    tail[0] = 1.0
    return tail


def band_limit(x: np.ndarray, low_hz: float, high_hz: float) -> np.ndarray:
    """`x` through a Butterworth band-pass (order CHANNEL_ORDER each side), 3 dB down at
    `low_hz` and `high_hz`, as a telephone line or a small loudspeaker passes speech."""
    sos = butter(CHANNEL_ORDER, [low_hz, high_hz], btype="bandpass", fs=SAMPLE_RATE,
                 output="sos")
    return sosfilt(sos, x)


def tilt(x: np.ndarray, a: float) -> np.ndarray:
    """`x` through y[n] = x[n] - a x[n-1]: gain 1 - a at 0 Hz, 1 + a at the Nyquist
    frequency (a > 0 brightens, a < 0 darkens: a microphone's or a voice's spectral tilt)."""
    return lfilter([1.0, -a], [1.0], x)


def channel(x: np.ndarray, plan: ClipPlan) -> np.ndarray:
    """`x` through the plan's channel: its band limit, then its tilt (either may be none)."""
    if plan.band_hz[1] > 0:
        x = band_limit(x, *plan.band_hz)
    return tilt(x, plan.tilt) if plan.tilt else x


def active_span(x: np.ndarray) -> tuple[int, int]:
    """First and last sample of the utterance: a 10 ms envelope above -40 dB of its peak."""
    env = np.sqrt(np.maximum(uniform_filter1d(x * x, int(0.01 * SAMPLE_RATE)), 0.0))
    loud = np.flatnonzero(env > 0.01 * env.max())
    return int(loud[0]), int(loud[-1]) + 1


def fit_word(x: np.ndarray, limit: int) -> np.ndarray:
    """The utterance without its leading and trailing silence, sped up to fit `limit` samples
    if longer (slow voices saying `backward` can exceed a second)."""
    lo, hi = active_span(x)
    x = x[lo:hi]
    if len(x) > limit:
        x = resample(x, len(x), limit)[:limit]
    return x


def render(plan: ClipPlan, speaker: Speaker, sources: list[np.ndarray]) -> np.ndarray:
    """The 1 s clip of a plan as int16 samples at SAMPLE_RATE."""
    rng = np.random.default_rng(plan.seed)
    x, rate = speaker.say(plan.voice, plan.word, plan.stretch, plan.pitch)
    x = fit_word(resample(x, rate * plan.speed, SAMPLE_RATE), int(0.95 * CLIP_SAMPLES))
    if plan.echo_rt60 > 0:
        x = fftconvolve(x, room_response(plan.echo_rt60, plan.echo_drr_db, rng))
        x = x[: int(0.98 * CLIP_SAMPLES)]
    x = channel(x, plan)
    x *= 10.0 ** (plan.level_db / 20.0) / np.max(np.abs(x))
    clip = np.zeros(CLIP_SAMPLES)
    start = int(plan.position * (CLIP_SAMPLES - len(x)))
    clip[start:start + len(x)] = x
    speech_rms = np.sqrt(np.mean(x * x))
    if plan.noise:
        noise = noise_of(plan.noise, CLIP_SAMPLES, rng, sources)
        clip += noise * speech_rms * 10.0 ** (-plan.snr_db / 20.0)
    clip += rng.standard_normal(CLIP_SAMPLES) * 10.0 ** (plan.floor_db / 20.0)
    return to_int16(clip)


def to_int16(x: np.ndarray) -> np.ndarray:
    """Float samples in [-1, 1] as 16-bit integers (clipped)."""
    return np.round(np.clip(x, -1.0, 32767 / 32768) * 32768).astype(np.int16)


def write_wav(path: Path, samples: np.ndarray) -> None:
    """A 16 kHz mono 16-bit wav file."""
    sf.write(str(path), samples, SAMPLE_RATE, subtype="PCM_16", format="WAV")


# -- workers -----------------------------------------------------------------------------------

_WORKER: dict = {}


def _init_worker(out: str, use_babble: bool) -> None:
    # Scratch files live inside the unfinished corpus, so nothing is left behind on failure.
    speaker = Speaker(Path(out) / SCRATCH)
    multiprocessing.util.Finalize(speaker, speaker.close, exitpriority=10)
    _WORKER.update(out=Path(out), speaker=speaker,
                   sources=babble_sources() if use_babble else [])


def _render_one(plan: ClipPlan) -> tuple[int, str | None]:
    """(index, None) once the clip is written, or (index, why it failed)."""
    try:
        samples = render(plan, _WORKER["speaker"], _WORKER["sources"])
    except SynthesisError as exc:
        return plan.index, str(exc)
    write_wav(_WORKER["out"] / plan.name, samples)
    return plan.index, None


def render_all(plans: list[ClipPlan], out: Path, jobs: int, use_babble: bool) -> dict[int, str]:
    """Render every plan into `out` with `jobs` processes; {index: failure} for clips that
    could not be made. Shows a progress bar (clips done, rate, time left)."""
    if jobs <= 1:
        _init_worker(str(out), use_babble)
        try:
            with progress(len(plans)) as bar:
                return _collect(map(_render_one, plans), bar)
        finally:
            _WORKER.pop("speaker").close()
    # fork: workers start at once (before the progress bar's thread exists); each opens its
    # own festival on first use.
    ctx = multiprocessing.get_context("fork")
    with ctx.Pool(jobs, _init_worker, (str(out), use_babble)) as pool:
        with progress(len(plans)) as bar:
            failures = _collect(pool.imap_unordered(_render_one, plans, chunksize=4), bar)
        pool.close()  # a clean exit lets each worker stop its festival
        pool.join()
    return failures


def progress(total: int) -> tqdm:
    """A progress bar on stderr: clips done, rate and time left (hidden when not a terminal)."""
    return tqdm(total=total, desc="synthesising", unit="clip", file=sys.stderr, disable=None)


def _collect(results, bar) -> dict[int, str]:
    failures = {}
    for index, problem in results:
        if problem:
            failures[index] = problem
        bar.update(1)
    return failures


# -- the corpus --------------------------------------------------------------------------------


def write_noise_folder(folder: Path, seed: int, sources: list[np.ndarray]) -> list[str]:
    """`_background_noise_/` with long noise recordings (0.1 RMS); the names written."""
    folder.mkdir()
    written = []
    for index, (name, seconds) in enumerate(NOISE_FILES.items()):
        kind = name.removesuffix("_noise")
        if kind == "babble" and not sources:
            continue
        rng = np.random.default_rng([seed, 1000 + index])
        x = 0.1 * noise_of(kind, seconds * SAMPLE_RATE, rng, sources)
        write_wav(folder / f"{name}.wav", to_int16(x))
        written.append(name)
    return written


def write_lists(out: Path, plans: list[ClipPlan], failures: dict[int, str]) -> None:
    """validation_list.txt and testing_list.txt, as GSCD has them."""
    for split, filename in LIST_FILES.items():
        names = sorted(p.name for p in plans if p.split == split and p.index not in failures)
        (out / filename).write_text("".join(f"{n}\n" for n in names))


def write_voices(out: Path, voices: list[Voice], split_of: dict[str, str],
                 plans: list[ClipPlan], failures: dict[int, str]) -> None:
    """voices.csv: voice id, engine, speaker (and its file-name hash), split, clips made."""
    made = Counter(p.voice.id for p in plans if p.index not in failures)
    with open(out / "voices.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["voice", "engine", "speaker", "speaker_id", "split", "count"])
        for v in voices:
            w.writerow([v.id, v.engine, v.speaker, speaker_hash(v.speaker),
                        split_of[v.speaker], made[v.id]])


def prepare_output(out: Path) -> Path:
    """The temporary folder next to `out` that becomes `out` when the corpus is complete."""
    if out.exists():
        raise UsageError(f"{out} already exists; choose a new folder or remove it")
    tmp = out.with_name(out.name + ".tmp")
    if tmp.exists():
        if not (tmp / PARTIAL_MARK).is_file():
            raise UsageError(f"{tmp} exists and is not an unfinished springc corpus; remove it")
        shutil.rmtree(tmp)  # left by an interrupted run
    (tmp / SCRATCH).mkdir(parents=True)
    (tmp / PARTIAL_MARK).write_text("an unfinished `springc data synth`; safe to delete\n")
    return tmp


def check_words(words: tuple[str, ...]) -> tuple[str, ...]:
    """The words asked for, each one of the 35 GSCD words."""
    unknown = [w for w in words if w not in WORDS]
    if unknown:
        raise UsageError(f"not GSCD words: {', '.join(unknown)}; choose from {' '.join(WORDS)}")
    return tuple(dict.fromkeys(words))


@dataclass
class SynthReport:
    """What `synthesise` made."""

    out: Path
    clips: int
    per_split: dict[str, int]
    voices: int
    speakers: int
    noise_files: list[str]
    notes: list[str]  # engines or voices skipped, clips that failed


def synthesise(out, *, clips: int = DEFAULT_CLIPS, seed: int = 0, jobs: int = 0,
               words: tuple[str, ...] = WORDS, voices: list[Voice] | None = None,
               engines: tuple[str, ...] = ENGINES) -> SynthReport:
    """Write a GSCD-layout corpus of `clips` clips into the new folder `out` (built in
    `out.tmp` and renamed when complete). `voices` defaults to every installed voice of
    `engines`; missing engines and voices are skipped with a note (DataError if none is left)."""
    out = Path(out)
    words = check_words(tuple(words))
    if clips < len(words):
        raise UsageError(f"--clips {clips} is fewer than the {len(words)} words")
    if out.exists():  # before the seconds spent finding voices
        raise UsageError(f"{out} already exists; choose a new folder or remove it")
    unknown = sorted(set(engines) - set(ENGINES))
    if unknown:
        raise UsageError(f"unknown engine(s): {', '.join(unknown)}; use {', '.join(ENGINES)}")
    notes: list[str] = []
    if voices is None:
        voices, notes = installed_voices(engines)
    for note in notes:
        warn(note)
    if not voices:
        raise DataError("text-to-speech engines", "no usable voice is installed",
                        hint="apt-get install espeak-ng flite festival festvox-kallpc16k")
    use_babble = bool(babble_sources())
    if not use_babble:
        notes.append("no speech recordings for babble noise (apt-get install codec2-examples "
                     "alsa-utils); babble left out")
        warn(notes[-1])
    plans, split_of = make_plan(voices, words, clips, seed, use_babble)
    tmp = prepare_output(out)
    try:
        for word in words:
            (tmp / word).mkdir()
        noise_files = write_noise_folder(tmp / NOISE_FOLDER, seed, babble_sources()
                                         if use_babble else [])
        failures = render_all(plans, tmp, jobs or os.cpu_count() or 1, use_babble)
        for index, problem in sorted(failures.items()):
            notes.append(f"{plans[index].name} ({plans[index].voice.id}): {problem}; left out")
            warn(notes[-1])
        if len(failures) == len(plans):
            raise DataError(str(out), "every clip failed to synthesise")
        write_lists(tmp, plans, failures)
        write_voices(tmp, voices, split_of, plans, failures)
        shutil.rmtree(tmp / SCRATCH)
        (tmp / PARTIAL_MARK).unlink()
        tmp.rename(out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    made = [p for p in plans if p.index not in failures]
    return SynthReport(out, len(made), dict(Counter(p.split for p in made)), len(voices),
                       len(split_of), noise_files, notes)
