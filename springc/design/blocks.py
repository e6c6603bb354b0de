"""Parameters of the linear building blocks from their design targets (paper Sec. III).

The same formulas are written into the standard library subcircuits (`netlists/lib/*.spr`) as
parameter expressions; these functions are for design tools and tests that need the numbers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from springc.errors import UsageError

LOCAL_STIFFNESS_RATIO = 1e-6  # paper: k_l = 1e-6 k_c keeps the group velocity flat near DC
READOUT_Q = 0.01  # paper: quality factor of the leaky-integrator readout
LOWPASS_Q = 0.5  # critical damping: no resonance, least energy lost


@dataclass(frozen=True)
class DelayLineParams:
    """One site of a delay line: mass `m`, coupling `kc`, local stiffness `kl`, the matched
    termination damping `b_match` (N s/m) and the delay per site `td` (s)."""

    m: float
    kc: float
    kl: float
    b_match: float
    td: float


@dataclass(frozen=True)
class ReadoutParams:
    """An overdamped readout mass: `m`, local stiffness `k_local` (the total `k_total` minus what
    is supplied from outside), damping `b`, natural frequency `omega` (rad/s), `q` and the slow
    time constant `tau` (s)."""

    m: float
    k_local: float
    k_total: float
    b: float
    omega: float
    q: float
    tau: float


@dataclass(frozen=True)
class LowpassParams:
    """A critically damped low-pass mass: `m`, local stiffness `k`, local damping `b` (the total
    `b_total` minus what the attached delay lines supply) and cutoff `fc` (Hz)."""

    m: float
    k: float
    b: float
    b_total: float
    fc: float


def delayline_params(td: float, kc: float) -> DelayLineParams:
    """Delay line with delay `td` (s) per site and coupling `kc` (N/m): the long-wavelength group
    delay of Eq. (dispersion_rel) is sqrt(m / kc) per site, so m = td^2 kc; the characteristic
    impedance of the chain, sqrt(m kc), is the damping that terminates it without reflection."""
    _positive(td=td, kc=kc)
    m = td**2 * kc
    return DelayLineParams(m, kc, LOCAL_STIFFNESS_RATIO * kc, math.sqrt(m * kc), td)


def readout_omega(tau: float, qr: float = READOUT_Q) -> float:
    """Natural frequency (rad/s) whose slow overdamped decay has time constant `tau`:
    tau = 2Q / (w (1 - sqrt(1 - 4Q^2))), written without the cancellation of 1 - sqrt(...)."""
    _positive(tau=tau, qr=qr)
    if qr >= 0.5:
        raise UsageError(f"readout Q must be below 0.5 (overdamped), got {qr}")
    one_minus_root = 4 * qr**2 / (1 + math.sqrt(1 - 4 * qr**2))
    return 2 * qr / (tau * one_minus_root)


def readout_params(tau: float, qr: float = READOUT_Q, m: float = 1.0,
                   k_external: float = 0.0) -> ReadoutParams:
    """Leaky-integrator readout of mass `m` with time constant `tau` (s) and quality factor `qr`.
    `k_external` is stiffness supplied from outside (in the classifier the quadratic couplings
    give g a each); the local spring supplies the rest."""
    _positive(m=m)
    w = readout_omega(tau, qr)
    k_total = m * w**2
    if k_external > k_total:
        raise UsageError(f"external stiffness {k_external} exceeds the readout's total "
                         f"stiffness {k_total} for tau = {tau} s")
    return ReadoutParams(m, k_total - k_external, k_total, m * w / qr, w, qr, tau)


def lowpass_params(fc: float, k: float, b_external: float = 0.0) -> LowpassParams:
    """Critically damped (Q = 1/2) low-pass mass with cutoff `fc` (Hz) and stiffness `k`:
    m = k / (2 pi fc)^2 and b = m w / Q = 2 sqrt(k m). `b_external` is damping supplied by the
    delay lines it drives (their impedance); the local damping is the rest."""
    _positive(fc=fc, k=k)
    w = 2 * math.pi * fc
    m = k / w**2
    b_total = m * w / LOWPASS_Q
    if b_external > b_total:
        raise UsageError(f"external damping {b_external} exceeds the low-pass damping "
                         f"{b_total} at fc = {fc} Hz")
    return LowpassParams(m, k, b_total - b_external, b_total, fc)


def _positive(**values: float) -> None:
    for name, value in values.items():
        if not value > 0:
            raise UsageError(f"{name} must be positive, got {value}")
