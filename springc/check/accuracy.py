"""Per-mode error estimates of an integrator, and the tolerance-driven choice of step.

For a mode with eigenvalue lambda and step h, one step multiplies the mode by R(z), z = h
lambda (the tableau's stability polynomial), where the exact flow multiplies it by exp(z). Per
step, log(R / exp(z)) = (amplitude error) + i (phase error): its real part is the numerical
damping (or growth) per step, its imaginary part the phase lag per step.

Accumulated error: the relative L2 error of the mode's impulse response over the run,

    e^2 = sum_{k<N} |R^k - exp(z)^k|^2 / sum_{k<N} |exp(z)|^(2k),   N = duration / h,

which is also the relative L2 error of the mode's response to a white input (Parseval). The
physical decay weights the sum, so a mode counts over its decay time or the run, whichever is
shorter. The sums are geometric and are evaluated in closed form (long double, so errors down
to about 1e-9 are resolved).

The splitting schemes of `springc.kernels.expint` propagate their blocks' modes exactly (error 0, up
to the splitting error of the nonlinear coupling, which no linear estimate sees); their other
modes have the error of the inner tableau. A "kicked" block, on whose nodes the rest puts a
stiffness at rest (a Q element's g a), is not integrated exactly: its modes are given the
inner tableau's error (an over-estimate), and its step limit is the scheme's own
(`checks.split_step_limit`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from springc.kernels import expint
from springc.check import linear
from springc.check.checks import block_kicks, split_step_limit
from springc.errors import UsageError
from springc.kernels.integrators import TABLEAUX, get_tableau, max_stable_step, stability_polynomial
from springc.lang.ir import FlatNetlist

DEFAULT_TOLERANCE = 1e-3  # relative L2 error per mode (and per probe on nonlinear terms)
SUBSTEPS = (1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64)  # candidates of the choice
# strang-rk4 is left out: the linear estimate cannot see its splitting error (it freezes the
# blocks over the Runge-Kutta step), which exp-rk4 avoids at about the same cost.
CANDIDATES = ("rk4", "rk38", "ssprk3", "heun3", "exp-rk4", "exp-heun3")
LAWSON_BLOCK_COST = 0.65  # measured: exp-rk4 / rk4 wall time = 1 + 0.65 * (block dof share)


def nonlinear(net: FlatNetlist) -> bool:
    """Whether the netlist has forces the linearisation leaves out (Duffing, quadratic and
    monomial terms): errors these estimates do not see, which `springc sim` checks by step
    doubling (`springc.sim.stepcheck`)."""
    return bool(len(net.duffings) or len(net.quads) or len(net.monomials))


def log_ratio(method: str, z: np.ndarray) -> np.ndarray:
    """log(R(z) / exp(z)) on the branch closest to 0: real part = log amplitude error per
    step, imaginary part = phase error per step (rad). -inf real part where R(z) = 0."""
    z = np.asarray(z, dtype=complex)
    r = np.polynomial.polynomial.polyval(z, stability_polynomial(get_tableau(method)))
    with np.errstate(divide="ignore"):
        lr = np.log(r) - z
    return lr.real + 1j * (np.angle(np.exp(1j * lr.imag)))


def impulse_error(method: str, lam: np.ndarray, h: float, duration: float) -> np.ndarray:
    """Relative L2 error of each mode's impulse response over `duration` (module docstring);
    inf for a mode the step makes grow."""
    lam = np.atleast_1d(np.asarray(lam, dtype=complex))
    z = lam * h
    n = max(1, round(duration / h))
    return _accumulated(z, log_ratio(method, z), n)


def _accumulated(z: np.ndarray, lr: np.ndarray, n: int) -> np.ndarray:
    """The module docstring's e for every mode, in long double."""
    lz = z.astype(np.clongdouble)
    lrho = lr.astype(np.clongdouble)
    a = 2 * lz.real  # log |exp(z)|^2
    s_exact = _geometric(a, n)
    s_num = _geometric(a + 2 * lrho.real, n)
    s_cross = _geometric(a + lrho, n)
    num = s_num + s_exact - 2 * s_cross.real
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):  # beyond a double: inf
        out = np.sqrt(np.maximum(num.real, 0.0) / s_exact.real).astype(float)
    out[~np.isfinite(num) | ~np.isfinite(s_exact)] = np.inf
    out[~np.isfinite(lr.real)] = 1.0  # R = 0: the numerical mode vanishes after one step
    out[(z == 0) | (lr == 0)] = 0.0
    return out


def _geometric(log_q: np.ndarray, n: int) -> np.ndarray:
    """sum_{k<n} q^k for q = exp(log_q), accurate near q = 1."""
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        out = np.expm1(n * log_q) / np.expm1(log_q)
    return np.where(log_q == 0, n, out)


