"""Fit mechanical Mel filters to triangular Mel filters (paper Sec. III.A, Eq. filter-response).

Each bin of the filterbank is realised either by two coupled unit masses (the "two-mode"
filter: a symmetric mode at `wa` and an antisymmetric mode at `wb = delta * wa`, driven with
opposite-signed forces so that they cancel at DC) or, for comparison, by one damped mass (the
"single-mode" Lorentzian). The fit is a least-squares match of the peak-normalised amplitude
response to the triangle on a uniform frequency grid from 0 to `fmax`, initialised as in the
paper: `wa` at the Mel centre, `delta = 1.1`, `alpha = 400` rad/s.

The peak is pinned to the Mel centre, where the triangle peaks: left free, the least-squares fit
moves the peak of the lowest bin 11% above its centre (for 8 bins from 20 Hz to 8 kHz), because
neither response can follow the triangle's corner and the fit trades the peak position for a
broader shoulder. Pinning costs little misfit and keeps the bins in Mel order. It is exact
because the responses are scale invariant: H(w; s wa, delta, s alpha) = H(w / s; wa, delta,
alpha), so the fit runs over the shape (delta and r = alpha / wa) and `wa` follows from the
peak of the shape.

The amplitude is what is fitted: the paper disregards the phase, and so do the features.

Every bin is also fitted from the previous bin's optimum shape, and the better fit is kept: with
many bins the upper ones are so wide that the paper's alpha = 400 rad/s makes a two-mode filter
with two separate resonance peaks, where the fit stalls (the peak jumps from one resonance to
the other as the parameters move).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

from springc.design.emit import SprWriter, num, write_atomic
from springc.design.filters import (
    DEFAULT_FMAX,
    DEFAULT_FMIN,
    mel_edges,
    mel_triangles,
    single_mode_response,
    two_mode_response,
)
from springc.errors import UsageError

KINDS = ("two-mode", "single-mode")
INIT_DELTA = 1.1  # paper: initial relative spacing of the two modes
INIT_ALPHA = 400.0  # paper: initial mass-proportional damping, rad/s
GRID_POINTS = 4000  # fitting grid: about 2 Hz spacing up to 8 kHz, finer than the narrowest bin
# Smallest split delta - 1 of a two-mode filter's modes. As delta -> 1 the normalised response
# tends to a limit shape that the widest bins fit best, so the misfit falls ever more slowly
# there and the fit would stop wherever the machine's rounding leaves it; such a filter is the
# difference of two nearly equal modes, which a fabricated device cannot match (local
# mismatch about 3e-3, ../shared/design/device-anchors.md). At the bound the fit is well posed.
MIN_SPLIT = 0.01


@dataclass(frozen=True)
class MelFilter:
    """One fitted filter. `fa` (Hz) is the first mode (the only one for single-mode), `delta`
    the ratio wb/wa (1.0 for single-mode), `alpha` the damping per unit mass (rad/s), `gain` the
    factor that makes the peak amplitude 1, `centre` the Mel centre (Hz) it was fitted to and
    `misfit` the relative L2 error ||(|H| - T)|| / ||T|| on the fitting grid."""

    kind: str
    fa: float
    delta: float
    alpha: float
    gain: float
    centre: float
    misfit: float

    def response(self, f_hz) -> np.ndarray:
        """Complex response at `f_hz` (displacement of the output mass), peak amplitude 1."""
        return self.gain * _raw_response(self.kind, f_hz, self.fa, self.delta, self.alpha)

    def peak_hz(self) -> float:
        """Frequency (Hz) of the amplitude peak."""
        return _peak(self.kind, self.fa, self.delta, self.alpha)[0]

    @property
    def fb(self) -> float:
        """Frequency (Hz) of the second (antisymmetric) mode."""
        return self.delta * self.fa


def fit_melbank(bins: int, fmin: float = DEFAULT_FMIN, fmax: float = DEFAULT_FMAX,
                kind: str = "two-mode") -> list[MelFilter]:
    """Fit `bins` mechanical filters of `kind` ("two-mode" or "single-mode") to the triangular
    Mel filters between `fmin` and `fmax` (Hz); each returned filter has peak amplitude 1."""
    if kind not in KINDS:
        raise UsageError(f"unknown filter kind {kind!r}; expected one of {KINDS}")
    if bins < 1 or not 0 <= fmin < fmax:
        raise UsageError(f"need bins >= 1 and 0 <= fmin < fmax, got {bins}, {fmin}, {fmax}")
    f = fitting_grid(fmax)
    targets = mel_triangles(f, bins, fmin, fmax)
    centres = mel_edges(bins, fmin, fmax)[1:-1]
    out: list[MelFilter] = []
    for target, centre in zip(targets, centres):
        starts = [_initial(kind, centre)] + ([_shape(out[-1])] if out else [])
        out.append(min((_fit_one(kind, f, target, centre, p0) for p0 in starts),
                       key=lambda flt: flt.misfit))
    return out


def fitting_grid(fmax: float) -> np.ndarray:
    """The uniform frequency grid (Hz) on which the misfit is measured: (0, fmax]."""
    return np.linspace(0.0, fmax, GRID_POINTS + 1)[1:]


def misfit(amplitude: np.ndarray, target: np.ndarray) -> float:
    """Relative L2 misfit ||amplitude - target|| / ||target||."""
    return float(np.linalg.norm(amplitude - target) / np.linalg.norm(target))


def _raw_response(kind: str, f_hz, fa: float, delta: float, alpha: float) -> np.ndarray:
    if kind == "two-mode":
        return two_mode_response(f_hz, fa, delta, alpha)
    if kind == "single-mode":
        return single_mode_response(f_hz, fa, alpha)
    raise UsageError(f"unknown filter kind {kind!r}")


def _peak(kind: str, fa: float, delta: float, alpha: float) -> tuple[float, float]:
    """(frequency, amplitude) of the amplitude peak of the unnormalised response, in closed
    form. The responses scale: the two-mode H(w; wa, delta, alpha) = wa h(w / wa; delta, r =
    alpha / wa), the single-mode one (driven by alpha w0, not alpha w0^2) H = h(w / wa; r),
    and |h(u)|^2 is a rational function of s = u^2 whose maximum is a root of its
    derivative's numerator (a quintic for two modes, linear for one). The fit needs the peak
    exact and smooth in the parameters: a peak searched numerically to 1e-8 makes the
    least-squares Jacobian (finite differences of 1e-6) noise, and the fit then stops at a
    point that moves with the machine's rounding (the filterbank, and every feature, differed
    by percents between CPUs with and without AVX-512)."""
    wa = 2 * np.pi * fa
    r = alpha / wa
    if kind == "two-mode":
        s, amp = _two_mode_peak(delta, r)
        return fa * math.sqrt(s), wa * amp
    s, amp = _single_mode_peak(r)
    return fa * math.sqrt(s), amp


def _two_mode_peak(delta: float, r: float) -> tuple[float, float]:
    """(s, |h|) at the maximum of |h(u)|^2 = r^2 (delta^2 - 1)^2 s (s + r^2) /
    (((1 - s)^2 + r^2 s) ((delta^2 - s)^2 + r^2 s)), s = u^2 > 0."""
    d2, r2 = delta * delta, r * r
    top = np.array([1.0, r2, 0.0])  # coefficients, highest power first
    bottom = np.convolve([1.0, r2 - 2.0, 1.0], [1.0, r2 - 2.0 * d2, d2 * d2])
    roots = np.roots(np.polysub(np.convolve(np.polyder(top), bottom),
                                np.convolve(top, np.polyder(bottom))))
    s = roots.real[(np.abs(roots.imag) <= 1e-9 * np.abs(roots)) & (roots.real > 0)]
    power = (r * (d2 - 1.0)) ** 2 * np.polyval(top, s) / np.polyval(bottom, s)
    k = int(np.argmax(power))
    return float(s[k]), float(np.sqrt(power[k]))


def _single_mode_peak(r: float) -> tuple[float, float]:
    """(s, |h|) at the maximum of |h(u)|^2 = r^2 / ((1 - s)^2 + r^2 s): at s = 1 - r^2 / 2
    where that is positive, else at s = 0 (an overdamped mode peaks at rest)."""
    s = max(1.0 - r * r / 2.0, 0.0)
    return s, r / math.sqrt((1.0 - s) ** 2 + r * r * s)


def _unpack(kind: str, p: np.ndarray, centre: float) -> tuple[float, float, float]:
    """Shape parameters -> (fa, delta, alpha) with the peak at `centre`; logs keep r > 0 and
    delta > 1. The shape is (delta, r = alpha / wa); fa scales it so that the peak lands on the
    centre."""
    if kind == "two-mode":
        delta, r = 1.0 + float(np.exp(p[0])), float(np.exp(p[1]))
    else:
        delta, r = 1.0, float(np.exp(p[0]))
    unit_peak = _peak(kind, 1.0, delta, 2 * np.pi * r)[0]  # peak (Hz) of the shape at fa = 1 Hz
    fa = centre / unit_peak
    return fa, delta, 2 * np.pi * fa * r


def _normalised_amplitude(kind: str, f: np.ndarray, p: np.ndarray, centre: float) -> np.ndarray:
    fa, delta, alpha = _unpack(kind, p, centre)
    return np.abs(_raw_response(kind, f, fa, delta, alpha)) / _peak(kind, fa, delta, alpha)[1]


def _initial(kind: str, centre: float) -> np.ndarray:
    """The paper's start: wa at the centre, delta = 1.1, alpha = 400 rad/s (as a shape)."""
    r = INIT_ALPHA / (2 * np.pi * centre)
    if kind == "two-mode":
        return np.array([np.log(INIT_DELTA - 1.0), np.log(r)])
    return np.array([np.log(r)])


