"""The squaring unit of the paper's Fig. 6: one quadratic coupling from the terminal site of a
matched delay line into a leaky-integrator readout (paper Sec. III.B), swept over the squaring
error eps.

The squaring error is the paper's eps = A^2 gamma / alpha at the pulse amplitude A, with the
stiffness in units of the delay line's coupling kc (A^2 gamma / alpha is itself a stiffness,
N/m): eps = A^2 gamma / (alpha kc). `squaring_error` and `leverage_for` are the one definition
the classifier's heads use too (`springc.kws.training.transfer`). The unit's line has kc = 1 N/m,
so its eps is the paper's number as written.

With the readout's stiffness all from the coupling (k_r = 0, gamma alpha fixed by tau and Q_r),
x_l = A u and x_r = (A^2 / alpha) v turn the equations of motion into ones whose only
parameter is eps, so the peak-normalised readout and the energy transfer are functions of eps
alone. The sweep varies A at fixed gamma and alpha (one batch of runs through one kernel); the
ideal is the same unit's readout in the limit eps -> 0 (the leaky-integrated square of the pulse
the line delivers), taken from a run at `EPS_REFERENCE`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from springc.design import blocks

KC = 1.0  # N/m: the line's stiffness scale, so that eps is A^2 gamma / alpha as written
TS = 0.002  # s per site: the 8x3 classifier's lines (td 32 ms over 16 sites)
SITES = 4  # the matched input end absorbs what the coupling reflects: a short line suffices
SIGMA = 5 * TS  # the Gaussian pulse's width (the building-block figures' pulses: 5 sites)
TAU, QR = 80.0, blocks.READOUT_Q  # the paper's readout
GAMMA = 1.0  # N/m^2; alpha = k_r / gamma, the sweep moves A
EPSILONS = np.logspace(-4, 4, 17)  # Fig. 6c: half decades, 3.16e-2 among them
SHOWN = (1e-4, 10**-1.5, 1e4)  # Fig. 6d
EPS_REFERENCE = 1e-9  # the eps -> 0 limit: distortion of order eps, below every swept point
SUBSTEPS = 8  # RK4 per output step: the coupling's stiffness at eps = 1e4 stays inside RK4's region

UNIT_NET = """\
.title squaring unit: matched line, quadratic coupling, leaky-integrator readout (paper Fig. 6a)
.include "delayline.spr"
Xd x1 xl delayline n={n} td={ts} kc={kc} term=1 term_in=1
Qr xl xr g={g} a={a}
Mr xr m=1 b={br}
Fin x1 in(0)
"""


def squaring_error(amplitude: float, gamma, alpha, k_scale: float):
    """eps = A^2 gamma / (alpha k): the paper's squaring error of a quadratic coupling
    (gamma, alpha) driven at amplitude A, stiffness in units of the driving line's k."""
    return amplitude**2 * gamma / (alpha * k_scale)


def leverage_for(amplitude: float, gamma, epsilon: float, k_scale: float):
    """The leverage alpha that puts a coupling of strength gamma at squaring error eps."""
    return amplitude**2 * gamma / (epsilon * k_scale)


def amplitude_for(epsilon, gamma: float, alpha: float, k_scale: float):
    """The pulse amplitude at which a coupling (gamma, alpha) has squaring error eps."""
    return np.sqrt(np.asarray(epsilon, np.float64) * alpha * k_scale / gamma)


@dataclass(frozen=True)
class Unit:
    """The unit's parameters: line sites and delay per site, kc, coupling strength, readout
    time constant and quality factor, pulse width (s)."""

    sites: int = SITES
    ts: float = TS
    kc: float = KC
    gamma: float = GAMMA
    tau: float = TAU
    qr: float = QR
    sigma: float = SIGMA

    @property
    def readout(self) -> blocks.ReadoutParams:
        """The readout mass (1 kg) with all its stiffness from the coupling (k_r = 0)."""
        return blocks.readout_params(self.tau, self.qr, 1.0)

    @property
    def alpha(self) -> float:
        """gamma alpha = the readout's stiffness, which sets its time constant."""
        return self.readout.k_total / self.gamma

    @property
    def arrival(self) -> float:
        """When the pulse's centre reaches the terminal site (s): launched at 4 sigma, then
        ts per coupling and half a site more for the line's full-mass end sites (the centroid
        of x_l^2 at eps -> 0 is within 2e-6 s of it)."""
        return 4 * self.sigma + (self.sites - 0.5) * self.ts

    @property
    def tstop(self) -> float:
        """The simulated (and judged) span: the pulse, then 20 widths of readout."""
        return self.arrival + 20 * self.sigma

    def netlist(self) -> str:
        """The unit's `.spr` text."""
        from springc.design.emit import num

        return UNIT_NET.format(n=self.sites, ts=num(self.ts), kc=num(self.kc),
                               g=num(self.gamma), a=num(self.alpha), br=num(self.readout.b))

    def forces(self, amplitudes: np.ndarray, tstep: float) -> np.ndarray:
        """(runs, 1, samples): the force that launches a Gaussian displacement pulse of each
        amplitude from the matched input end (2 Z times the pulse's velocity: half of the work
        goes into the input's damper)."""
        t = np.arange(round(8 * self.sigma / tstep) + 1) * tstep
        t0 = 4 * self.sigma
        dgauss = -(t - t0) / self.sigma**2 * np.exp(-((t - t0) ** 2) / (2 * self.sigma**2))
        z = self.ts * self.kc
        return (np.asarray(amplitudes)[:, None] * 2 * z * dgauss[None, :])[:, None, :]


