"""Digital realisation of the paper's feature extraction (Sec. II): Mel filterbank, squaring,
cube-root compression and a critically damped low-pass, giving the features x_i(t).

Every linear stage is applied in the frequency domain with zero padding, so the result is the
linear (not circular) convolution with the stage's impulse response: the same signal the
mass-spring realisation produces when driven from rest. The chain for one clip u(t):

    y_i = h_i * u                         filter i of the bank (complex response H_i(f))
    v_i = (y_i^2)^(1/3) = |y_i|^(2/3)     squaring, then cube-root compression
    x_i'' + 2 w x_i' + w^2 x_i = w^2 v_i  low-pass, w = 2 pi fc (critically damped, Q = 1/2)

and x_i is sampled at `feature_rate` on t = 0, dt, ..., T with T = clip length + (m-1) t_d, so
that the last delay line still sees the end of the clip.
"""

from __future__ import annotations

import functools
import math
from dataclasses import asdict, dataclass

import numpy as np
from scipy import fft as sfft

from springc.design import filters
from springc.errors import UsageError

FILTERBANKS = ("two-mode", "single-mode", "triangular")


@dataclass(frozen=True)
class FeatureSettings:
    """Everything that determines the SVM features of a clip (paper Sec. II defaults)."""

    bins: int = 8
    delays: int = 3
    filterbank: str = "two-mode"
    td: float = 0.032  # s, delay between kernel taps
    tau: float = 80.0  # s, leaky-integrator time constant of the readout
    fc: float = 50.0  # Hz, low-pass cut-off
    feature_rate: float = 1000.0  # Hz, sampling rate of x_i(t)
    fmin: float = filters.DEFAULT_FMIN
    fmax: float = filters.DEFAULT_FMAX

    def validate(self, rate: float) -> None:
        """Raise UsageError for settings that cannot be realised at sample rate `rate`."""
        if self.bins < 2:
            raise UsageError(f"--bins must be at least 2 (got {self.bins})")
        if self.delays < 1:
            raise UsageError(f"--delays must be at least 1 (got {self.delays})")
        if self.filterbank not in FILTERBANKS:
            raise UsageError(f"unknown filterbank {self.filterbank!r}; use one of {FILTERBANKS}")
        if min(self.td, self.tau, self.fc, self.feature_rate) <= 0:
            raise UsageError("td, tau, fc and the feature rate must be positive")
        if not 0 < self.fmin < self.fmax <= rate / 2:
            raise UsageError(f"need 0 < fmin < fmax <= {rate / 2:g} Hz (Nyquist)")
        _integer_ratio(rate, self.feature_rate, "sample rate / feature rate")
        _integer_ratio(self.td * self.feature_rate, 1.0, "td * feature rate")

    def to_dict(self) -> dict:
        """Plain dict for settings.json and cache keys."""
        return asdict(self)


def _integer_ratio(a: float, b: float, what: str) -> int:
    ratio = a / b
    if abs(ratio - round(ratio)) > 1e-9 * max(1.0, ratio) or round(ratio) < 1:
        raise UsageError(f"{what} must be a positive integer (got {ratio:g})")
    return int(round(ratio))


def horizon(settings: FeatureSettings, clip_seconds: float) -> float:
    """Integration end T = clip length + (m-1) t_d (seconds)."""
    return clip_seconds + (settings.delays - 1) * settings.td


@functools.lru_cache(maxsize=32)
def melbank_filters(bins: int, kind: str, fmin: float, fmax: float) -> tuple:
    """The fitted mechanical Mel filters (`springc.design.melbank`), cached per process."""
    from springc.design.melbank import fit_melbank

    return tuple(fit_melbank(bins, fmin=fmin, fmax=fmax, kind=kind))


def filter_responses(f_hz: np.ndarray, settings: FeatureSettings) -> np.ndarray:
    """Responses of the bank at frequencies `f_hz`, shape (bins, len(f_hz)), peak 1 each:
    real Mel triangles (zero phase) or the complex responses of the mechanical filters.

    Applied to sampled audio on the FFT grid, this is the filters' exact response to the
    band-limited signal the samples stand for. The mechanical responses are not band-limited,
    so cutting them at Nyquist leaves a small precursor (Gibbs ringing, below 1% of the peak
    and within a few ms) before an impulse; the response itself is causal."""
    kind = settings.filterbank
    if kind == "triangular":
        return filters.mel_triangles(f_hz, settings.bins, settings.fmin, settings.fmax)
    if kind not in FILTERBANKS:
        raise UsageError(f"unknown filterbank {kind!r}; use one of {FILTERBANKS}")
    bank = melbank_filters(settings.bins, kind, settings.fmin, settings.fmax)
    return np.stack([f.response(f_hz) for f in bank])


