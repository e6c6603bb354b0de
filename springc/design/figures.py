"""The building-block experiments of the paper's Sec. III and their figures (`springc figures`).

Each `experiment_*` function builds its network from the standard library (`netlists/lib`),
runs it through the compiler's own analyses or simulator, and returns the measured numbers with
the paper's prediction beside them; each `plot_*` function draws one PNG comparable with a
figure of the paper. The tests (`tests/test_lib_*.py`) assert on the same experiments, so a
figure always shows what the tests check.

The simulated experiments share one kernel where they can (same element kinds and the same
recorded quantities), because compiling a kernel costs far more than running it.
"""

from __future__ import annotations

import math
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.linalg import subspace_angles

from springc.lang import physics
from springc.design import blocks
from springc.design.emit import num
from springc.design.filters import mel_triangles
from springc.design.melbank import Melbank, design_melbank, fitting_grid
from springc.design.mvm import MvmDesign, design_mvm, write_mvm
from springc.design import squaring
from springc.lang.ir import FlatNetlist
from springc.check import check
from springc.lang import load_text
from springc.sim.simulate import simulate

# Delay line of the paper's Fig. 3d: m = 1e-3, kc = 10, kl = 1e-5, so td = 10 ms per site.
TD, KC = 0.01, 10.0
# The kernel options every simulated experiment asks for, so that equal element kinds share it.
REDUCTIONS = ("work:in", "dissipated:all")


# ---------------------------------------------------------------- delay line: pulse propagation
PULSE_NET = """\
.title delay line pulse propagation (paper Sec. III.A, Fig. 3d)
.include "delayline.spr"
Xd a b delayline n={n} td={td} kc={kc} term=1 term_in=1
Fin a in(0)
"""


@dataclass(frozen=True)
class Pulse:
    """Velocity of a Gaussian force pulse at several sites (1-based), its arrival times
    (energy centroids) and the fitted delay per site against the design value td."""

    t: np.ndarray
    sites: tuple[int, ...]
    v: np.ndarray  # (sites, T)
    arrival: np.ndarray
    delay_per_site: float
    td: float


def experiment_pulse(n: int = 60, td: float = TD, kc: float = KC,
                     sites: tuple[int, ...] = (10, 20, 30, 40, 50)) -> Pulse:
    """A Gaussian force pulse (sigma = 5 td, well inside the flat part of the dispersion)
    enters a delay line terminated at both ends; the arrival time at each probed site is the
    centroid of v^2, and the delay per site the slope of arrival against site index."""
    net = load_text(PULSE_NET.format(n=n, td=td, kc=kc))
    sigma, tstep = 5 * td, td / 10
    t0 = 4 * sigma
    tstop = t0 + n * td + 8 * sigma
    force = _gauss(np.arange(round(tstop / tstep) + 1) * tstep, t0, sigma)
    labels = [f"v({_site(i, n)})" for i in sites]
    res = simulate(check(net), force[None, None, :], 1 / tstep, tstep=tstep, tstop=tstop,
                   probes=labels, reductions=REDUCTIONS)
    v = np.stack([res.probes[label][0] for label in labels])
    arrival = (v**2 @ res.t) / (v**2).sum(axis=1)
    slope = np.polyfit(np.asarray(sites, float), arrival, 1)[0]
    return Pulse(res.t, tuple(sites), v, arrival, float(slope), td)


def _site(i: int, n: int) -> str:
    """Top-level name of site i (1-based) of the delay line `Xd a b` in PULSE_NET."""
    return "a" if i == 1 else "b" if i == n else f"Xd.s{i}"


def _gauss(t: np.ndarray, t0: float, sigma: float) -> np.ndarray:
    return np.exp(-((t - t0) ** 2) / (2 * sigma**2))


# ---------------------------------------------------------------- delay line: dispersion
DISPERSION_NET = """\
.title free delay line for its modes (paper Eq. dispersion_rel, Fig. 3d)
.include "delayline.spr"
Xd a b delayline n={n} td={td} kc={kc}
"""


