"""`springc build`, `springc ac` and `springc modes` through click's CliRunner, and `build`
once as a real subprocess of the installed `springc`."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from springc_cli.main import main

import springc
from springc.design.filters import two_mode_response

EXAMPLES = Path(__file__).resolve().parent.parent / "netlists" / "examples"

FILTER = """\
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
.tran {1/64000} 1
.ac xb 200 5000 points=50
"""


@pytest.fixture
def netlist(tmp_path):
    path = tmp_path / "filter.spr"
    path.write_text(FILTER)
    return path


def _run(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def test_build_json(netlist) -> None:
    res = _run("build", netlist, "--json")
    assert res.exit_code == 0, res.output
    data = json.loads(res.output)
    assert data["dofs"] == 2 and data["elements"] == {"M": 2, "K": 2, "C": 1, "F": 2}
    assert data["omega_max"] == pytest.approx(1.1 * 2 * np.pi * 1000, rel=1e-12)
    assert data["dt_max"] > 1 / 64000


def test_build_text_and_kernel(netlist, tmp_path) -> None:
    kernel = tmp_path / "kernel.py"
    res = _run("build", netlist, "--emit-kernel", kernel, "--method", "rk38")
    assert res.exit_code == 0, res.output
    assert "omega_max" in res.output and "(rk38)" in res.output
    text = kernel.read_text()
    assert "def " in text and "rk38" in text


def test_a_library_file_is_summarised_by_its_subcircuits(tmp_path) -> None:
    bank = tmp_path / "bank.spr"
    res = _run("design", "melbank", "--bins", 3, "-o", bank)
    assert res.exit_code == 0, res.output
    data = json.loads(_run("build", bank, "--json").output)
    by_name = {s["name"]: s for s in data["subckts"]}
    melbank = by_name["melbank"]
    assert data["dofs"] == 0 and melbank["ports"] == ["out0", "out1", "out2"]
    # two masses per two-mode filter, one drive per mass
    assert melbank["dofs"] == 6 and melbank["elements"]["M"] == 6
    assert melbank["elements"]["F"] == 6 and melbank["params"] == {"ch": "0"}
    text = _run("build", bank).output
    assert "a library of 4 subcircuit(s), no top-level network" in text
    assert "melbank out0 out1 out2  ch=0" in text and "dofs 6" in text
    res = CliRunner().invoke(main, ["build", str(bank), "--emit-kernel", str(tmp_path / "k.py")])
    assert res.exit_code == 1 and "has no kernel" in res.output
    assert not (tmp_path / "k.py").exists()


def test_a_library_summary_shows_defaults_as_written(tmp_path) -> None:
    lib = tmp_path / "lib.spr"
    lib.write_text(".subckt osc a f0=1k q={2 * 5}\nMa a m=1 b={1/q}\n"
                   "Ka a k={(2*pi*f0)**2}\n.ends\n")
    data = json.loads(_run("build", lib, "--json").output)
    assert data["subckts"] == [{"name": "osc", "ports": ["a"],
                                "params": {"f0": "1k", "q": "{2 * 5}"}, "dofs": 1,
                                "elements": {"M": 1, "K": 1}, "loc": f"{lib}:1:1"}]


def test_build_error_exits_1_with_location_and_caret(tmp_path) -> None:
    """A step the netlist pins (`.options method=`) above its stability limit is refused."""
    bad = tmp_path / "bad.spr"
    bad.write_text(FILTER.replace("64000", "1000") + ".options method=rk4\n")
    res = _run("build", bad)
    assert res.exit_code == 1
    assert f"{bad}:11:1: error: time step 0.001 s is unstable for rk4" in res.output
    assert "   11 | .tran {1/1000} 1\n      | ^" in res.output
    assert "Traceback" not in res.output


STIFF = "* one stiff mass\nM1 n1 m=1 b=0.1 x0=1\nK1 n1 k=1e8\n.probe x(n1)\n.tran 1m 0.01\n"


def test_build_reports_the_integration_sim_chooses(tmp_path) -> None:
    """Unpinned, a step above RK4's limit (sqrt(8) / 1e4 s for k = 1e8) is not an error: build
    reports what sim takes, the cheapest (method, substeps) of `accuracy.choose`, and sim
    takes exactly that; the same step pinned by --method is refused by both."""
    path = tmp_path / "stiff.spr"
    path.write_text(STIFF)
    data = json.loads(_run("build", path, "--json").output)
    chosen = data["integration"]
    assert chosen["chosen"] and chosen["tolerance"] == 1e-3
    # RK4 reaches 2 sqrt(2) on the imaginary axis; the damping (0.05/s against 1e4 rad/s)
    # moves the eigenvalue off it by 5e-6 of its size, and the limit by about as much
    assert data["dt_max"] == pytest.approx(np.sqrt(8) / 1e4, rel=1e-4)
    assert chosen["h"] == 1e-3 / chosen["substeps"] <= data["dt_max"]
    res = _run("sim", path, "-o", tmp_path / "out.npz")
    assert res.exit_code == 0, res.output
    assert (f"chose {chosen['method']} with {chosen['substeps']} substep(s)"
            in res.output)
    for command in (["build", path], ["sim", path, "-o", tmp_path / "pinned.npz"]):
        res = _run(*command, "--method", "rk4")
        assert res.exit_code == 1 and "is unstable for rk4" in res.output
    assert not (tmp_path / "pinned.npz").exists()


def test_build_warns_where_sim_refuses(tmp_path) -> None:
    """Released at 1.6 kHz (Q 1e5) and recorded at 1 kHz for 1 s, the mode the initial state
    excites cannot be held within 1e-3 by RK4 up to 64 substeps: build warns, and sim
    refuses with the same reason and writes nothing."""
    path = tmp_path / "stiff.spr"
    path.write_text(STIFF.replace(".tran 1m 0.01", ".tran 1m 1"))
    built = _run("build", path)
    assert built.exit_code == 0 and "warning: no integrator meets tolerance 0.001" in built.output
    res = _run("sim", path, "-o", tmp_path / "out.npz")
    assert res.exit_code == 1 and "no integrator meets tolerance 0.001" in res.output
    assert "Traceback" not in res.output and not (tmp_path / "out.npz").exists()


@pytest.mark.parametrize("name", sorted(p.name for p in EXAMPLES.glob("*.spr")))
def test_build_and_sim_agree_on_every_example(name) -> None:
    """`springc build` and `springc sim` (here: their library calls) name the same
    integration for every example netlist: the netlist's own where it pins one, else the
    choice for 1e-3, which step doubling confirms on the nonlinear examples."""
    net = springc.load(EXAMPLES / name)
    report = net.summary(as_dict=True)["integration"]
    res = net.simulate()
    assert (report["method"], report["substeps"]) == (res.settings.method,
                                                      res.settings.substeps)
    assert (res.choice is not None) == report["chosen"]


def test_ac_writes_csv_and_plot(netlist, tmp_path) -> None:
    out, png = tmp_path / "h.csv", tmp_path / "h.png"
    res = _run("ac", netlist, "--node", "xb", "-o", out, "--plot", png)
    assert res.exit_code == 0, res.output
    table = np.loadtxt(out, delimiter=",", skiprows=1)
    assert out.read_text().startswith("f_hz,mag,phase_rad\n") and table.shape == (50, 3)
    np.testing.assert_allclose(table[[0, -1], 0], [200, 5000], rtol=1e-12)
    h = two_mode_response(table[:, 0], 1000.0, 1.1, 400.0)
    np.testing.assert_allclose(table[:, 1], np.abs(h), rtol=1e-6)
    np.testing.assert_allclose(table[:, 2], np.angle(h), atol=1e-6)
    assert png.read_bytes()[:4] == b"\x89PNG"


def test_ac_options_override_the_directive(netlist, tmp_path) -> None:
    out = tmp_path / "h.csv"
    res = _run("ac", netlist, "--fmin", 10, "--fmax", 100, "--points", 3, "-o", out)
    assert res.exit_code == 0, res.output
    np.testing.assert_allclose(np.loadtxt(out, delimiter=",", skiprows=1)[:, 0], [10, 31.6227766,
                                                                                 100], rtol=1e-8)


def test_ac_bad_node_exits_1_and_writes_nothing(netlist, tmp_path) -> None:
    out = tmp_path / "h.csv"
    res = _run("ac", netlist, "--node", "nope", "-o", out)
    assert res.exit_code == 1 and "unknown node 'nope'" in res.output
    assert not out.exists()


def test_modes_json_and_text(netlist) -> None:
    res = _run("modes", netlist, "--json")
    assert res.exit_code == 0, res.output
    rows = json.loads(res.output)["modes"]
    np.testing.assert_allclose([r["freq_hz"] for r in rows], [1000, 1100], rtol=1e-12)
    np.testing.assert_allclose([r["damping_rate"] for r in rows], [200, 200], rtol=1e-12)
    text = _run("modes", netlist, "--count", 1).output
    assert "1000" in text and "1100 " not in text


@pytest.mark.skipif(shutil.which("springc") is None, reason="springc not installed")
def test_installed_springc_build(netlist, tmp_path) -> None:
    proc = subprocess.run(["springc", "build", str(netlist), "--json"], capture_output=True,
                          text=True, timeout=300, check=False)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["dofs"] == 2
    bad = tmp_path / "bad.spr"
    bad.write_text("M1 a m=0\n")
    proc = subprocess.run(["springc", "build", str(bad)], capture_output=True, text=True,
                          timeout=300, check=False)
    assert proc.returncode == 1
    assert f"{bad}:1:1: error: M1: mass m=0 must be > 0" in proc.stderr


def test_ac_needs_a_node(tmp_path) -> None:
    path = tmp_path / "plain.spr"
    path.write_text(FILTER.replace(".ac xb 200 5000 points=50\n", ""))
    res = _run("ac", path, "-o", tmp_path / "h.csv")
    assert res.exit_code == 1 and "no output node: give --node or an .ac directive" in res.output


def test_modes_refuses_a_netlist_that_fails_the_checks(tmp_path) -> None:
    path = tmp_path / "bad.spr"
    path.write_text("M1 a m=1\nK1 a k=-1\n")
    res = _run("modes", path)
    assert res.exit_code == 1 and "2:1: error: K1: stiffness k=-1 must be >= 0" in res.output
