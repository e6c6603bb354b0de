"""The paper's pre-processing of a speech clip before it excites a mass-spring model (Sec. IV):
centre the utterance in the window, then subtract the slowly varying background that a
Savitzky-Golay filter finds (cut-off about 75 Hz), leaving the speech band."""

from __future__ import annotations

import functools

import numpy as np
from scipy.ndimage import uniform_filter1d
from scipy.signal import savgol_coeffs, savgol_filter

SAVGOL_ORDER = 3  # cubic; a symmetric Savitzky-Golay filter of order 3 equals that of order 2
ENVELOPE_S = 0.02  # energy envelope smoothing: about two pitch periods of a low voice
FLOOR_PERCENTILE = 20.0  # the quietest fifth of a 1 s clip is taken as its noise floor


def lowpass_cutoff(window: int, rate: float, order: int = SAVGOL_ORDER) -> float:
    """The 3 dB frequency (Hz) of the Savitzky-Golay smoother: where its zero-phase response
    first falls to 1/sqrt(2) (searched below twice Schafer's estimate, 0.2 % resolution)."""
    coeffs = savgol_coeffs(window, order)
    lags = np.arange(window) - window // 2
    estimate = (order + 1) / (3.2 * (window // 2) - 4.6) * rate / 2.0
    freqs = np.linspace(0.0, min(2.0 * estimate, rate / 2.0), 1001)
    response = np.cos(2.0 * np.pi * np.outer(freqs, lags) / rate) @ coeffs
    return float(freqs[np.argmax(response < 2.0**-0.5)])


@functools.lru_cache(maxsize=32)
def savgol_window(rate: float, cutoff_hz: float, order: int = SAVGOL_ORDER) -> int:
    """The (odd) window length whose Savitzky-Golay smoother has its 3 dB point nearest to
    `cutoff_hz`. Schafer's approximation f_c / (rate / 2) ~= (N + 1) / (3.2 M - 4.6) (order N,
    half-width M; "What is a Savitzky-Golay filter?", 2011) is about 20 % off at these
    widths, so the exact response is bisected over the half-width (the cut-off falls as the
    window grows)."""
    lo, hi = order + 2, max(order + 3, int(2.0 * (order + 1) * rate / 2.0 / cutoff_hz))
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (mid, hi) if lowpass_cutoff(2 * mid + 1, rate, order) > cutoff_hz else (lo, mid)
    best = min((lo, hi), key=lambda m: abs(lowpass_cutoff(2 * m + 1, rate, order) - cutoff_hz))
    return 2 * best + 1


def slow_background(x: np.ndarray, rate: float, cutoff_hz: float = 75.0) -> np.ndarray:
    """The slowly varying part of `x` (below about `cutoff_hz`), along the last axis."""
    x = np.asarray(x, dtype=np.float64)
    window = savgol_window(rate, cutoff_hz)
    n = x.shape[-1]
    if n < window:
        # Shorter than the filter: fit one polynomial to all of it (the slowest available).
        window = n if n % 2 else n - 1
        if window <= SAVGOL_ORDER:
            return np.broadcast_to(x.mean(axis=-1, keepdims=True), x.shape).copy()
    return savgol_filter(x, window, SAVGOL_ORDER, axis=-1, mode="interp")


def remove_background(x: np.ndarray, rate: float, cutoff_hz: float = 75.0) -> np.ndarray:
    """`x` minus its Savitzky-Golay background: a high-pass with its 3 dB point near
    `cutoff_hz`, removing drift, hum and wind below the speech band (works along the last axis,
    so a batch of clips of shape (batch, samples) is filtered at once)."""
    x = np.asarray(x, dtype=np.float64)
    return x - slow_background(x, rate, cutoff_hz)


def energy_centroid(x: np.ndarray, rate: float) -> float:
    """The time (in samples) of the centre of the clip's energy above its noise floor."""
    x = np.asarray(x, dtype=np.float64)
    width = max(int(ENVELOPE_S * rate), 1)
    envelope = uniform_filter1d(x * x, width, mode="constant")
    # Subtracting the floor keeps steady background noise from pulling the centre to the middle.
    excess = np.clip(envelope - np.percentile(envelope, FLOOR_PERCENTILE), 0.0, None)
    total = excess.sum()
    if total <= 0.0:
        return (len(x) - 1) / 2.0
    return float((np.arange(len(x)) * excess).sum() / total)  # not BLAS: tiny, threads cost


def shift(x: np.ndarray, samples: int) -> np.ndarray:
    """`x` delayed by `samples` (advanced if negative), zero-filled, same length."""
    out = np.zeros_like(x)
    n = len(x)
    if samples >= 0:
        out[samples:] = x[: max(n - samples, 0)]
    else:
        out[: max(n + samples, 0)] = x[-samples:]
    return out


def centre_utterance(x: np.ndarray, rate: float) -> np.ndarray:
    """`x` shifted (zero-filled) so that the energy centroid of the utterance sits in the middle
    of the window. A silent clip is returned unchanged."""
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 1:
        raise ValueError(f"centre_utterance expects one clip of shape (samples,), got {x.shape}")
    move = round((len(x) - 1) / 2.0 - energy_centroid(x, rate))
    return shift(x, move)


def preprocess(x: np.ndarray, rate: float, cutoff_hz: float = 75.0) -> np.ndarray:
    """The paper's pre-processing of one clip: the utterance centred in the window, without
    its background below about `cutoff_hz`. The background goes first so that a slow drift,
    which can carry more energy than the speech, does not pull the centre (the filter is
    time-invariant, so the order changes nothing else but the zero-filled ends)."""
    return centre_utterance(remove_background(x, rate, cutoff_hz), rate)