@functools.lru_cache(maxsize=16)
def _bank_on_grid(settings: FeatureSettings, size: int, rate: float) -> np.ndarray:
    """`filter_responses` on the rfft grid of a `size`-point transform (reused per batch)."""
    return filter_responses(sfft.rfftfreq(size, 1.0 / rate), settings)


def lowpass_response(f_hz: np.ndarray, fc: float) -> np.ndarray:
    """Critically damped second-order low-pass w^2 / (w + i 2 pi f)^2, w = 2 pi fc: the
    response of x'' + 2 w x' + w^2 x = w^2 u (numpy's FFT sign convention, causal)."""
    w = 2 * np.pi * fc
    return w**2 / (w + 2j * np.pi * np.asarray(f_hz, dtype=np.float64)) ** 2


def _fft_size(length: int, decim: int) -> int:
    """A fast FFT length >= 2 * length (room for the causal tail: no wrap into [0, length)),
    divisible by `decim` so the output can be taken at the feature rate."""
    return decim * sfft.next_fast_len(math.ceil(2 * length / decim), real=True)


def features(signals: np.ndarray, rate: float, settings: FeatureSettings) -> np.ndarray:
    """The features x_i(t) of a batch of clips.

    signals: (clips, samples) at `rate` Hz. Returns (clips, bins, K+1) sampled at
    `settings.feature_rate` on t_k = k / feature_rate, k = 0..K, K = round(T * feature_rate),
    T = `horizon`. Input before t = 0 and after the clip is zero (the system starts at rest)."""
    signals = np.atleast_2d(np.asarray(signals, dtype=np.float64))
    settings.validate(rate)
    decim = _integer_ratio(rate, settings.feature_rate, "sample rate / feature rate")
    k_out = round(horizon(settings, signals.shape[1] / rate) * settings.feature_rate)
    length = (k_out + 1) * decim
    size = _fft_size(max(length, signals.shape[1]), decim)
    # single precision inside (relative error ~1e-6, far below the features' spread): the
    # transforms dominate the cost and run about twice as fast
    spectrum = sfft.rfft(signals.astype(np.float32), size, axis=-1)
    bank = _bank_on_grid(settings, size, rate).astype(np.complex64)
    y = sfft.irfft(spectrum[:, None, :] * bank[None], size, axis=-1)
    v = np.cbrt(np.square(y[..., :length]))
    x = _lowpass_decimate(v, rate, settings.fc, decim, size)[..., : k_out + 1]
    return x.astype(np.float64)


def _lowpass_decimate(v: np.ndarray, rate: float, fc: float, decim: int,
                      size: int) -> np.ndarray:
    """Low-pass `v` (zero-padded to `size`) and sample every `decim`-th point, band-limited:
    the spectrum is cut at the output Nyquist frequency before the inverse transform."""
    spectrum = sfft.rfft(v, size, axis=-1)
    spectrum *= lowpass_response(sfft.rfftfreq(size, 1.0 / rate), fc).astype(spectrum.dtype)
    size_out = size // decim
    kept = spectrum[..., : size_out // 2 + 1]
    return sfft.irfft(kept, size_out, axis=-1) / decim


def lowpass(u: np.ndarray, rate: float, fc: float) -> np.ndarray:
    """The low-pass stage alone on signals `u` (..., samples) at `rate`, same length out."""
    u = np.asarray(u, dtype=np.float64)
    size = _fft_size(u.shape[-1], 1)
    spectrum = sfft.rfft(u, size, axis=-1) * lowpass_response(sfft.rfftfreq(size, 1 / rate), fc)
    return sfft.irfft(spectrum, size, axis=-1)[..., : u.shape[-1]]


def filterbank(u: np.ndarray, rate: float, settings: FeatureSettings) -> np.ndarray:
    """The filterbank stage alone: (..., samples) -> (..., bins, samples), zero-padded FFT."""
    u = np.asarray(u, dtype=np.float64)
    size = _fft_size(u.shape[-1], 1)
    freqs = sfft.rfftfreq(size, 1.0 / rate)
    spectrum = sfft.rfft(u, size, axis=-1)[..., None, :] * filter_responses(freqs, settings)
    return sfft.irfft(spectrum, size, axis=-1)[..., : u.shape[-1]]
