"""springc.export.spice + springc.export.ngspice: exported networks run in ngspice and agree
with the analytic solution or scipy's DOP853 on the reference physics; export errors are located.

Tolerances (relative L2 over the probe traces) come from ngspice's trapezoidal rule, whose
error shrinks as the square of its largest step `tmax`; the measured errors are in comments.
"""

from __future__ import annotations

import re
import resource
import shutil
import subprocess

import numpy as np
import pytest
import soundfile as sf
from click.testing import CliRunner
from scipy.integrate import solve_ivp

from springc.lang import physics
from springc.sim.audio import load_audio
from springc.errors import NetlistError, SimulationError, SourceLoc
from springc.export.spice import SpiceOptions, export_spice, probe_vectors
from springc.lang.ir import FlatNetlist, IRBuilder, Source, Tran
from springc.lang import load_text
from springc.export.ngspice import cross_check, plot_cross_check, run_ngspice, simulate_ngspice
from springc.sim.sources import analytic
from springc.check import check

needs_ngspice = pytest.mark.skipif(
    shutil.which("ngspice") is None,
    reason="ngspice is not installed (apt-get install ngspice; .ci/run installs it)",
)
LOC = SourceLoc("t.spr", 3, 1)


def rel_l2(got: np.ndarray, want: np.ndarray) -> float:
    return float(np.linalg.norm(got - want) / np.linalg.norm(want))


def dop853(net: FlatNetlist, tstop: float, forcing) -> object:
    """Dense DOP853 solution of the reference physics with `forcing(t) -> (n,)` forces."""
    n, mass = net.n, net.mass()

    def rhs(t, y):
        x, v = y[:n], y[n:]
        f = physics.internal_force(net, x) + physics.damping_force(net, v) + forcing(t)
        return np.concatenate([v, f / mass])

    x0, v0 = net.initial_state()
    y0 = np.concatenate([x0, v0])
    return solve_ivp(
        rhs,
        (0, tstop),
        y0,
        method="DOP853",
        rtol=1e-11,
        atol=1e-13,
        dense_output=True,
        max_step=1e-3,
    ).sol


def analytic_forcing(net: FlatNetlist):
    """Forces of the analytic sources (sin gauss step pwl) at time t, per node."""

    def forcing(t: float) -> np.ndarray:
        f = np.zeros(net.n)
        for node, gain, src in zip(net.forces.node, net.forces.gain, net.forces.source):
            f[node] += gain * analytic(src, np.asarray(t))
        return f

    return forcing


# ------------------------------------------------------------------ (1) damped oscillator


def oscillator() -> tuple[FlatNetlist, dict]:
    p = {
        "m": 2.0,
        "w0": 2 * np.pi * 200,
        "gamma": 30.0,
        "f0": 3.0,
        "fd": 150.0,
        "x0": 1e-3,
        "v0": 0.5,
    }
    b = IRBuilder("driven damped oscillator")
    b.mass("M1", "a", p["m"], 2 * p["m"] * p["gamma"], x0=p["x0"], v0=p["v0"])
    b.spring("K1", "a", p["m"] * p["w0"] ** 2)
    b.force("F1", "a", Source("sin", (p["f0"], p["fd"], 0.0)))
    b.probe("x", "a")
    b.probe("v", "a")
    b.tran = Tran(1e-5, 0.05, LOC)
    return b.finish(), p


