"""The split integrators (exp-rk4, strang-rk4) wherever a method is named: `.options method=`,
`springc build --method` (step check, exact blocks, per-mode errors, kernel) and `springc sim`
following the netlist's option."""

from __future__ import annotations

import json

import numpy as np
import pytest
import soundfile as sf
from click.testing import CliRunner
from springc_cli.main import main

# Two driven filter pairs at 7 and 8 kHz (paper Eq. filter-response; their fastest modes are
# 7.7 and 8.8 kHz, omega h = 3.0 and 3.5 at the 16 kHz step, past RK4's 2.83), squared (Q) into
# a slow coupled pair r, s at 50 Hz.
NETLIST = """\
.title two fast filter pairs and a slow coupled part
.param w1={2*pi*7000} w2={2*pi*8000} delta=1.1 alpha=400 ws={2*pi*50}
Ma xa m=1 b={alpha}
Mb xb m=1 b={alpha}
Ka xa k={w1**2}
Kb xb k={w1**2}
Cab xa xb k={(delta**2 - 1) * w1**2 / 2}
Fa xa in(0) gain={alpha * (1 + delta**2) * w1**2}
Fb xb in(0) gain={alpha * (1 - delta**2) * w1**2}
Mc xc m=1 b={alpha}
Md xd m=1 b={alpha}
Kc xc k={w2**2}
Kd xd k={w2**2}
Ccd xc xd k={(delta**2 - 1) * w2**2 / 2}
Fc xc in(0) gain={alpha * (1 + delta**2) * w2**2}
Fd xd in(0) gain={alpha * (1 - delta**2) * w2**2}
Mr r m=1 b=20
Ms s m=1 b=20
Kr r k={ws**2}
Ks s k={ws**2}
Crs r s k={ws**2/4}
Qbr xb r g=1e3
Qds xd s g=1e3
.probe x(xa) x(xd) x(r) x(s)
OPTIONS
.tran {1/16000} 0.05
"""
TRAN_LINE = 26
STIFF = "Mt t m=1\nKt t k={(2*pi*9000)**2}\nCst s t k=1e3\n"


def _write(folder, name: str, options: str = "", extra: str = ""):
    path = folder / name
    path.write_text(NETLIST.replace("OPTIONS", options) + extra)
    return path


