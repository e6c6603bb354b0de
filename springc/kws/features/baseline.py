"""The conventional baseline: a log-Mel spectrogram (25 ms windows, 10 ms hop, 40 Mel bands)
flattened into one vector per clip, classified by logistic regression (`svm.select` with
kind="logreg"), on the same splits as the springtronic architecture."""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from springc.design.filters import DEFAULT_FMAX, DEFAULT_FMIN, mel_triangles

WINDOW_S = 0.025
HOP_S = 0.010
MEL_BANDS = 40
FLOOR = 1e-10  # power floor before the log, far below 16-bit quantisation noise


def baseline_settings() -> dict:
    """The fixed settings of the baseline, stored in the model folder."""
    return {"window_s": WINDOW_S, "hop_s": HOP_S, "mel_bands": MEL_BANDS,
            "fmin": DEFAULT_FMIN, "fmax": DEFAULT_FMAX}


def log_mel(signals: np.ndarray, rate: float) -> np.ndarray:
    """Log-Mel spectrograms, shape (clips, frames, MEL_BANDS), of signals (clips, samples):
    Hann-windowed frames, power spectrum, triangular Mel filterbank, natural log."""
    signals = np.atleast_2d(np.asarray(signals, dtype=np.float64))
    win, hop = round(WINDOW_S * rate), round(HOP_S * rate)
    nfft = 1 << (win - 1).bit_length()
    frames = sliding_window_view(signals, win, axis=-1)[:, ::hop, :] * np.hanning(win)
    power = np.abs(np.fft.rfft(frames, nfft, axis=-1)) ** 2
    bank = mel_triangles(np.fft.rfftfreq(nfft, 1.0 / rate), MEL_BANDS, DEFAULT_FMIN,
                         min(DEFAULT_FMAX, rate / 2))
    return np.log(power @ bank.T + FLOOR)


def baseline_features(signals: np.ndarray, rate: float) -> np.ndarray:
    """The flattened log-Mel vector per clip, shape (clips, frames * MEL_BANDS)."""
    spec = log_mel(signals, rate)
    return spec.reshape(spec.shape[0], -1)