def _shape(flt: MelFilter) -> np.ndarray:
    """The fit parameters of a fitted filter, to start the next bin from."""
    r = np.log(flt.alpha / (2 * np.pi * flt.fa))
    return np.array([np.log(flt.delta - 1.0), r]) if flt.kind == "two-mode" else np.array([r])


def _fit_one(kind: str, f: np.ndarray, target: np.ndarray, centre: float,
             p0: np.ndarray) -> MelFilter:
    lower = np.full(len(p0), -np.inf)
    if kind == "two-mode":
        lower[0] = math.log(MIN_SPLIT)
    sol = least_squares(lambda p: _normalised_amplitude(kind, f, p, centre) - target,
                        np.maximum(p0, lower), bounds=(lower, np.inf), diff_step=1e-6,
                        xtol=1e-12, ftol=1e-12)
    fa, delta, alpha = _unpack(kind, sol.x, centre)
    gain = 1.0 / _peak(kind, fa, delta, alpha)[1]
    err = misfit(np.abs(_raw_response(kind, f, fa, delta, alpha)) * gain, target)
    return MelFilter(kind, fa, delta, alpha, gain, float(centre), err)


@dataclass(frozen=True)
class Melbank:
    """Both fits of one filterbank, for reporting and writing."""

    bins: int
    fmin: float
    fmax: float
    two_mode: tuple[MelFilter, ...]
    single_mode: tuple[MelFilter, ...]

    def filters(self, kind: str) -> tuple[MelFilter, ...]:
        """The filters of `kind`."""
        return self.two_mode if kind == "two-mode" else self.single_mode