@dataclass(frozen=True)
class Dispersion:
    """Mode frequencies of a free chain of n sites (from the linear analysis) at their wave
    numbers q_j = pi j / n, and the analytic dispersion omega(q) and group velocity."""

    q_modes: np.ndarray
    omega_modes: np.ndarray
    omega_theory: np.ndarray  # Eq. dispersion_rel at q_modes
    m: float
    kc: float
    kl: float

    def omega(self, q: np.ndarray) -> np.ndarray:
        """Eq. (dispersion_rel): sqrt(kl/m + 4 kc/m sin^2(q/2)), rad/s."""
        return np.sqrt(self.kl / self.m + 4 * self.kc / self.m * np.sin(q / 2) ** 2)

    def group_velocity(self, q: np.ndarray) -> np.ndarray:
        """d omega / dq = (kc/m) sin(q) / omega(q), sites per second."""
        return self.kc / self.m * np.sin(q) / self.omega(q)


def experiment_dispersion(n: int = 40, td: float = TD, kc: float = KC) -> Dispersion:
    """The modes of a free chain are standing waves cos(q (i - 1/2)) with q = pi j / n, j = 0
    .. n-1 (free ends: zero slope), so its eigenfrequencies sample Eq. (dispersion_rel)."""
    from springc.check.linear import modes

    net = load_text(DISPERSION_NET.format(n=n, td=td, kc=kc))
    p = blocks.delayline_params(td, kc)
    omega = np.sort(2 * np.pi * np.asarray(modes(net).freqs_hz, dtype=float))
    q = np.pi * np.arange(n) / n
    theory = np.sqrt(p.kl / p.m + 4 * kc / p.m * np.sin(q / 2) ** 2)
    return Dispersion(q, omega, theory, p.m, kc, p.kl)


# ---------------------------------------------------------------- matrix-vector multiplier
MVM_NET = """\
.title matrix-vector multiplier driven at its inputs (paper Sec. III.A)
.include "{path}"
Xm {ports} mvm
{forces}
"""


@dataclass(frozen=True)
class MvmCheck:
    """The designed multiplier as compiled: principal angles (rad) between its zero modes and
    [I; Q], and the driven response x_out against Q x_in at frequencies `f_hz` (relative
    error per frequency) for input forces `u`."""

    design: MvmDesign
    angles: np.ndarray
    zero_eigenvalues: np.ndarray
    f_hz: np.ndarray
    rel_error: np.ndarray
    x_in: np.ndarray  # (len(f_hz), N) complex
    x_out: np.ndarray


def mvm_netlist(design: MvmDesign, folder: Path, u: np.ndarray) -> FlatNetlist:
    """Write the design to `folder/mvm.spr` and load a netlist that drives input i with force
    u_i in(0)."""
    path = write_mvm(design, folder / "mvm.spr")
    forces = "\n".join(f"F{i} in{i} in(0) gain={num(ui)}" for i, ui in enumerate(u))
    text = MVM_NET.format(path=path, ports=" ".join(design.nodes), forces=forces)
    return load_text(text, str(folder / "top.spr"))


def experiment_mvm(n: int = 24, seed: int = 0, f_hz: np.ndarray | None = None) -> MvmCheck:
    """A random orthogonal Q (QR of a Gaussian matrix), the multiplier for a delay line with
    m = 1e-3, kc = 10, driven by random input forces; the response solves
    (K - w^2 M + i w B) x = F for the compiled netlist."""
    rng = np.random.default_rng(seed)
    q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    design = design_mvm(q, m=TD**2 * KC, kc=KC)
    u = rng.standard_normal(n)
    f = np.geomspace(0.1, 3 * design.stiff_mode_hz(), 60) if f_hz is None else f_hz
    with tempfile.TemporaryDirectory() as tmp:
        net = mvm_netlist(design, Path(tmp), u)
    idx_in = [net.node_index(f"in{i}") for i in range(n)]
    idx_out = [net.node_index(f"out{i}") for i in range(n)]
    zero, zero_ev = _zero_modes(net, n)
    target = np.zeros((net.n, n))
    target[idx_in] = np.eye(n)
    target[idx_out] = q
    x = _driven(net, f)
    x_in, x_out = x[:, idx_in], x[:, idx_out]
    err = np.linalg.norm(x_out - x_in @ q.T, axis=1) / np.linalg.norm(x_in, axis=1)
    return MvmCheck(design, subspace_angles(zero, target), zero_ev, f, err, x_in, x_out)