def _run(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def test_build_rejects_rk4_with_the_step_it_needs(tmp_path) -> None:
    path = _write(tmp_path, "pairs.spr")
    res = _run("build", path, "--method", "rk4")
    assert res.exit_code == 1
    assert (f"{path}:{TRAN_LINE}:1: error: time step 6.25e-05 s is unstable for rk4: the "
            "oscillating mode at 8800 Hz") in res.output
    assert "hint: use .tran tstep <= 5.129" in res.output and "substeps=2" in res.output
    assert "Traceback" not in res.output


def _rk4_log_ratio(lam: complex, h: float) -> complex:
    """log(R(z) / exp(z)) of classic RK4, R(z) = 1 + z + z^2/2 + z^3/6 + z^4/24."""
    z = lam * h
    return np.log(1 + z + z**2 / 2 + z**3 / 6 + z**4 / 24) - z


def test_build_with_options_exp_rk4_reports_exact_blocks_and_mode_errors(tmp_path) -> None:
    res = _run("build", _write(tmp_path, "pairs.spr", ".options method=exp_rk4"), "--json")
    assert res.exit_code == 0, res.output
    data = json.loads(res.output)
    assert data["method"] == "exp-rk4"
    assert data["exact_blocks"] == [["xa", "xb"], ["xc", "xd"]]
    assert data["omega_max"] == pytest.approx(1.1 * 2 * np.pi * 8000, rel=1e-12)
    assert data["dt_max"] > 100 * data["tstep"]  # only the 50 Hz part limits the step
    assert {n["node"] for n in data["fastest_nodes"][:2]} == {"r", "s"}
    rows = data["mode_errors"]
    exact = sorted(round(r["freq_hz"]) for r in rows if r["exact"])
    assert exact == [7000, 7700, 8000]  # the 5 worst listed: 8800 Hz is the fifth exact one
    assert all(r["error"] == 0 for r in rows if r["exact"])
    slow = [r for r in rows if not r["exact"]]
    assert {tuple(r["nodes"]) for r in slow} <= {("r", "s"), ("s", "r")} and len(slow) == 2
    for r in slow:  # the rest is RK4: its per-step amplitude and phase error
        lam = complex(-r["damping_rate"], np.sqrt((2 * np.pi * r["freq_hz"]) ** 2
                                                 - r["damping_rate"] ** 2))
        lr = _rk4_log_ratio(lam, data["tstep"])
        assert r["amplitude_per_step"] == pytest.approx(lr.real, rel=1e-3, abs=1e-15)
        assert r["phase_per_step"] == pytest.approx(lr.imag, rel=1e-3, abs=1e-15)
        assert 0 < r["error"] < 1e-6


def test_build_text_names_the_blocks_and_the_limiting_mode(tmp_path) -> None:
    res = _run("build", _write(tmp_path, "pairs.spr"), "--method", "strang-rk4")
    assert res.exit_code == 0, res.output
    assert "  exact       2 block(s) by matrix exponential: (xa, xb), (xc, xd)" in res.output
    assert "  limiting    oscillating mode at 61.4" in res.output
    assert "(strang-rk4)" in res.output and "exact (split block); nodes xc, xd" in res.output


def test_build_split_rejects_a_stiff_rest(tmp_path) -> None:
    path = _write(tmp_path, "stiff.spr", '.options method="exp-rk4"', STIFF)
    res = _run("build", path)
    assert res.exit_code == 1
    assert (f"{path}:{TRAN_LINE}:1: error: time step 6.25e-05 s is unstable for exp-rk4: the "
            "oscillating mode at 9000") in res.output
    assert "dominant nodes t (1.00)" in res.output


def test_build_emits_the_split_kernel(tmp_path) -> None:
    kernel = tmp_path / "kernel.py"
    res = _run("build", _write(tmp_path, "pairs.spr"), "--method", "exp-rk4", "--emit-kernel",
               kernel)
    assert res.exit_code == 0, res.output
    text = kernel.read_text()
    assert "# integrator: exp-rk4 (" in text and "def run(" in text


def test_build_unknown_method_lists_all(tmp_path) -> None:
    res = _run("build", _write(tmp_path, "pairs.spr"), "--method", "exp-rk5")
    assert res.exit_code == 1
    assert "error: unknown integrator 'exp-rk5'" in res.output
    assert "known: rk4, rk38, ssprk3, heun3, midpoint, strang-rk4, exp-rk4" in res.output
    path = _write(tmp_path, "bad.spr", ".options method=exp_rk5")
    res = _run("build", path)
    assert res.exit_code == 1
    assert f"{path}:{TRAN_LINE - 1}:17: error: unknown integration method 'exp_rk5'" in res.output


def test_sim_follows_options_method(tmp_path) -> None:
    """`.options method=exp_rk4` gives the trajectory of `--method exp-rk4` (to 1e-12). Not a
    coincidence of defaults: RK4, the default, is unstable at this step (the divergence guard
    would stop the run)."""
    rng = np.random.default_rng(3)
    sf.write(tmp_path / "noise.wav", 1e-3 * rng.normal(size=800), 16000, subtype="DOUBLE")
    runs = {"option": (_write(tmp_path, "opt.spr", ".options method=exp_rk4"), []),
            "flag": (_write(tmp_path, "plain.spr"), ["--method", "exp-rk4"])}
    out = {}
    for name, (path, extra) in runs.items():
        res = _run("sim", path, "-i", tmp_path / "noise.wav", "-o", tmp_path / f"{name}.npz",
                   *extra)
        assert res.exit_code == 0, res.output
        out[name] = np.load(tmp_path / f"{name}.npz")
    for probe in ("x(xa)", "x(xd)", "x(r)", "x(s)"):
        scale = np.abs(out["flag"][probe]).max()
        assert scale > 0 and np.isfinite(scale)
        assert np.abs(out["option"][probe] - out["flag"][probe]).max() <= 1e-12 * scale
