"""`springc sim`: outputs, formats, plots and user errors (exit 1, no traceback, no file)."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest
import soundfile as sf
from click.testing import CliRunner

import springc

from springc.lang import load_file
from springc_cli.main import main
from springc.check import check

NETLIST = """\
.title cli oscillator
.param w0={2*pi*40}
Ma a m=1 b=30
Ka a k={w0**2}
Fa a in(0) gain=500
Fs a sin(20 25)
.probe x(a) v(a)
.tran 1e-4 0.05
"""


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    folder = tmp_path_factory.mktemp("sim")
    (folder / "osc.spr").write_text(NETLIST)
    inputs = folder / "inputs"
    inputs.mkdir()
    t = np.arange(400) / 8000
    sf.write(inputs / "a.wav", 0.2 * np.sin(2 * np.pi * 300 * t), 8000, subtype="DOUBLE")
    sf.write(inputs / "b.flac", 0.1 * np.sin(2 * np.pi * 90 * t), 8000)
    sf.write(folder / "stereo.wav", np.stack([t, t], axis=1), 8000)
    return folder


def invoke(*args):
    return CliRunner().invoke(main, ["sim", *map(str, args)])


def test_npz_holds_t_probes_and_reductions_as_the_library_computes(case):
    out = case / "out.npz"
    res = invoke(case / "osc.spr", "-i", case / "inputs", "-o", out, "--plot", case / "p.png",
                 "--reduce", "energy", "--reduce", "final:v(a)")
    assert res.exit_code == 0, res.output
    data = np.load(out)
    assert data["t"].shape == (501,) and data["x(a)"].shape == (2, 501)
    assert [p.rsplit("/", 1)[-1] for p in data["runs"]] == ["a.wav", "b.flac"]
    lib = springc.load(case / "osc.spr").simulate([case / "inputs"],
                                                 reduce=["energy", "final:v(a)"])
    assert lib.choice and lib.choice in res.output  # the default: chosen for 1e-3, said
    np.testing.assert_array_equal(data["v(a)"], lib["v(a)"])
    np.testing.assert_array_equal(data["energy"], lib["energy"])
    assert data["final:v(a)"][1] == data["v(a)"][1, -1]
    assert (case / "p.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def _spy_simulate(monkeypatch, key: str):
    """Replace `springc.sim.simulate.simulate` by a wrapper recording each call's `key`
    keyword: (the values seen, the real function)."""
    from springc.sim import simulate as sm

    seen = []
    real = sm.simulate

    def spy(*args, **kw):
        seen.append(kw[key])
        return real(*args, **kw)

    monkeypatch.setattr(sm, "simulate", spy)
    return seen, real


@pytest.mark.parametrize("form, write_out", [("auto", None), ("written-out", True),
                                             ("shared", False)])
def test_kernel_form_reaches_simulate(case, monkeypatch, form, write_out):
    seen, real = _spy_simulate(monkeypatch, "write_out")
    res = invoke(case / "osc.spr", "-i", case / "inputs", "-o", case / f"{form}.npz",
                 "--kernel", form, "--method", "rk4")
    assert res.exit_code == 0, res.output
    assert seen == [write_out]
    lib = real(check(load_file(case / "osc.spr")), [case / "inputs"], write_out=write_out)
    np.testing.assert_array_equal(np.load(case / f"{form}.npz")["x(a)"], lib.probes["x(a)"])


def test_no_fma_reaches_simulate_and_changes_only_the_rounding(case, monkeypatch):
    """`--no-fma`: the kernel fuses no product with an add (`simulate(fma=False)`); the
    trajectories are the fused kernel's to rounding."""
    seen, real = _spy_simulate(monkeypatch, "fma")
    res = invoke(case / "osc.spr", "-i", case / "inputs", "-o", case / "exact.npz",
                 "--method", "rk4", "--no-fma")
    assert res.exit_code == 0, res.output
    assert seen == [False]
    got = np.load(case / "exact.npz")["x(a)"]
    lib = real(check(load_file(case / "osc.spr")), [case / "inputs"], fma=False)
    np.testing.assert_array_equal(got, lib.probes["x(a)"])
    fused = real(check(load_file(case / "osc.spr")), [case / "inputs"])
    np.testing.assert_allclose(got, fused.probes["x(a)"], rtol=0,
                               atol=1e-12 * np.abs(got).max())


def test_csv_long_format_and_overrides(case):
    out = case / "out.csv"
    res = invoke(case / "osc.spr", "-o", out, "--tstop", "0.01", "--outrate", "5000",
                 "--substeps", "2", "--method", "rk38", "--reduce", "energy")
    assert res.exit_code == 0, res.output
    rows = out.read_text().splitlines()
    assert rows[0] == "run,quantity,t,value"
    assert len(rows) == 1 + 2 * 51 + 1  # two probes of 51 samples, one reduction
    assert rows[2].startswith("run0,x(a),0.0002,")


@pytest.mark.parametrize("args, message", [
    (["-o", "{d}/x.txt"], "unknown format"),
    (["-i", "{d}/missing.wav", "-o", "{d}/x.npz"], "missing.wav: no such file"),
    (["-i", "{d}/stereo.wav", "-o", "{d}/x.npz"], "stereo.wav: has 2 channels"),
    (["-o", "{d}/x.npz", "--reduce", "msq:x(nowhere)"], "unknown node 'nowhere'"),
    (["-o", "{d}/x.npz", "--tstep", "0.02", "--tstop", "20", "--method", "rk4"],
     "is unstable for rk4"),
    (["-o", "{d}/x.npz", "--tolerance", "1e-3", "--method", "rk4"], "chooses the method"),
])
def test_user_errors_exit_1_without_traceback_or_output(case, args, message):
    res = invoke(case / "osc.spr", *[a.format(d=case) for a in args])
    assert res.exit_code == 1, res.output
    assert message in res.output and "Traceback" not in res.output
    assert not list(case.glob("x.*")) and not list(case.glob(".x.*"))


def test_installed_command_runs_and_documents_reductions(case):
    help_text = subprocess.run(["springc", "sim", "--help"], capture_output=True, text=True,
                               check=True).stdout
    assert "msq:x(N)[:T0:T1]" in help_text and "dissipated:all" in help_text
    done = subprocess.run(["springc", "sim", str(case / "osc.spr"), "-i",
                           str(case / "inputs/a.wav"), "-o", str(case / "sub.npz")],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert np.load(case / "sub.npz")["x(a)"].shape == (1, 501)