def _zero_modes(net: FlatNetlist, count: int) -> tuple[np.ndarray, np.ndarray]:
    """The `count` lowest undamped modes (shapes, eigenvalues of M^-1 K) of the compiler's
    linearisation; the linear analysis must report exactly `count` zero modes."""
    from springc.check.linear import linearise, modes

    found = modes(net).zero_count
    if found != count:
        raise AssertionError(f"linear analysis reports {found} zero modes, expected {count}")
    lin = linearise(net)
    sq = np.sqrt(lin.M.diagonal())
    omega2, vecs = np.linalg.eigh(lin.K.toarray() / np.outer(sq, sq))
    return vecs[:, :count] / sq[:, None], omega2[:count]


def _driven(net: FlatNetlist, f_hz: np.ndarray) -> np.ndarray:
    """Steady-state complex displacement (len(f), n) for the netlist's in(0) forces."""
    k, b, m = physics.stiffness_matrix(net), physics.damping_matrix(net), np.diag(net.mass())
    force = np.zeros(net.n)
    np.add.at(force, net.forces.node, net.forces.gain)
    return np.stack([np.linalg.solve(k - w**2 * m + 1j * w * b, force)
                     for w in 2 * np.pi * np.asarray(f_hz)])


# ---------------------------------------------------------------- quadratic coupling energetics
ENERGETICS_NET = """\
.title energetics of the quadratic coupling (paper Fig. 5)
.include "delayline.spr"
* reference: the last coupling of a matched line is linear
Xl l1 ll delayline n={n1} td={td} kc={kc} term_in=1
Cl ll ln k={kc}
Mln ln m={m} b={z}
Kln ln k={kl}
Fl l1 in(0)
* the same line whose last coupling is quadratic: V = g/(2a) (x_ll^2 - a x_n)^2
Xq q1 ql delayline n={n1} td={td} kc={kc} term_in=1
Qq ql qn g={g} a={a}
Mqn qn m={m} b={z}
Kqn qn k={kl}
Fq q1 in(0)
"""


@dataclass(frozen=True)
class Energetics:
    """Input work and energy dissipated at the far terminal site, per pulse amplitude, for
    the linear and the quadratic last coupling, and the log-log slopes of E_out(E_in) of the
    quadratic one over its lowest and highest `fit_points` amplitudes."""

    amplitude: np.ndarray
    e_in_lin: np.ndarray
    e_out_lin: np.ndarray
    e_in_quad: np.ndarray
    e_out_quad: np.ndarray
    slope_low: float
    slope_high: float


def experiment_energetics(amplitudes: np.ndarray | None = None, n: int = 40, g: float = KC,
                          a: float = 1.0, fit_points: int = 3) -> Energetics:
    """Gaussian displacement pulses of the given amplitudes (sigma = 5 td) launched from the
    matched left end: the force is 2 Z times the pulse's velocity (half of the work goes into
    the left damper, half into the line). E_in is the work of that force, E_out the energy
    dissipated by the matched damping of the last site (paper Sec. III.B)."""
    amps = np.geomspace(1e-3, 1e3, 13) if amplitudes is None else np.asarray(amplitudes)
    p = blocks.delayline_params(TD, KC)
    net = load_text(ENERGETICS_NET.format(n1=n - 1, td=TD, kc=KC, m=p.m, z=p.b_match,
                                          kl=p.kl, g=g, a=a))
    sigma, tstep = 5 * TD, TD / 10
    tstop = 8 * sigma + 2 * n * TD
    t = np.arange(round(tstop / tstep) + 1) * tstep
    dgauss = -(t - 4 * sigma) / sigma**2 * _gauss(t, 4 * sigma, sigma)
    inputs = (amps[:, None] * 2 * p.b_match * dgauss[None, :])[:, None, :]
    specs = ("work:Fl", "work:Fq", "dissipated:Mln", "dissipated:Mqn")
    # the quartic stiffness of the quadratic coupling grows with amplitude: substeps keep the
    # largest pulses inside the integrator's stability region
    res = simulate(check(net), inputs, 1 / tstep, tstep=tstep, tstop=tstop, substeps=4,
                   probes=["x(l1)"], reductions=REDUCTIONS + specs)
    r = res.reductions
    e_in, e_out = r["work:Fq"], r["dissipated:Mqn"]
    lo, hi = slice(0, fit_points), slice(len(amps) - fit_points, None)

    def slope(s):
        return float(np.polyfit(np.log(e_in[s]), np.log(e_out[s]), 1)[0])

    return Energetics(amps, r["work:Fl"], r["dissipated:Mln"], e_in, e_out, slope(lo),
                      slope(hi))