@dataclass
class ModeError:
    """One mode's error estimate at step `h` (per step and accumulated over the run)."""

    freq_hz: float
    damping_rate: float
    q: float
    amplitude: float  # log(|R| / |exp(z)|) per step (negative: numerical damping)
    phase: float  # arg R - Im z per step, rad (negative: lag)
    h: float
    error: float  # accumulated relative L2 error (module docstring)
    exact: bool  # integrated exactly (a block of a splitting scheme)
    nodes: list[tuple[str, float]]
    oscillating: bool = True  # False: overdamped, a decay at `damping_rate` and no frequency

    @property
    def numerical_damping(self) -> float:
        """Numerical damping rate in 1/s (the step's amplitude error as a decay rate)."""
        return -self.amplitude / self.h

    def to_json(self) -> dict:
        return {"freq_hz": self.freq_hz if self.oscillating else None,
                "oscillating": self.oscillating, "damping_rate": self.damping_rate, "q": self.q,
                "amplitude_per_step": self.amplitude, "phase_per_step": self.phase,
                "numerical_damping": self.numerical_damping,
                "error": self.error if math.isfinite(self.error) else None,
                "exact": self.exact, "nodes": [n for n, _ in self.nodes]}

    def describe(self) -> str:
        what = "exact (split block)" if self.exact else (
            f"relative error {self.error:.3g}, numerical damping {self.numerical_damping:.3g}/s "
            f"(physical {self.damping_rate:.3g}/s), phase {self.phase:+.3g} rad/step")
        nodes = ", ".join(n for n, _ in self.nodes)
        if not self.oscillating:
            return f"decay {self.damping_rate:9.5g} 1/s (overdamped) {what}; nodes {nodes}"
        return f"{self.freq_hz:9.5g} Hz (Q {self.q:.3g}) {what}; nodes {nodes}"


def mode_errors(net: FlatNetlist, h: float, method: str, duration: float,
                found: linear.Modes | None = None, count: int | None = None) -> list[ModeError]:
    """Error estimates of the modes of the linearisation (see `linear.modes`) for `method` at
    step `h` over `duration`, worst first: every mode's error is computed (vectorised), but
    only the worst `count` (all if None) are described."""
    found = found if found is not None else linear.modes(net)
    exact = _exact_modes(net, found, method)
    inner = _inner(method)
    err = np.where(exact, 0.0, impulse_error(inner, found.eigenvalues, h, duration))
    # worst first, an infinite error first of all; ties in mode order (a stable sort)
    order = np.argsort(np.where(np.isfinite(err), -err, -np.inf), kind="stable")[:count]
    return [_mode_error(found, int(k), inner, h, float(err[k]), bool(exact[k])) for k in order]


def _inner(method: str) -> str:
    """The tableau a method applies to the modes it does not integrate exactly."""
    return expint.SCHEMES[method].inner if expint.is_split(method) else method


def _mode_error(found: linear.Modes, k: int, inner: str, h: float, error: float,
                exact: bool) -> ModeError:
    mode = found.mode(k)
    lr = log_ratio(inner, [mode.lam * h])[0]
    return ModeError(mode.freq_hz, mode.damping_rate, mode.q, float(lr.real), float(lr.imag),
                     h, error, exact, mode.dominant(2), mode.oscillating)


def _exact_modes(net: FlatNetlist, found: linear.Modes, method: str) -> np.ndarray:
    """Which modes a splitting scheme integrates exactly: most of the shape on the nodes of
    blocks that are not kicked (see the module docstring)."""
    out = np.zeros(len(found), bool)
    if not expint.is_split(method):
        return out
    blocks = expint.find_blocks(net)
    inside = np.zeros(net.n, bool)
    for nodes, kick in zip(blocks.nodes, block_kicks(net, blocks)):
        inside[nodes] = kick is None
    for k, (nodes, amps) in enumerate(found.shapes):
        w = np.abs(amps) ** 2
        out[k] = w.sum() > 0 and w[inside[nodes]].sum() > 0.5 * w.sum()
    return out


