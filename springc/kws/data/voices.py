"""The text-to-speech voices installed on this machine, and one process-local way to speak a
word with each (espeak-ng, flite, festival from Debian's main archive).

A voice is what an engine is asked for (`espeak:en-gb-scotland+f2`, `flite:slt`); its speaker
is the underlying recorded voice or synthetic model, shared across engines where the same
recordings were used (flite slt and festival slt; flite kal16 and festival kal), so that
splits can be made speaker-disjoint.
"""

from __future__ import annotations

import hashlib
import io
import re
import shutil
import subprocess
import tempfile
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Self

import numpy as np
import soundfile as sf

ENGINES = ("espeak", "flite", "festival")
ESPEAK_ACCENTS = ("en-us", "en-gb", "en-gb-scotland", "en-gb-x-rp", "en-029", "en-gb-x-gbclan",
                  "en-gb-x-gbcwmd", "en-us-nyc")
FLITE_VOICES = {"kal16": "kal", "awb": "awb", "rms": "rms", "slt": "slt"}
FESTIVAL_VOICES = {"kal_diphone": "kal", "ked_diphone": "ked", "cmu_us_slt_arctic_hts": "slt"}
DEBIAN_PACKAGES = {"espeak": "espeak-ng", "flite": "flite",
                   "festival": "festival festvox-kallpc16k festvox-kdlpc16k festvox-us-slt-hts"}
PROBE_WORD = "seven"
FESTIVAL_VOICE_ROOT = Path("/usr/share/festival/voices")
MARKER = "@@springc-done@@"
FESTIVAL_TIMEOUT_S = 60.0  # one word takes well under a second


class SynthesisError(Exception):
    """An engine failed to speak a word (caught by the synthesiser and reported by name)."""


@dataclass(frozen=True)
class Voice:
    """One engine voice: `id` names it, `speaker` is the underlying voice it shares."""

    id: str
    engine: str
    speaker: str
    spec: str  # what the engine is given: an espeak voice+variant, a flite or festival voice


def run(args: list[str], stdin: str | None = None, timeout: float = 60.0,
        error_word: str | None = None) -> bytes:
    """stdout of a command; SynthesisError when it fails, or when its stderr holds
    `error_word` (flite exits 0 after falling back to its default voice)."""
    try:
        done = subprocess.run(args, input=None if stdin is None else stdin.encode(),
                              capture_output=True, timeout=timeout, check=False)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise SynthesisError(f"{args[0]}: {exc}") from None
    stderr = done.stderr.decode(errors="replace").strip()
    if done.returncode != 0 or (error_word and error_word in stderr):
        raise SynthesisError(f"{' '.join(args)}: exit {done.returncode}: {stderr[:200]}")
    return done.stdout


def decode_wav(data: bytes, what: str) -> tuple[np.ndarray, int]:
    """Samples and rate of wav bytes; SynthesisError if there is no sound in them."""
    try:
        x, rate = sf.read(io.BytesIO(data), dtype="float64", always_2d=True)
    except Exception as exc:  # soundfile raises several types
        raise SynthesisError(f"{what}: no wav output ({exc})") from None
    if x.shape[0] == 0 or not np.any(x):
        raise SynthesisError(f"{what}: silent output")
    return x[:, 0], int(rate)


# -- enumerating what is installed -------------------------------------------------------------


def espeak_variants() -> list[str]:
    """The espeak-ng voice variants installed (`m1`, `f2`, `croak`, ...)."""
    listing = run(["espeak-ng", "--voices=variant"]).decode(errors="replace")
    return sorted({m.group(1) for m in re.finditer(r"!v/(\S+)", listing)})


def probe_variant(variant: str) -> tuple[str, str | None]:
    """(hash of the audio, None) of an espeak-ng variant saying the probe word, or ("", why)."""
    try:
        audio = run(["espeak-ng", "-v", f"en-us+{variant}", "--stdout", PROBE_WORD])
        x, _ = decode_wav(audio, f"variant {variant}")
    except SynthesisError as exc:
        return "", str(exc)
    return hashlib.sha1(np.round(x * 32768).astype(np.int16).tobytes()).hexdigest(), None


def espeak_voices(notes: list[str]) -> list[Voice]:
    """Every installed English accent with every variant. Variants that sound identical
    (several files differ only by name) are one speaker; silent ones are left out."""
    listing = run(["espeak-ng", "--voices=en"]).decode(errors="replace").split()
    accents = [a for a in ESPEAK_ACCENTS if a in listing]
    for a in sorted(set(ESPEAK_ACCENTS) - set(accents)):
        notes.append(f"espeak-ng: accent {a} not installed; skipped")
    variants = espeak_variants()
    with ThreadPoolExecutor(max_workers=8) as pool:  # subprocesses: threads overlap them
        probes = list(pool.map(probe_variant, variants))
    groups: dict[str, str] = {}  # audio hash -> first variant that sounded so
    speaker_of: dict[str, str] = {}
    for variant, (digest, problem) in zip(variants, probes):
        if problem:
            notes.append(f"espeak-ng: variant {variant} unusable ({problem}); skipped")
            continue
        speaker_of[variant] = groups.setdefault(digest, variant)
    return [Voice(f"espeak:{a}+{v}", "espeak", f"espeak-{a}+{speaker_of[v]}", f"{a}+{v}")
            for a in accents for v in sorted(speaker_of)]


def flite_voices(notes: list[str]) -> list[Voice]:
    """The wanted flite voices that `flite -lv` lists."""
    listing = run(["flite", "-lv"]).decode(errors="replace").split()
    found = []
    for name, speaker in FLITE_VOICES.items():
        if name in listing:
            found.append(Voice(f"flite:{name}", "flite", speaker, name))
        else:
            notes.append(f"flite: voice {name} not installed; skipped")
    return found


