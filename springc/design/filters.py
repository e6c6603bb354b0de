"""Analytic responses of the mechanical Mel filters and the Mel scale (paper Sec. III.A).

Shared by the filterbank design tool and the digital realisation of the KWS architecture.
"""

from __future__ import annotations

import numpy as np

DEFAULT_FMIN = 20.0  # Hz, lower edge of the Mel filterbank
DEFAULT_FMAX = 8000.0  # Hz, upper edge: Nyquist of 16 kHz speech


def hz_to_mel(f):
    """The HTK Mel scale."""
    return 2595.0 * np.log10(1.0 + np.asarray(f, dtype=np.float64) / 700.0)


def mel_to_hz(mel):
    """Inverse of `hz_to_mel`."""
    return 700.0 * (10.0 ** (np.asarray(mel, dtype=np.float64) / 2595.0) - 1.0)


def mel_edges(bins: int, fmin: float = DEFAULT_FMIN, fmax: float = DEFAULT_FMAX) -> np.ndarray:
    """The bins + 2 band edges (Hz), equally spaced in Mel; filter i spans edges i..i+2 and
    peaks at edge i+1, its centre."""
    return mel_to_hz(np.linspace(hz_to_mel(fmin), hz_to_mel(fmax), bins + 2))


def mel_triangles(f_hz: np.ndarray, bins: int, fmin: float = DEFAULT_FMIN,
                  fmax: float = DEFAULT_FMAX) -> np.ndarray:
    """Triangular Mel filter amplitudes, shape (bins, len(f_hz)), peak 1 at each centre."""
    e = mel_edges(bins, fmin, fmax)
    f = np.asarray(f_hz, dtype=np.float64)[None, :]
    lo, mid, hi = e[:-2, None], e[1:-1, None], e[2:, None]
    up = (f - lo) / (mid - lo)
    down = (hi - f) / (hi - mid)
    return np.clip(np.minimum(up, down), 0.0, None)


def two_mode_response(f_hz, fa: float, delta: float, alpha: float) -> np.ndarray:
    """Paper Eq. (filter-response): H = a wa^2/(wa^2 - w^2 + i a w) - a wb^2/(wb^2 - w^2 + i a w)
    with wb = delta * wa, for displacement of the filter's output mass, unnormalised."""
    w = 2 * np.pi * np.asarray(f_hz, dtype=np.float64)
    wa = 2 * np.pi * fa
    wb = delta * wa
    return (alpha * wa**2 / (wa**2 - w**2 + 1j * alpha * w)
            - alpha * wb**2 / (wb**2 - w**2 + 1j * alpha * w))


def single_mode_response(f_hz, f0: float, alpha: float) -> np.ndarray:
    """A single Lorentzian mode, alpha w0 / (w0^2 - w^2 + i alpha w), unnormalised: the
    response of one damped unit mass driven by force alpha * w0 (peak 1 at w0)."""
    w = 2 * np.pi * np.asarray(f_hz, dtype=np.float64)
    w0 = 2 * np.pi * f0
    return alpha * w0 / (w0**2 - w**2 + 1j * alpha * w)
