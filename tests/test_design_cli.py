"""cli/design.py: `springc design ...` writes readable .spr files, refuses bad input with exit 1
and leaves no file behind."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest
from click.testing import CliRunner
from springc_cli.main import main

from springc.lang import load_file, load_text


def run(*args: str):
    return CliRunner().invoke(main, ["design", *args])


def test_melbank_writes_a_subcircuit_and_reports_misfits(tmp_path):
    out = tmp_path / "bank.spr"
    res = run("melbank", "--bins", "4", "--fmax", "4000", "-o", str(out))
    assert res.exit_code == 0, res.output
    assert "misfit 2-mode" in res.output and len(res.output.splitlines()) >= 6
    net = load_text(f'.include "{out}"\nXb a b c d melbank\n')
    assert len(net.masses) == 8  # four two-mode filters


def test_melbank_plot(tmp_path):
    res = run("melbank", "--bins", "3", "-o", str(tmp_path / "b.spr"), "--plot",
              str(tmp_path / "b.png"))
    assert res.exit_code == 0, res.output
    assert (tmp_path / "b.png").read_bytes()[:4] == b"\x89PNG"


def test_mvm_from_npy(tmp_path):
    q, _ = np.linalg.qr(np.random.default_rng(3).standard_normal((5, 5)))
    np.save(tmp_path / "q.npy", q)
    res = run("mvm", "--matrix", str(tmp_path / "q.npy"), "-o", str(tmp_path / "mvm.spr"))
    assert res.exit_code == 0, res.output
    assert "N = 5" in res.output
    text = (tmp_path / "mvm.spr").read_text()
    assert ".subckt mvm in0 in1 in2 in3 in4 out0 out1 out2 out3 out4" in text


def test_bad_matrix_exits_1_without_output(tmp_path):
    np.save(tmp_path / "q.npy", np.ones((3, 3)))
    res = run("mvm", "--matrix", str(tmp_path / "q.npy"), "-o", str(tmp_path / "mvm.spr"))
    assert res.exit_code == 1
    assert "q.npy: Q is not orthogonal" in res.output
    assert "Traceback" not in res.output
    assert not (tmp_path / "mvm.spr").exists()


@pytest.mark.parametrize("args,names", [
    (["delayline", "--td", "0.01"], ["dl_m", "dl_kc", "dl_kl", "dl_b", "dl_td"]),
    (["readout", "--tau", "80", "--kext", "0.5"], ["ro_m", "ro_k", "ro_b", "ro_omega"]),
    (["lowpass", "--fc", "50", "--k", "100", "--bext", "0.16"], ["lp_m", "lp_k", "lp_b"]),
])
def test_parameter_files_define_the_parameters(tmp_path, args, names):
    out = tmp_path / "p.spr"
    res = run(*args, "-o", str(out))
    assert res.exit_code == 0, res.output
    use = " * ".join(names)
    net = load_text(f'.include "{out}"\nM1 a m={{abs({use})}}\n')
    assert net.masses.m[0] > 0


def test_delayline_params_drive_the_library_subcircuit(tmp_path):
    """The written parameters plugged into delayline.spr give m = td^2 kc per site."""
    run("delayline", "--td", "0.02", "--kc", "5", "-o", str(tmp_path / "p.spr"))
    (tmp_path / "top.spr").write_text('.include "p.spr"\n.include "delayline.spr"\n'
                                      "Xd a b delayline n=3 td={dl_td} kc={dl_kc} term=1\n")
    net = load_file(tmp_path / "top.spr")
    assert net.masses.m == pytest.approx([0.02**2 * 5] * 3)
    assert net.dashpots.b == pytest.approx([np.sqrt(0.02**2 * 5 * 5)])


@pytest.mark.parametrize("args", [["readout", "--tau", "-1"], ["readout", "--tau", "1",
                                                                "--qr", "0.7"],
                                  ["lowpass", "--fc", "50", "--bext", "100"]])
def test_bad_values_exit_1_without_output(tmp_path, args):
    res = run(*args, "-o", str(tmp_path / "x.spr"))
    assert res.exit_code == 1 and res.output.startswith("error:")
    assert not (tmp_path / "x.spr").exists()


def test_installed_command(tmp_path):
    """The console script, as a user runs it."""
    proc = subprocess.run(["springc", "design", "readout", "--tau", "80", "-o",
                           str(tmp_path / "r.spr")], capture_output=True, text=True,
                          check=False)
    assert proc.returncode == 0, proc.stderr
    assert "ro_omega = 1.249874987" in proc.stdout