# ---------------------------------------------------------------- readout: leaky integrator
READOUT_NET = """\
.title delay line, quadratic coupling and leaky-integrator readout (paper Fig. 6a)
.include "delayline.spr"
.include "readout.spr"
Xd x1 xl delayline n={n} td={td} kc={kc} term=1 term_in=1
Qr xl xr g={g} a={a}
Xr xr readout tau={tau} qr={qr} m=1 kext={kext}
Fin x1 in(0)
"""


@dataclass(frozen=True)
class ReadoutDecay:
    """Trajectories of the delay line's last site x_l and the readout x_r, the measured time
    constant of x_r's decay after the pulse and the design value."""

    t: np.ndarray
    x_l: np.ndarray
    x_r: np.ndarray
    fit_window: tuple[float, float]
    tau_measured: float
    tau_design: float


def experiment_readout(tau: float = 80.0, qr: float = blocks.READOUT_Q, n: int = 20,
                       amplitude: float = 0.1, g: float = 1e-2) -> ReadoutDecay:
    """A Gaussian displacement pulse of `amplitude` travels down a matched delay line whose
    last site drives the readout through a quadratic coupling (g, with a chosen so that g a is
    half the readout's stiffness; the readout's own spring supplies the rest). After the pulse
    the readout relaxes freely: log x_r is fitted over 0.5 tau .. 3 tau after the pulse."""
    p = blocks.delayline_params(TD, KC)
    ro = blocks.readout_params(tau, qr, 1.0)
    a = 0.5 * ro.k_total / g
    net = load_text(READOUT_NET.format(n=n, td=TD, kc=KC, g=g, a=a, tau=tau, qr=qr,
                                       kext=g * a))
    sigma, tstep = 5 * TD, TD / 10
    t_pulse = 8 * sigma + n * TD
    tstop = t_pulse + 3.5 * tau
    t = np.arange(round(t_pulse / tstep) + 1) * tstep
    dgauss = -(t - 4 * sigma) / sigma**2 * _gauss(t, 4 * sigma, sigma)
    inputs = (amplitude * 2 * p.b_match * dgauss)[None, None, :]
    res = simulate(check(net), inputs, 1 / tstep, tstep=tstep, tstop=tstop, outrate=100.0,
                   probes=["x(xl)", "x(xr)"], reductions=REDUCTIONS)
    x_r = res.probes["x(xr)"][0]
    window = (t_pulse + 0.5 * tau, t_pulse + 3 * tau)
    sel = (res.t >= window[0]) & (res.t <= window[1])
    rate = -np.polyfit(res.t[sel], np.log(x_r[sel]), 1)[0]
    return ReadoutDecay(res.t, res.probes["x(xl)"][0], x_r, window, float(1 / rate), tau)


# ---------------------------------------------------------------- feature-extraction chain
FEATURE_NET = """\
.title one channel of the mass-spring feature extraction (paper Fig. 7a)
.include "featurechain.spr"
Xc lp featurechain fa={fa} delta={delta} alpha={alpha} ch=0 gain={gain} g={g} a={a}
+ fc={fc} klp={klp} nd={nd} sites={sites} td={td} kc={kc}
"""