def oscillator_exact(p: dict, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """x(t), v(t) of m x'' + 2 m gamma x' + m w0^2 x = f0 sin(wd t) from x0, v0."""
    m, w0, g, wd = p["m"], p["w0"], p["gamma"], 2 * np.pi * p["fd"]
    amp = p["f0"] / (m * (w0**2 - wd**2) + 2j * m * g * wd)  # x_p = Im(amp e^{i wd t})
    xp, vp = np.imag(amp * np.exp(1j * wd * t)), np.imag(1j * wd * amp * np.exp(1j * wd * t))
    w1 = np.sqrt(w0**2 - g**2)
    c1 = p["x0"] - np.imag(amp)
    c2 = (p["v0"] - np.imag(1j * wd * amp) + g * c1) / w1
    cos, sin, decay = np.cos(w1 * t), np.sin(w1 * t), np.exp(-g * t)
    x = xp + decay * (c1 * cos + c2 * sin)
    v = vp + decay * ((w1 * c2 - g * c1) * cos - (g * c2 + w1 * c1) * sin)
    return x, v


@needs_ngspice
def test_driven_damped_oscillator_matches_the_analytic_solution():
    net, p = oscillator()
    errors = []
    for tmax in (5e-6, 2.5e-6):
        t, got = simulate_ngspice(check(net), SpiceOptions(tmax=tmax))
        x, v = oscillator_exact(p, t)
        errors.append(rel_l2(got["x(a)"], x))
        assert rel_l2(got["v(a)"], v) < 1e-4  # measured 7.6e-5, 1.9e-5
    assert errors[1] < 3e-5  # measured 1.9e-5
    # Second order in the step, as the trapezoidal rule: the export itself adds no error.
    assert 3.5 < errors[0] / errors[1] < 4.5  # measured 3.99


# ------------------------------------------------------------------ (2) 200-site chain


def chain(n: int = 200, td: float = 1 / 4000, kc: float = 10.0) -> FlatNetlist:
    """A delay line (paper, Sec. delay lines): m = td^2 kc, kl = 1e-6 kc, impedance-matched
    dampers sqrt(m kc) at both ends, a Gaussian pulse into site 0."""
    m = td**2 * kc
    b = IRBuilder("200-site chain")
    for i in range(n):
        b.mass(f"M{i}", f"s{i}", m, np.sqrt(m * kc) if i in (0, n - 1) else 0.0)
        b.spring(f"K{i}", f"s{i}", 1e-6 * kc)
    for i in range(n - 1):
        b.coupling(f"C{i}", f"s{i}", f"s{i + 1}", kc)
    b.force("F0", "s0", Source("gauss", (1.0, 20 * td, 5 * td)))
    for i in (0, n // 2, n - 1):
        b.probe("x", f"s{i}")
    b.tran = Tran(1 / 32000, 0.06, LOC)
    return b.finish()


@needs_ngspice
def test_chain_driven_by_a_gaussian_pulse_matches_dop853(capsys):
    net = chain()
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t, got = simulate_ngspice(check(net))
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    seconds = after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime
    ref = dop853(net, net.tran.tstop, analytic_forcing(net))(t)
    for label, node in (("x(s0)", 0), ("x(s100)", 100), ("x(s199)", 199)):
        # measured 2.9e-7, 1.0e-5, 4.5e-5: phase error of the trapezoidal rule grows along
        # the line
        assert rel_l2(got[label], ref[node]) < 1e-4, label
    # the pulse did arrive at the far end (the comparison is not of two zeros)
    assert np.max(np.abs(ref[199])) > 0.1 * np.max(np.abs(ref[0]))
    with capsys.disabled():
        print(f"\nngspice, 200-site chain: {seconds / net.tran.tstop:.2f} CPU s per simulated s")


# ------------------------------------------------------------------ (3) nonlinear networks

W = 2 * np.pi * 100


def duffing(b: IRBuilder) -> None:
    b.mass("Ma", "a", 1.0, 20.0, x0=0.3)
    b.spring("Ka", "a", W**2)
    b.duffing("Da", "a", 5 * W**2)  # l x^2 = 0.45 w^2 at x0: strongly nonlinear
    b.force("Fa", "a", Source("sin", (30.0, 80.0, 0.5)), 1.5)


def quadratic(b: IRBuilder) -> None:
    b.mass("Ma", "a", 1.0, 20.0, x0=0.2)
    b.mass("Mb", "b", 2.0, 10.0, v0=-20.0)
    b.spring("Ka", "a", W**2)
    b.spring("Kb", "b", 2 * W**2)
    b.quad("Qab", "a", "b", W**2, a=0.5)
    b.force("Fa", "a", Source("step", (50.0, 0.01)))


def lever(b: IRBuilder) -> None:
    b.mass("Mb", "b", 2.0, 10.0, x0=0.01)
    b.mass("Mc", "c", 0.5, 5.0)
    b.spring("Kb", "b", 2 * W**2)
    b.spring("Kc", "c", W**2)
    b.coupling("Cbc", "b", "c", 0.3 * W**2, a=2.0)
    b.force("Fb", "b", Source("pwl", (0.0, 0.0, 0.02, 100.0, 0.03, -50.0)), 2.0)


def mixed(b: IRBuilder) -> None:
    """All element kinds at once, with dashpots between nodes and to ground."""
    duffing(b)
    quadratic_rest = [("Mb", "b", 2.0, 10.0), ("Mc", "c", 0.5, 5.0)]
    for name, node, m, damp in quadratic_rest:
        b.mass(name, node, m, damp, v0=-5.0)
    b.spring("Kb", "b", 2 * W**2)
    b.spring("Kc", "c", W**2)
    b.quad("Qab", "a", "b", W**2, a=0.5)
    b.coupling("Cbc", "b", "c", 0.3 * W**2, a=2.0)
    b.coupling("Cac", "a", "c", 0.1 * W**2)
    b.dashpot("Bbc", "b", "c", 3.0)
    b.dashpot("Ba0", "a", "0", 1.0)
    b.monomial("P1", 0.2 * W**2, [("c", 4)])
    b.monomial("P2", 0.05 * W**2, [("a", 2), ("c", 2)])


@needs_ngspice
@pytest.mark.parametrize("build", [duffing, quadratic, lever, mixed], ids=lambda f: f.__name__)
def test_nonlinear_networks_match_dop853(build):
    b = IRBuilder(build.__name__)
    build(b)
    for node in b._nodes:
        b.probe("x", node)
        b.probe("v", node)
    b.tran = Tran(1e-5, 0.06, LOC)
    net = b.finish()
    t, got = simulate_ngspice(check(net), SpiceOptions(tmax=2.5e-6))
    ref = dop853(net, net.tran.tstop, analytic_forcing(net))(t)
    for probe in net.probes:
        row = probe.node + (net.n if probe.quantity == "v" else 0)
        # measured at most 3.3e-5 over all four networks
        assert rel_l2(got[probe.label], ref[row]) < 1e-4, probe.label


# ------------------------------------------------------------------ sampled signals


@needs_ngspice
def test_sampled_signals_drive_a_free_mass_exactly(tmp_path):
    """A free mass integrates its force once: v = (1/m) int F dt, which the trapezoidal rule
    gets exactly between the PWL breakpoints, so in(k) and wav(...) must match the sampled
    signal's integral (resampled to 1/tstep, zero after its end) up to ngspice's first-order
    restart steps at the breakpoints."""
    tstep, m = 1 / 8000, 0.5
    rng = np.random.default_rng(1)
    signal_in = rng.normal(size=200)
    wav = tmp_path / "s.wav"
    sf.write(wav, 0.5 * rng.uniform(-1, 1, 100), 4000, subtype="FLOAT")
    b = IRBuilder("free masses")
    b.mass("Ma", "a", m)
    b.mass("Mb", "b", m)
    b.force("Fa", "a", Source("in", channel=1), 3.0)
    b.force("Fb", "b", Source("wav", path=str(wav)), -2.0)
    b.probe("v", "a")
    b.probe("v", "b")
    b.tran = Tran(tstep, 0.03, LOC)
    net = b.finish()
    t, got = simulate_ngspice(check(net), SpiceOptions(inputs={1: (signal_in, 1 / tstep)}))
    for label, samples, gain in (
        ("v(a)", signal_in, 3.0),
        ("v(b)", load_audio(wav, 1 / tstep, 0), -2.0),
    ):
        grid = np.arange(len(samples) + 1) * tstep
        force = gain * np.append(samples, 0.0)
        v_grid = np.concatenate([[0.0], np.cumsum((force[1:] + force[:-1]) / 2 * tstep)]) / m
        want = np.interp(t, grid, v_grid)  # v is piecewise quadratic: compare on the grid
        on_grid = np.isclose(t / tstep, np.round(t / tstep), atol=1e-6, rtol=0)
        assert on_grid.sum() > 100
        # measured 1.6e-6 (a constant offset from ngspice's first step); reltol 1e-6 instead of
        # the 1e-9 chosen for sampled signals gives 8e-4
        assert np.max(np.abs(got[label][on_grid] - want[on_grid])) < 1e-5 * np.max(np.abs(want))


# ------------------------------------------------------------------ export text and errors


def small() -> FlatNetlist:
    b = IRBuilder("small")
    b.mass("M1", "a", 2.0, 4.0, x0=0.5, v0=1.5, loc=LOC)
    b.mass("M2", "b", 1.0)
    b.spring("K1", "a", 8.0)
    b.coupling("C1", "a", "b", 2.0)
    b.duffing("D1", "b", 3.0)
    b.probe("v", "a")
    b.tran = Tran(1e-3, 0.1, LOC)
    return b.finish()


def test_export_maps_elements_through_the_force_current_analogy():
    text = export_spice(check(small()))
    lines = set(text.splitlines())
    assert "Cm0 v0 0 2.0" in lines  # mass -> capacitor
    assert "Rm0 v0 0 0.25" in lines  # damper b=4 -> 1/4 ohm
    assert "Lk0 v0 0 0.125 ic=4.0" in lines  # spring k=8 -> 1/8 H carrying k x0
    assert "Lc0 v0 v1 0.5 ic=1.0" in lines  # unit coupling -> inductor with k (x0a - x0b)
    assert "Bd0 0 v1 I=-(3.0)*V(x1)*V(x1)*V(x1)" in lines  # Duffing force -l x^3
    assert "Gx1 0 x1 v1 0 1" in lines and "Gx0 0 x0 v0 0 1" not in lines  # positions on need
    assert ".ic v(v0)=1.5 v(v1)=0.0 v(x1)=0.0" in lines
    assert ".tran 0.001 0.1 0 0.001 uic" in lines
    assert "wrdata springc_probes.txt v(v0)" in lines
    assert probe_vectors(small()) == {"v(a)": "v(v0)"}


def test_unbound_input_is_an_error_at_the_force():
    b = IRBuilder("needs input")
    b.mass("M1", "a", 1.0)
    b.force("F1", "a", Source("in", channel=2), loc=SourceLoc("in.spr", 7, 1))
    b.tran = Tran(1e-3, 0.1, LOC)
    with pytest.raises(NetlistError) as err:
        export_spice(check(b.finish()))
    assert err.value.format().startswith("in.spr:7:1: error: this force reads input channel 2")


def test_missing_transient_is_an_error():
    b = IRBuilder("no tran", file="n.spr")
    b.mass("M1", "a", 1.0)
    with pytest.raises(NetlistError, match="no .tran"):
        export_spice(check(b.finish()))
    assert ".tran 0.01 1.0 0 0.01 uic" in export_spice(check(b.finish()), SpiceOptions(1.0, 0.01))


def test_missing_ngspice_is_a_clear_error(monkeypatch):
    monkeypatch.setattr(shutil, "which", lambda name: None)
    with pytest.raises(SimulationError, match="ngspice is not installed"):
        run_ngspice(export_spice(check(small())), 0.1, 1e-3, probe_vectors(small()))


@needs_ngspice
def test_ngspice_failure_quotes_its_log():
    text = export_spice(check(small())).replace("Cm0 v0 0 2.0", "Cm0 v0 0 2.0 bogus=(")
    with pytest.raises(SimulationError) as err:
        run_ngspice(text, 0.1, 1e-3, probe_vectors(small()))
    assert "ngspice" in err.value.message


# ------------------------------------------------------------------ CLI

SPR = """\
.title two-mode band-pass filter
.param wa={2*pi*1000} delta=1.1 alpha=400
Ma xa m=1 b={alpha}
Mb xb m=1 b={alpha}
Ka xa k={wa**2}
Kb xb k={wa**2}
Cab xa xb k={(delta**2 - 1) * wa**2 / 2}
Fa xa in(0) gain={alpha * (1 + delta**2) * wa**2}
Fb xb in(0) gain={alpha * (1 - delta**2) * wa**2}
.probe x(xa) x(xb)
.tran {1/32000} 0.02
"""


def cli_case(tmp_path):
    spr = tmp_path / "bp.spr"
    spr.write_text(SPR)
    wav = tmp_path / "noise.wav"
    sf.write(wav, np.random.default_rng(0).normal(0, 0.1, 320), 16000, subtype="FLOAT")
    return spr, wav


@needs_ngspice
def test_cli_export_writes_a_circuit_that_ngspice_runs(tmp_path):
    from springc_cli.main import main

    spr, wav = cli_case(tmp_path)
    out = tmp_path / "bp.cir"
    res = CliRunner().invoke(
        main,
        [
            "export",
            "--spice",
            str(spr),
            "-o",
            str(out),
            "--input",
            str(wav),
            "--compare",
            "--substeps",
            "4",
        ],
    )
    assert res.exit_code == 0, res.output
    # the file's 320 samples at 16 kHz end at 0.02 s: springc and ngspice see the same signal
    for label in ("x(xa)", "x(xb)"):
        diff = re.search(
            rf"{re.escape(label)}: relative L2 difference .* ([0-9.e+-]+)\n", res.output
        )
        assert diff and float(diff.group(1)) < 1e-4, res.output
    run = subprocess.run(
        ["ngspice", "-b", out.name], cwd=tmp_path, capture_output=True, check=False
    )
    assert run.returncode == 0
    data = np.loadtxt(tmp_path / "springc_probes.txt", skiprows=1)
    assert data.shape[1] == 3 and data[-1, 0] == pytest.approx(0.02)
    assert np.all(np.isfinite(data)) and np.max(np.abs(data[:, 1])) > 0


def test_cli_unbound_input_exits_1_with_location_and_no_file(tmp_path):
    spr, _ = cli_case(tmp_path)
    out = tmp_path / "bp.cir"
    run = subprocess.run(
        ["springc", "export", "--spice", str(spr), "-o", str(out)],
        capture_output=True,
        text=True,
        check=False,
    )
    assert run.returncode == 1
    assert re.search(r"bp\.spr:8:1: error: this force reads input channel 0", run.stderr)
    assert "Traceback" not in run.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bp.spr", "noise.wav"]  # no output


def test_cli_requires_a_format(tmp_path):
    from springc_cli.main import main

    spr, _ = cli_case(tmp_path)
    res = CliRunner().invoke(main, ["export", str(spr), "-o", str(tmp_path / "x.cir")])
    assert res.exit_code == 1
    assert "--spice" in res.output


@needs_ngspice
def test_springc_simulator_agrees_with_ngspice_on_an_audio_driven_filter(tmp_path):
    """The cross-check the export is for: the two-mode band-pass filter of the language spec
    driven by noise through in(0), springc's RK4 kernel (4 substeps) against ngspice."""
    net = load_text(SPR, "bp.spr")
    rate = 1 / net.tran.tstep
    signal = np.random.default_rng(0).normal(0, 0.1, int(0.02 * rate))
    compared = cross_check(check(net), SpiceOptions(inputs={0: (signal, rate)}), substeps=4)
    assert compared.t[-1] == pytest.approx(0.02) and len(compared.t) == 641
    for label in ("x(xa)", "x(xb)"):
        assert compared.errors[label] == pytest.approx(
            rel_l2(compared.springc[label], compared.ngspice[label])
        )
        assert compared.errors[label] < 1e-4, label  # measured 1.2e-5 and 2.5e-5
    assert compared.springc_seconds > 0 and compared.ngspice_seconds > 0
    plot_cross_check(compared, tmp_path / "check.png")
    assert (tmp_path / "check.png").read_bytes()[:4] == b"\x89PNG"