def festival_voices(notes: list[str]) -> list[Voice]:
    """The wanted festival voices that `(voice.list)` names."""
    # Debian keeps each voice in its own folder; asking festival costs a second's start-up.
    names = {p.name for p in FESTIVAL_VOICE_ROOT.glob("*/*") if p.is_dir()}
    if not names:
        listing = run(["festival", "--pipe"], stdin="(print (voice.list))\n")
        names = set(re.findall(r"[\w-]+", listing.decode(errors="replace")))
    found = []
    for name, speaker in FESTIVAL_VOICES.items():
        if name in names:
            found.append(Voice(f"festival:{name}", "festival", speaker, name))
        else:
            notes.append(f"festival: voice {name} not installed; skipped")
    return found


def installed_voices(engines: tuple[str, ...] = ENGINES) -> tuple[list[Voice], list[str]]:
    """(voices, notes): every usable voice of the wanted engines, and one note per engine or
    voice that is missing (with the Debian package that provides it)."""
    listers = {"espeak": ("espeak-ng", espeak_voices), "flite": ("flite", flite_voices),
               "festival": ("festival", festival_voices)}
    voices: list[Voice] = []
    notes: list[str] = []
    for engine in engines:
        program, lister = listers[engine]
        if shutil.which(program) is None:
            notes.append(f"{program}: not installed (apt-get install {DEBIAN_PACKAGES[engine]});"
                         " skipped")
            continue
        try:
            voices += lister(notes)
        except SynthesisError as exc:
            notes.append(f"{program}: cannot list its voices ({exc}); skipped")
    return voices, notes


# -- speaking ----------------------------------------------------------------------------------


class Speaker:
    """Speaks words with any voice; keeps one `festival --pipe` process open (starting one
    costs far more than a word) and a scratch folder for flite. Use as a context manager."""

    def __init__(self, scratch_root: Path | None = None) -> None:
        self.scratch = Path(tempfile.mkdtemp(prefix="springc-tts-", dir=scratch_root))
        self.festival: subprocess.Popen | None = None
        self.festival_voice = ""

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Stop festival and remove the scratch folder."""
        if self.festival is not None:
            self.festival.stdin.close()
            self.festival.wait(timeout=10)
            self.festival = None
        shutil.rmtree(self.scratch, ignore_errors=True)

    def say(self, voice: Voice, text: str, stretch: float, pitch: float) -> tuple[np.ndarray, int]:
        """(samples, rate) of `text` spoken by `voice`, slowed by `stretch` (>1 slower) and
        with its pitch scaled by `pitch` where the engine can do so."""
        if voice.engine == "espeak":
            return self.espeak(voice, text, stretch, pitch)
        if voice.engine == "flite":
            return self.flite(voice, text, stretch, pitch)
        if voice.engine == "festival":
            return self.say_festival(voice, text, stretch)
        raise TypeError(f"unknown engine {voice.engine!r}")

    def espeak(self, voice: Voice, text: str, stretch: float, pitch: float):
        args = ["espeak-ng", "-v", voice.spec, "-s", str(round(175 / stretch)),
                "-p", str(int(np.clip(round(50 * pitch), 0, 99))), "--stdout", text]
        return decode_wav(run(args), voice.id)

    def flite(self, voice: Voice, text: str, stretch: float, pitch: float):
        out = self.scratch / "flite.wav"
        out.unlink(missing_ok=True)
        run(["flite", "-voice", voice.spec, "-t", text, "-o", str(out),
             "--setf", f"duration_stretch={stretch:.4f}",
             "--setf", f"int_f0_target_mean={100 * pitch:.2f}"], error_word="Error")
        if not out.is_file():
            raise SynthesisError(f"{voice.id}: flite wrote no file")
        return decode_wav(out.read_bytes(), voice.id)

    def festival_command(self, command: str) -> str:
        """Send one Scheme command to the persistent festival; its output up to the marker."""
        if self.festival is None:
            self.festival = subprocess.Popen(
                ["festival", "--pipe"], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT, text=True, bufsize=1)
        proc = self.festival
        try:
            proc.stdin.write(f'{command}\n(format t "{MARKER}\\n")(fflush nil)\n')
            proc.stdin.flush()
        except BrokenPipeError:
            self.festival = None
            raise SynthesisError("festival exited") from None
        lines = []
        # A watchdog: festival waiting on something forever is killed, and reads EOF below.
        watchdog = threading.Timer(FESTIVAL_TIMEOUT_S, proc.kill)
        watchdog.start()
        try:
            for line in proc.stdout:
                if MARKER in line:
                    return "".join(lines)
                lines.append(line)
        finally:
            watchdog.cancel()
        self.festival = None
        self.festival_voice = ""
        raise SynthesisError(f"festival exited or hung: {''.join(lines)[-200:]}")

    def say_festival(self, voice: Voice, text: str, stretch: float):
        if self.festival_voice != voice.spec:
            self.festival_voice = ""
            reply = self.festival_command(f"(voice_{voice.spec})")
            if "SIOD ERROR" in reply:
                raise SynthesisError(f"{voice.id}: {reply.strip()[:200]}")
            self.festival_voice = voice.spec
        out = self.scratch / "festival.wav"
        out.unlink(missing_ok=True)
        quoted = text.replace("\\", " ").replace('"', " ")
        reply = self.festival_command(
            f"(Parameter.set 'Duration_Stretch {stretch:.4f})"
            f'(utt.save.wave (utt.synth (Utterance Text "{quoted}")) "{out}" \'riff)')
        if "SIOD ERROR" in reply or not out.is_file():
            raise SynthesisError(f"{voice.id}: {reply.strip()[:200] or 'no file written'}")
        return decode_wav(out.read_bytes(), voice.id)