@dataclass(frozen=True)
class Sweep:
    """Per eps: the pulse amplitude, energy transfer E_out / E_in (readout dissipation over
    input work), distortion (RMS of the peak-normalised readout against the ideal) and gain
    (readout peak over the ideal's at the same amplitude: 1 for an exact square); the
    trajectories x_l, x_r (runs, T) and the peak-normalised ideal."""

    unit: Unit
    epsilon: np.ndarray
    amplitude: np.ndarray
    transfer: np.ndarray
    distortion: np.ndarray
    gain: np.ndarray
    t: np.ndarray
    x_l: np.ndarray
    x_r: np.ndarray
    ideal: np.ndarray


def simulate_unit(unit: Unit, amplitudes: np.ndarray, substeps: int = SUBSTEPS):
    """The unit's run for each pulse amplitude through springc's own compiler and simulator:
    the springc `Result` with x(xl), x(xr), the input work and the readout's dissipation."""
    from springc.api import load

    net = load(unit.netlist(), judge_step=False)
    tstep = unit.ts / 10
    return net.simulate(unit.forces(amplitudes, tstep), input_rate=1 / tstep, tstep=tstep,
                        tstop=unit.tstop, method="rk4", substeps=substeps,
                        precision="float64", probes=["x(xl)", "x(xr)"],
                        reduce=["work:Fin", "dissipated:Mr"])


def sweep(unit: Unit | None = None, epsilons: np.ndarray = EPSILONS,
          substeps: int = SUBSTEPS) -> Sweep:
    """Energy transfer, distortion and gain of the unit at every eps (paper Fig. 6c), one
    batch with the eps -> 0 reference run first."""
    unit = unit or Unit()
    eps = np.concatenate([[EPS_REFERENCE], np.asarray(epsilons, np.float64)])
    amps = amplitude_for(eps, unit.gamma, unit.alpha, unit.kc)
    res = simulate_unit(unit, amps, substeps)
    x_l, x_r = res["x(xl)"], res["x(xr)"]
    if not np.all(np.isfinite(x_r)):
        bad = eps[~np.all(np.isfinite(x_r), axis=1)]
        raise RuntimeError(f"squaring unit diverged at eps {bad.tolist()}: raise substeps")
    transfer = res.reductions["dissipated:Mr"] / res.reductions["work:Fin"]
    ideal = x_r[0] / x_r[0].max()
    peak = x_r.max(axis=1)
    distortion = np.sqrt(np.mean((x_r / peak[:, None] - ideal) ** 2, axis=1))
    gain = peak / (x_r[0].max() * (amps / amps[0]) ** 2)
    return Sweep(unit, eps[1:], amps[1:], transfer[1:], distortion[1:], gain[1:], res.t,
                 x_l[1:], x_r[1:], ideal)


def small_eps_readout(unit: Unit, t: np.ndarray, amplitude: float) -> np.ndarray:
    """The analytic eps -> 0 readout: the Gaussian pulse A g(t - arrival) squared and
    integrated by the readout's two poles p1 < p2, x_r = gamma / D sum_p +- int exp(-p (t-s))
    A^2 g^2(s) ds (D = sqrt(b^2 - 4 m k)), each integral an exponentially modified Gaussian."""
    from scipy.special import erfcx

    ro = unit.readout
    d = math.sqrt(ro.b**2 - 4 * ro.m * ro.k_total)
    p1, p2 = (ro.b - d) / (2 * ro.m), (ro.b + d) / (2 * ro.m)
    s = unit.sigma / math.sqrt(2)  # g^2 is a Gaussian of width sigma / sqrt(2)
    u = np.asarray(t) - unit.arrival

    def emg(p: float) -> np.ndarray:
        z = (p * s**2 - u) / (s * math.sqrt(2))
        return s * math.sqrt(math.pi / 2) * np.exp(-(u**2) / (2 * s**2)) * erfcx(z)

    return unit.gamma * amplitude**2 / d * (emg(p1) - emg(p2))