@dataclass(frozen=True)
class Features:
    """A tone burst at a filter's centre through the feature chain: the filter output x_f,
    the feature (low-pass mass) and its delayed copies at the far ends of the nd delay lines,
    with their arrival times (centroids of x^2) and the design delay td."""

    t: np.ndarray
    x_f: np.ndarray
    lp: np.ndarray
    delayed: np.ndarray  # (nd, T)
    arrival_lp: float
    arrival: np.ndarray  # (nd,)
    td: float


def experiment_features(bin_index: int = 3, nd: int = 2, td: float = 0.032,
                        sites: int = 4, sigma: float = 0.05) -> Features:
    """The `bin_index` filter of the 8-bin bank, squarer (g = 1, a = 1e-4), 50 Hz low-pass
    (k = 100) and `nd` delay lines of `sites` sites per `td`; input a tone at the Mel centre
    with a Gaussian envelope of width `sigma` (long enough that the feature's spectrum stays in
    the flat part of the lines' dispersion)."""
    flt = design_melbank(8).two_mode[bin_index]
    net = load_text(FEATURE_NET.format(fa=num(flt.fa), delta=num(flt.delta),
                                       alpha=num(flt.alpha), gain=num(flt.gain), g=1, a=1e-4,
                                       fc=50, klp=100, nd=nd, sites=sites, td=td, kc=KC))
    tstep, t0 = 1 / 32000, 4 * sigma
    tstop = t0 + 4 * sigma + nd * td
    t = np.arange(round(tstop / tstep) + 1) * tstep
    tone = _gauss(t, t0, sigma) * np.sin(2 * np.pi * flt.centre * t)
    labels = ["x(Xc.f)", "x(lp)"] + [f"x(Xc.d{j})" for j in range(1, nd + 1)]
    res = simulate(check(net), tone[None, None, :], 1 / tstep, tstep=tstep, tstop=tstop,
                   outrate=16000.0, probes=labels, reductions=REDUCTIONS)
    x = np.stack([res.probes[label][0] for label in labels])
    arrival = (x**2 @ res.t) / (x**2).sum(axis=1)
    return Features(res.t, x[0], x[1], x[2:], float(arrival[1]), arrival[2:], td)


# ---------------------------------------------------------------- plots
def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: str | Path) -> Path:
    """Save through a temporary file and a rename (no half-written PNG)."""
    import os

    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp.png")
    fig.savefig(tmp, dpi=120, bbox_inches="tight")
    _pyplot().close(fig)
    os.replace(tmp, path)
    return path


def plot_melbank(bank: Melbank, path: str | Path) -> Path:
    """Paper Fig. 4: (a) two-mode filters and Mel triangles, (b) one filter and its two modes,
    (c) a two-mode against a single-mode filter."""
    plt = _pyplot()
    f = fitting_grid(bank.fmax)
    tri = mel_triangles(f, bank.bins, bank.fmin, bank.fmax)
    fig, ax = plt.subplots(1, 3, figsize=(15, 4))
    for i, flt in enumerate(bank.two_mode):
        ax[0].plot(f, np.abs(flt.response(f)), color=f"C{i % 10}")
        ax[0].plot(f, tri[i], ":", color=f"C{i % 10}")
    ax[0].set(title=f"(a) {bank.bins} two-mode filters (full), Mel triangles (dotted)",
              xlabel="f (Hz)", ylabel="|H|")
    _plot_modes(ax[1], bank, f, min(3, bank.bins - 1))
    k = min(6, bank.bins - 1)
    two, one = bank.two_mode[k], bank.single_mode[k]
    ax[2].plot(f, np.abs(two.response(f)), color="gray", label=f"two-mode, misfit {two.misfit:.3f}")
    ax[2].plot(f, np.abs(one.response(f)), color="purple",
               label=f"single-mode, misfit {one.misfit:.3f}")
    ax[2].plot(f, tri[k], "k:", label="Mel triangle")
    ax[2].set(title=f"(c) filter {k + 1}: two-mode vs Lorentzian", xlabel="f (Hz)")
    ax[2].legend(fontsize=8)
    return _save(fig, path)