@dataclass
class Choice:
    """The cheapest (method, substeps) meeting a tolerance, and why."""

    method: str
    substeps: int
    h: float
    error: float  # worst estimated error over the modes in the band
    cost: float  # stage evaluations per input sample (relative work)
    worst: ModeError | None
    band_hz: float
    modes_complete: bool
    # set by `springc.sim.stepcheck.verify` on a nonlinear netlist: the step-doubling error over
    # the first run's first `pilot_s` seconds, and the substeps the linear estimate chose
    pilot_error: float | None = None
    pilot_s: float = 0.0
    linear_substeps: int = 0

    def modes_judged(self) -> str:
        """Which modes the error is estimated over, in words."""
        if math.isinf(self.band_hz):
            return "every linear mode (the initial state excites them all)"
        return f"the linear modes up to {self.band_hz:.5g} Hz"

    def describe(self) -> str:
        worst = f"; worst mode {self.worst.describe()}" if self.worst else ""
        linear = (f" (at {self.linear_substeps} substep(s))"
                  if self.linear_substeps and self.linear_substeps != self.substeps else "")
        pilot = ("" if self.pilot_error is None else
                 f"; on the nonlinear terms, step doubling over the first {self.pilot_s:g} s "
                 f"of the first run: estimated error {self.pilot_error:.3g}")
        return (f"chose {self.method} with {self.substeps} substep(s) (h = {self.h:.4g} s): "
                f"estimated error {self.error:.3g} for {self.modes_judged()}{linear}{pilot}, cost "
                f"{self.cost:.3g} stages per sample{worst}")


def cost(net: FlatNetlist, method: str, substeps: int) -> float:
    """Relative work per input sample: force evaluations per step times substeps, plus the
    exact block updates of a splitting scheme (Strang: two small matrix-vector products per
    step; Lawson: measured), weighted by the share of block dofs."""
    if expint.is_split(method):
        scheme = expint.SCHEMES[method]
        share = len(expint.find_blocks(net).node_set()) / max(net.n, 1)
        stages = scheme.tableau.stages
        if scheme.kind == "lawson":
            return substeps * stages * (1 + LAWSON_BLOCK_COST * share)
        return substeps * (stages + 2 * share)
    return substeps * get_tableau(method).stages


def choose(net: FlatNetlist, tstep: float, duration: float, tol: float,
           methods: tuple[str, ...] = CANDIDATES,
           substeps: tuple[int, ...] = SUBSTEPS, found: linear.Modes | None = None) -> Choice:
    """The cheapest stable (method, substeps) whose estimated error is at most `tol` for every
    mode within the input band (up to the Nyquist frequency of the input grid 1/tstep), or
    for every mode where the netlist starts away from rest (an initial displacement or
    velocity excites modes of any frequency, which the record's grid then aliases).
    `found`: the modes of the linearisation where the checks computed them already."""
    if not tol > 0:
        raise UsageError(f"tolerance must be positive, got {tol}")
    found = found if found is not None else linear.modes(net)
    band = math.inf if starts_moving(net) else 0.5 / tstep
    best: Choice | None = None
    for method in methods:
        if method not in TABLEAUX and not expint.is_split(method):
            raise UsageError(f"unknown integrator {method!r}")
        got = _cheapest_substeps(net, found, method, tstep, duration, band, tol, substeps)
        if got is not None and (best is None or got.cost < best.cost):
            best = got
    if best is None:
        raise UsageError(f"no integrator meets tolerance {tol:g} with up to {max(substeps)} "
                         "substeps", hint="raise the tolerance or lower .tran tstep")
    return best


def starts_moving(net: FlatNetlist) -> bool:
    """Whether any mass starts away from rest (x0 or v0 not zero)."""
    return bool(np.any(net.masses.x0 != 0) or np.any(net.masses.v0 != 0))


def _cheapest_substeps(net, found, method, tstep, duration, band, tol,
                       substeps) -> Choice | None:
    """The fewest substeps for which `method` is stable for every mode it does not integrate
    exactly and meets `tol` on those within the band (None if none does)."""
    exact = _exact_modes(net, found, method)
    inner = _inner(method)
    lam = found.eigenvalues
    hmax = _stable_step(inner, lam[~exact])
    if expint.is_split(method):  # kicked blocks have a limit of their own
        hmax = min(hmax, split_step_limit(net, method, found).dt)
    chosen = np.flatnonzero((found.freqs_hz <= band * (1 + 1e-9)) & ~exact)
    for sub in substeps:
        h = tstep / sub
        if h > hmax * (1 + 1e-9):
            continue
        errs = impulse_error(inner, lam[chosen], h, duration)
        if len(errs) and not errs.max() <= tol:
            continue
        worst = None
        if len(errs):
            k = int(chosen[int(np.argmax(errs))])
            worst = _mode_error(found, k, inner, h, float(errs.max()), False)
        return Choice(method, sub, h, worst.error if worst else 0.0, cost(net, method, sub),
                      worst, band, found.complete)
    return None


def _stable_step(method: str, lam: np.ndarray) -> float:
    """Largest stable step for these eigenvalues (only the fastest can limit it)."""
    if not len(lam):
        return math.inf
    # along the rays of the left half-plane the stability boundaries of these tableaux lie
    # within a factor 3 of each other: a mode 10x slower than the fastest cannot set the step
    mag = np.abs(lam)
    fast = np.unique(np.round(lam[mag >= 0.1 * mag.max()], 6))
    return max_stable_step(get_tableau(method), fast)[0]