def design_melbank(bins: int, fmin: float = DEFAULT_FMIN,
                   fmax: float = DEFAULT_FMAX) -> Melbank:
    """Fit both kinds of filter to the same Mel triangles."""
    return Melbank(bins, fmin, fmax, tuple(fit_melbank(bins, fmin, fmax, "two-mode")),
                   tuple(fit_melbank(bins, fmin, fmax, "single-mode")))


def misfit_table(bank: Melbank) -> str:
    """Per-bin centre, fitted parameters and misfit of both kinds, as aligned text."""
    rows = [(f"{'bin':>3} {'centre Hz':>10} {'fa Hz':>10} {'delta':>7} {'alpha':>9} "
            f"{'misfit 2-mode':>13} {'misfit 1-mode':>13}")]
    for i, (two, one) in enumerate(zip(bank.two_mode, bank.single_mode)):
        rows.append(f"{i:3d} {two.centre:10.2f} {two.fa:10.2f} {two.delta:7.4f} "
                    f"{two.alpha:9.2f} {two.misfit:13.4f} {one.misfit:13.4f}")
    two = np.mean([f.misfit for f in bank.two_mode])
    one = np.mean([f.misfit for f in bank.single_mode])
    rows.append(f"{'mean':>43} {two:13.4f} {one:13.4f}")
    return "\n".join(rows)


def melbank_text(bank: Melbank, kind: str = "two-mode", name: str = "melbank") -> str:
    """`.spr` text: a header with the fit report, then `.subckt name out0 .. ch=0` built from
    the standard library's `melfilter` (two-mode) or `melfilter1` (single-mode)."""
    w = SprWriter()
    w.comment(f"{name}: {bank.bins} mechanical Mel filters ({kind}) fitted to triangular Mel "
              f"filters from {num(bank.fmin)} Hz to {num(bank.fmax)} Hz by `springc design "
              f"melbank` (paper Sec. III.A, Eq. filter-response, Fig. 4). Peak response 1 at "
              f"each Mel centre; misfit = ||(|H| - T)|| / ||T|| on a uniform grid to fmax.")
    w.comment("Ports: out0 .. out{N-1}, the filter outputs (m per unit input). Param: ch, the "
              "input channel that drives every filter.")
    w.comment("")
    w.lines.extend(f"* {line}" for line in misfit_table(bank).splitlines())
    w.blank()
    w.include("melfilter.spr")
    w.blank()
    w.subckt(name, [f"out{i}" for i in range(bank.bins)], {"ch": 0})
    for i, f in enumerate(bank.filters(kind)):
        if kind == "two-mode":
            w.statement(f"Xb{i}", f"out{i}", "melfilter", f"fa={num(f.fa)}",
                        f"delta={num(f.delta)}", f"alpha={num(f.alpha)}", "ch={ch}",
                        f"gain={num(f.gain)}")
        else:
            w.statement(f"Xb{i}", f"out{i}", "melfilter1", f"f0={num(f.fa)}",
                        f"alpha={num(f.alpha)}", "ch={ch}", f"gain={num(f.gain)}")
    w.ends(name)
    return w.text()


def write_melbank(bank: Melbank, path: str | Path, kind: str = "two-mode",
                  name: str = "melbank") -> Path:
    """Write `melbank_text` to `path` atomically."""
    if kind not in KINDS:
        raise UsageError(f"unknown filter kind {kind!r}; expected one of {KINDS}")
    return write_atomic(path, melbank_text(bank, kind, name))
