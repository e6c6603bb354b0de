"""`springc grad`: JSON output against the library, summing over inputs, per-run rows, and
user errors (exit 1, a located or option-naming message, no traceback)."""

from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest
import soundfile as sf
from click.testing import CliRunner
from reference_nets import GRAD_NETLIST

from springc.grad import ParamNetlist, gradient
from springc_cli.main import main


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    folder = tmp_path_factory.mktemp("grad")
    (folder / "net.spr").write_text(GRAD_NETLIST)
    t = np.arange(240) / 8000
    sf.write(folder / "a.wav", 0.2 * np.sin(2 * np.pi * 300 * t), 8000, subtype="DOUBLE")
    sf.write(folder / "b.wav", 0.1 * np.sin(2 * np.pi * 90 * t), 8000, subtype="DOUBLE")
    return folder


def run(*args: str):
    return CliRunner().invoke(main, ["grad", *args])


def test_json_sums_the_runs_and_matches_the_library(case):
    net, a, b = (str(case / n) for n in ("net.spr", "a.wav", "b.wav"))
    out = run(net, "--of", "msq:x(b)", "--wrt", "k0", "--wrt", "gain", "-i", a, "-i", b,
              "--json")
    assert out.exit_code == 0, out.output
    got = json.loads(out.output)
    lib = gradient(ParamNetlist.load(net), "msq:x(b)", ["k0", "gain"], [a, b])
    assert got["of"] == "msq:x(b)"
    assert got["value"] == pytest.approx(lib.values["msq:x(b)"].sum(), rel=1e-12)
    assert got["grad"] == pytest.approx(dict(zip(["k0", "gain"], lib.grad.sum(axis=0))),
                                        rel=1e-12)


def test_per_run_gives_one_row_per_input(case):
    net, a, b = (str(case / n) for n in ("net.spr", "a.wav", "b.wav"))
    out = run(net, "--of", "work:in", "--wrt", "bb", "-i", a, "-i", b, "--json", "--per-run")
    assert out.exit_code == 0, out.output
    rows = json.loads(out.output)
    assert [r["run"] for r in rows] == [a, b]
    lib = gradient(ParamNetlist.load(net), "work:in", ["bb"], [a, b])
    assert [r["grad"]["bb"] for r in rows] == pytest.approx(lib.grad[:, 0], rel=1e-12)


def test_text_output_names_each_parameter(case):
    out = run(str(case / "net.spr"), "--of", "final:x(a)", "--wrt", "k0", "--wrt", "l0")
    assert out.exit_code == 0, out.output
    assert out.output.startswith("final:x(a) = ")
    assert "d/dk0" in out.output and "d/dl0" in out.output


@pytest.mark.parametrize("args, message", [
    (["--wrt", "k1"], "error: --wrt k1: "),
    (["--wrt", "unused"], "net.spr:1:37: error: --wrt unused: no element coefficient"),
    (["--wrt", "amp"], "net.spr:1:46: error: --wrt amp: the parameter sets more than"),
])
def test_parameter_errors_exit_1_naming_the_option(case, args, message):
    out = run(str(case / "net.spr"), "--of", "final:x(a)", *args)
    assert out.exit_code == 1
    assert message in out.output
    assert "Traceback" not in out.output


@pytest.mark.parametrize("spec, message", [
    ("mean:x(a)", "error: --of mean:x(a): bad reduction"),
    ("msq:x(q)", "error: --of msq:x(q): unknown node 'q'"),
    ("energy", "error: --of energy: no gradient for this reduction"),
])
def test_bad_specs_exit_1_naming_the_option(case, spec, message):
    out = run(str(case / "net.spr"), "--of", spec, "--wrt", "k0")
    assert out.exit_code == 1
    assert message in out.output
    assert "Traceback" not in out.output


def test_a_netlist_error_is_located(case):
    bad = case / "bad.spr"
    bad.write_text(GRAD_NETLIST.replace("Kb b k={2*k0}", "Kb b k={2*k9}"))
    out = run(str(bad), "--of", "final:x(a)", "--wrt", "k0")
    assert out.exit_code == 1
    assert "bad.spr:5:" in out.output and "undefined parameter 'k9'" in out.output


def test_installed_command_runs(case):
    proc = subprocess.run(["springc", "grad", str(case / "net.spr"), "--of", "final:v(b)",
                           "--wrt", "k0", "--json"], capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert set(json.loads(proc.stdout)["grad"]) == {"k0"}