def _plot_modes(ax, bank: Melbank, f: np.ndarray, k: int) -> None:
    flt = bank.two_mode[k]
    w, wa, wb = 2 * np.pi * f, 2 * np.pi * flt.fa, 2 * np.pi * flt.fb

    def mode(w0):
        return flt.gain * flt.alpha * w0**2 / (w0**2 - w**2 + 1j * flt.alpha * w)

    ax.plot(f, np.abs(flt.response(f)), color="gray", label="filter (difference)")
    ax.plot(f, np.abs(mode(wa)), color="blue", label=f"mode a, {flt.fa:.0f} Hz")
    ax.plot(f, np.abs(mode(wb)), color="red", label=f"mode b, {flt.fb:.0f} Hz")
    ax.set(title=f"(b) filter {k + 1} and its two modes", xlabel="f (Hz)",
           xlim=(0, 4 * flt.fb))
    ax.legend(fontsize=8)


def plot_dispersion(d: Dispersion, path: str | Path) -> Path:
    """Paper Fig. 3d: omega(q) and group velocity, with the chain's computed modes."""
    plt = _pyplot()
    q = np.linspace(0, np.pi, 400)
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(q, d.omega(q), color="blue", label=r"$\omega(k)$, Eq. dispersion_rel")
    ax.plot(d.q_modes, d.omega_modes, "o", ms=3, color="navy",
            label=f"modes of a free {len(d.q_modes)}-site line (springc modes)")
    ax.set(xlabel="wave number k (rad/site)", ylabel=r"$\omega$ (rad/s)")
    ax2 = ax.twinx()
    ax2.plot(q, d.group_velocity(q), color="red", label="group velocity")
    ax2.axhline(math.sqrt(d.kc / d.m), color="red", ls=":", lw=0.8)
    ax2.set_ylabel("group velocity (sites/s)", color="red")
    ax.set_title(f"delay line m={d.m:g}, kc={d.kc:g}, kl={d.kl:g}")
    ax.legend(loc="lower right", fontsize=8)
    return _save(fig, path)


def plot_pulse(p: Pulse, path: str | Path) -> Path:
    """A pulse travelling down the delay line: velocity at the probed sites."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7, 4))
    for k, site in enumerate(p.sites):
        ax.plot(p.t, p.v[k], label=f"site {site}")
        ax.axvline(p.arrival[k], color=f"C{k}", ls=":", lw=0.8)
    ax.set(xlabel="t (s)", ylabel="velocity (m/s)",
           title=f"delay per site {1e3 * p.delay_per_site:.3f} ms "
                 f"(sqrt(m/kc) = {1e3 * p.td:.3f} ms)")
    ax.legend(fontsize=8)
    return _save(fig, path)


def plot_mvm(c: MvmCheck, path: str | Path) -> Path:
    """The multiplier: x_out against Q x_in in the band, and the error against frequency."""
    plt = _pyplot()
    fig, ax = plt.subplots(1, 2, figsize=(11, 4))
    k = int(np.argmin(np.abs(c.f_hz - c.design.band_edge_hz() / 4)))
    want = (c.x_in[k] @ c.design.Q.T).real
    ax[0].plot(want, c.x_out[k].real, "o", ms=4)
    lim = np.abs(want).max() * 1.1
    ax[0].plot([-lim, lim], [-lim, lim], "k:", lw=0.8)
    ax[0].set(xlabel="Q x_in", ylabel="x_out",
              title=f"N={c.design.n}, f = {c.f_hz[k]:.3g} Hz; max principal angle "
                    f"{c.angles.max():.1e} rad")
    ax[1].loglog(c.f_hz, c.rel_error, label="|x_out - Q x_in| / |x_in|")
    ax[1].loglog(c.f_hz, (c.f_hz / c.design.stiff_mode_hz()) ** 2, "k:",
                 label="(f / f_stiff)^2")
    ax[1].axvline(c.design.band_edge_hz(), color="gray", ls="--", lw=0.8,
                  label="delay-line band edge")
    ax[1].axhline(0.01, color="red", ls=":", lw=0.8, label="1%")
    ax[1].set(xlabel="f (Hz)", title="deviation from x_out = Q x_in")
    ax[1].legend(fontsize=8)
    return _save(fig, path)


def plot_energetics(e: Energetics, path: str | Path) -> Path:
    """Paper Fig. 5b: E_out against E_in, linear and quadratic last coupling."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6, 5))
    ax.loglog(e.e_in_lin, e.e_out_lin, "o-", color="black", label="linear coupling")
    ax.loglog(e.e_in_quad, e.e_out_quad, "o-", color="purple",
              label=f"quadratic: slope {e.slope_low:.3f} (low), {e.slope_high:.3f} (high)")
    x = np.geomspace(e.e_in_quad.min(), e.e_in_quad.max(), 50)
    ax.loglog(x, e.e_out_quad[0] * (x / e.e_in_quad[0]) ** 2, "r:", label="slope 2")
    ax.loglog(x, e.e_out_quad[-1] * (x / e.e_in_quad[-1]) ** (2 / 3), "b:", label="slope 2/3")
    ax.fill_between(x, x / 2, x.max(), color="0.85", label="E_out > E_in / 2")
    ax.set(xlabel="E_in (J)", ylabel="E_out (J)", ylim=(e.e_out_quad.min() / 3, x.max()))
    ax.legend(fontsize=8)
    return _save(fig, path)


