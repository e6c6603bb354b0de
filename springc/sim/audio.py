"""Reading and resampling sound files: the one place that turns audio on disk into arrays.

Every failure is a `DataError` naming the file and the reason (missing, unreadable, empty,
wrong channel), never a traceback from soundfile.
"""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import numpy as np
import soundfile as sf
from scipy.signal import resample_poly

from springc.errors import DataError

AUDIO_SUFFIXES = (".wav", ".flac", ".ogg")


def read_audio(path: str | Path, channel: int | None = None) -> tuple[np.ndarray, int]:
    """Samples (float64, shape (frames,)) and sample rate of a sound file.

    `channel` picks one channel of a multi-channel file; None accepts only a mono file, so
    that stereo input is never mixed or truncated silently."""
    path = Path(path)
    if not path.is_file():
        raise DataError(str(path), "no such file")
    try:
        data, rate = sf.read(str(path), dtype="float64", always_2d=True)
    except Exception as exc:  # soundfile raises several types for corrupt files
        raise DataError(str(path), f"cannot read as audio ({exc})") from None
    if data.shape[0] == 0:
        raise DataError(str(path), "the file holds no samples")
    nch = data.shape[1]
    if channel is None:
        if nch != 1:
            raise DataError(str(path), f"has {nch} channels", hint="choose one with a channel")
        channel = 0
    if not 0 <= channel < nch:
        raise DataError(str(path), f"has {nch} channel(s); channel {channel} does not exist")
    return data[:, channel].copy(), int(rate)


def resample(signal: np.ndarray, rate_in: float, rate_out: float) -> np.ndarray:
    """Band-limited polyphase resampling from `rate_in` to `rate_out` (Hz)."""
    if rate_in == rate_out:
        return np.asarray(signal, dtype=np.float64)
    ratio = Fraction(rate_out / rate_in).limit_denominator(1000)
    return resample_poly(signal, ratio.numerator, ratio.denominator)


def load_audio(path: str | Path, rate: float, channel: int | None = None) -> np.ndarray:
    """Read a sound file and resample it to `rate` Hz."""
    data, rate_in = read_audio(path, channel)
    return resample(data, rate_in, rate)


def list_audio(folder: str | Path) -> list[Path]:
    """Sound files directly in `folder`, in sorted order."""
    folder = Path(folder)
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in AUDIO_SUFFIXES)
