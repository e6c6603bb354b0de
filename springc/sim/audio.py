"""Reading and resampling sound files: the one place that turns audio on disk into arrays.

Every failure is a `DataError` naming the file and the reason (missing, unreadable, empty,
truncated, non-finite samples, wrong channel), never a traceback from soundfile.
"""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import struct

import numpy as np

from springc.errors import DataError

AUDIO_SUFFIXES = (".wav", ".flac", ".ogg")


def read_audio(path: str | Path, channel: int | None = None) -> tuple[np.ndarray, int]:
    """Samples (float64, shape (frames,)) and sample rate of a sound file.

    `channel` picks one channel of a multi-channel file; None accepts only a mono file, so
    that stereo input is never mixed or truncated silently."""
    path = Path(path)
    if not path.is_file():
        raise DataError(str(path), "is a folder, not a sound file" if path.is_dir()
                        else "no such file")
    data, rate = read_checked(path)
    nch = data.shape[1]
    if channel is None:
        if nch != 1:
            raise DataError(str(path), f"has {nch} channels", hint="choose one with a channel")
        channel = 0
    if not 0 <= channel < nch:
        raise DataError(str(path), f"has {nch} channel(s); channel {channel} does not exist")
    return data[:, channel].copy(), int(rate)


def read_checked(path: Path) -> tuple[np.ndarray, int]:
    """All channels (float64, shape (frames, channels)) and the rate of a sound file; DataError
    for an unreadable, truncated or empty file or one holding NaN or infinite samples."""
    import soundfile as sf  # its C library loads in a few tens of ms: only to read sound

    try:
        data, rate = sf.read(str(path), dtype="float64", always_2d=True)
    except Exception as exc:  # soundfile raises several types for corrupt files
        raise DataError(str(path), f"cannot read as audio ({exc})") from None
    short = wav_truncation(path)
    if short:
        raise DataError(str(path), short)
    if data.shape[0] == 0:
        raise DataError(str(path), "the file holds no samples")
    bad = non_finite(data, rate)
    if bad:
        raise DataError(str(path), bad)
    return data, int(rate)


def non_finite(data: np.ndarray, rate: float) -> str | None:
    """Where the first NaN or infinite sample of `data` (frames, channels) is, or None."""
    finite = np.isfinite(data)
    if finite.all():
        return None
    frame, ch = np.argwhere(~finite)[0]
    value = data[frame, ch]
    return (f"sample {frame} of channel {ch} (t = {frame / rate:g} s) is {value} "
            f"({(~finite).sum()} non-finite sample(s) in all)")


def wav_truncation(path: Path) -> str | None:
    """Why a RIFF/WAVE file is cut short (its data chunk announces more bytes than the file
    holds), or None. libsndfile reads what is there without a word, so a recording cut off
    by a full disk or an interrupted copy would pass as a shorter sound."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(12)
            if len(head) < 12 or head[:4] != b"RIFF" or head[8:12] != b"WAVE":
                return None
            size = path.stat().st_size
            while True:
                chunk = fh.read(8)
                if len(chunk) < 8:
                    return None
                name, length = chunk[:4], struct.unpack("<I", chunk[4:])[0]
                if name == b"data":
                    held = size - fh.tell()
                    # 0 and 0xFFFFFFFF: a streaming writer that never filled the size in
                    if length in (0, 0xFFFFFFFF) or held >= length:
                        return None
                    return (f"truncated: the data chunk announces {length} bytes but the file "
                            f"holds {held}")
                fh.seek(length + (length & 1), 1)  # chunks are padded to even sizes
    except OSError:
        return None


def resample(signal: np.ndarray, rate_in: float, rate_out: float) -> np.ndarray:
    """Band-limited polyphase resampling from `rate_in` to `rate_out` (Hz)."""
    if rate_in == rate_out:
        return np.asarray(signal, dtype=np.float64)
    ratio = Fraction(rate_out / rate_in).limit_denominator(1000)
    from scipy.signal import resample_poly  # 1 s of imports: only when a rate differs

    return resample_poly(signal, ratio.numerator, ratio.denominator)


def load_audio(path: str | Path, rate: float, channel: int | None = None) -> np.ndarray:
    """Read a sound file and resample it to `rate` Hz."""
    data, rate_in = read_audio(path, channel)
    return resample(data, rate_in, rate)


def list_audio(folder: str | Path) -> list[Path]:
    """Sound files directly in `folder`, in sorted order."""
    folder = Path(folder)
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in AUDIO_SUFFIXES)