def plot_readout(r: ReadoutDecay, path: str | Path) -> Path:
    """Paper Fig. 6b: the delay line's last site and the leaky-integrating readout."""
    plt = _pyplot()
    fig, ax = plt.subplots(1, 2, figsize=(11, 4))
    early = r.t <= r.t[np.argmax(r.x_r)] * 4
    ax[0].plot(r.t[early], r.x_l[early] / np.abs(r.x_l).max(), color="blue", label="x_l")
    ax[0].plot(r.t[early], r.x_r[early] / r.x_r.max(), color="orange", label="x_r")
    ax[0].set(xlabel="t (s)", ylabel="peak-normalised displacement", title="pulse and readout")
    ax[0].legend()
    ax[1].semilogy(r.t, r.x_r, color="orange", label="x_r (simulated)")
    t0 = r.fit_window[0]
    x0 = np.interp(t0, r.t, r.x_r)
    ax[1].semilogy(r.t, x0 * np.exp(-(r.t - t0) / r.tau_design), "k:",
                   label=f"exp(-t/tau), tau = {r.tau_design:g} s (design)")
    ax[1].axvspan(*r.fit_window, color="0.9")
    ax[1].set(xlabel="t (s)", title=f"measured tau = {r.tau_measured:.3f} s",
              ylim=(x0 * 1e-3, r.x_r.max() * 2))
    ax[1].legend(fontsize=8)
    return _save(fig, path)


def plot_features(c: Features, path: str | Path) -> Path:
    """Paper Fig. 7: the filter output, the feature (squared, compressed, low-passed) and its
    delayed copies."""
    plt = _pyplot()
    fig, ax = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    ax[0].plot(c.t, c.x_f, color="gray", lw=0.5)
    ax[0].set(ylabel="filter output x_f (m)", title="tone burst at the filter's Mel centre")
    ax[1].plot(c.t, c.lp, color="purple", label=f"feature (low-pass mass), t = "
               f"{c.arrival_lp:.4f} s")
    for j, (x, when) in enumerate(zip(c.delayed, c.arrival), start=1):
        ax[1].plot(c.t, x, label=f"delay line {j}: t = {when:.4f} s "
                   f"(+{(when - c.arrival_lp) / c.td:.3f} td)")
    ax[1].set(xlabel="t (s)", ylabel="displacement (m)", title=f"td = {c.td * 1e3:g} ms")
    ax[1].legend(fontsize=8)
    return _save(fig, path)


def plot_squaring(sw: squaring.Sweep, path: str | Path) -> Path:
    """Paper Fig. 6c-d: energy transfer and distortion of the squaring unit against eps; the
    peak-normalised readouts at the eps of `squaring.SHOWN` against the ideal."""
    plt = _pyplot()
    fig, ax = plt.subplots(1, 2, figsize=(12, 4), gridspec_kw={"wspace": 0.45})
    ax[0].semilogx(sw.epsilon, np.log10(sw.transfer), "o-", color="C0")
    ax[0].set(xlabel="squaring error eps = A^2 gamma / (alpha kc)",
              ylabel="log10 energy transfer (E_out / E_in)", title="(c) energy and distortion")
    twin = ax[0].twinx()
    twin.semilogx(sw.epsilon, sw.distortion, "s-", color="C3")
    twin.set_ylabel("distortion (RMS, peak-normalised)", color="C3")
    ms = 1e3 * (sw.t - sw.unit.arrival)
    ax[1].plot(ms, sw.ideal, "k--", label="leaky-integrated square of the pulse")
    for eps, color in zip(squaring.SHOWN, ("brown", "gray", "hotpink")):
        k = int(np.argmin(np.abs(np.log(sw.epsilon / eps))))
        ax[1].plot(ms, sw.x_r[k] / sw.x_r[k].max(), color=color,
                   label=f"eps = {sw.epsilon[k]:.3g}: distortion {sw.distortion[k]:.3g}")
    ax[1].set(xlabel="t - pulse arrival (ms)", ylabel="peak-normalised x_r",
              title="(d) readout trajectories")
    ax[1].legend(fontsize=8)
    return _save(fig, path)


FIGURES = ("melbank", "dispersion", "pulse", "mvm", "energetics", "readout", "squaring",
           "features")


def write_figures(outdir: str | Path,
                  only: tuple[str, ...] = FIGURES) -> dict[str, dict[str, float]]:
    """Run the experiments named in `only`, write `<name>.png` into `outdir`, and return the
    measured numbers per figure."""
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    numbers: dict[str, dict[str, float]] = {}
    for name in only:
        numbers[name] = _RUNNERS[name](outdir / f"{name}.png")
    return numbers


def _run_melbank(path: Path) -> dict[str, float]:
    bank = design_melbank(8)
    plot_melbank(bank, path)
    return {"misfit_two_mode_mean": float(np.mean([f.misfit for f in bank.two_mode])),
            "misfit_single_mode_mean": float(np.mean([f.misfit for f in bank.single_mode]))}


def _run_dispersion(path: Path) -> dict[str, float]:
    d = experiment_dispersion()
    plot_dispersion(d, path)
    return {"max_rel_error_modes": float(np.max(np.abs(d.omega_modes / d.omega_theory - 1)))}


def _run_pulse(path: Path) -> dict[str, float]:
    p = experiment_pulse()
    plot_pulse(p, path)
    return {"delay_per_site_s": p.delay_per_site, "td_s": p.td}


def _run_mvm(path: Path) -> dict[str, float]:
    c = experiment_mvm()
    plot_mvm(c, path)
    band = c.f_hz <= c.design.band_edge_hz()
    return {"max_principal_angle": float(c.angles.max()),
            "max_rel_error_in_band": float(c.rel_error[band].max())}


def _run_energetics(path: Path) -> dict[str, float]:
    e = experiment_energetics()
    plot_energetics(e, path)
    return {"slope_low": e.slope_low, "slope_high": e.slope_high}


def _run_readout(path: Path) -> dict[str, float]:
    r = experiment_readout()
    plot_readout(r, path)
    return {"tau_measured_s": r.tau_measured, "tau_design_s": r.tau_design}


def _run_squaring(path: Path) -> dict[str, float]:
    sw = squaring.sweep()
    plot_squaring(sw, path)
    numbers = {}
    for eps in squaring.SHOWN:
        k = int(np.argmin(np.abs(np.log(sw.epsilon / eps))))
        numbers[f"log10_transfer_eps_{eps:.3g}"] = float(np.log10(sw.transfer[k]))
        numbers[f"distortion_eps_{eps:.3g}"] = float(sw.distortion[k])
    return numbers


def _run_features(path: Path) -> dict[str, float]:
    c = experiment_features()
    plot_features(c, path)
    lags = (c.arrival - c.arrival_lp) / c.td
    return {f"delay_line_{j}_lag_td": float(lag) for j, lag in enumerate(lags, start=1)}


_RUNNERS = {"melbank": _run_melbank, "dispersion": _run_dispersion, "pulse": _run_pulse,
            "mvm": _run_mvm, "energetics": _run_energetics, "readout": _run_readout,
            "squaring": _run_squaring, "features": _run_features}
