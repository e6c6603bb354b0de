"""`compiler.build`: front end, checks and the summary of the result."""

from __future__ import annotations

import json

import numpy as np
import pytest

from springc.check import compiler
from springc.errors import CheckError, NetlistError

FILTER = """\
.title two-mode filter
.param wa={2*pi*1000} delta=1.1 alpha=400
.subckt osc n w=1
Mn n m=1 b={alpha}
Kn n k={w**2}
.ends
X1 xa osc w={wa}
X2 xb osc w={wa}
Cab xa xb k={(delta**2 - 1) * wa**2 / 2}
Fa xa in(0) gain=1
Mfree f m=2
.tran {1/64000} 1
"""


@pytest.fixture
def netlist(tmp_path):
    path = tmp_path / "filter.spr"
    path.write_text(FILTER)
    return path


def test_report(netlist) -> None:
    report = compiler.build(netlist)
    wb = 1.1 * 2 * np.pi * 1000
    assert report.dofs == 3
    assert report.elements == {"M": 3, "K": 2, "C": 1, "F": 1}
    assert (report.instances, report.instances_by_subckt) == (2, {"osc": 2})
    assert report.omega_max == pytest.approx(wb, rel=1e-12)
    assert report.f_max_hz == pytest.approx(1100.0, rel=1e-12)
    # Damped pair: lambda = -200 +- i sqrt(wb^2 - 200^2), |lambda| = wb; RK4's limit along
    # that direction is a little above the imaginary-axis value 2 sqrt 2 / wb.
    assert 2.8 / wb < report.dt_max < 2.9 / wb
    assert [n for n, _ in report.fastest_nodes] == ["xa", "xb"]
    assert report.tstep == pytest.approx(1 / 64000)
    assert report.zero_modes == 1
    assert [d.severity for d in report.notes] == ["info"]


def test_json_has_the_spec_keys(netlist) -> None:
    data = compiler.build(netlist, method="ssprk3").to_json()
    text = json.dumps(data)
    assert {"dofs", "elements", "omega_max", "dt_max"} <= set(data)
    assert data["method"] == "ssprk3" and json.loads(text)["dofs"] == 3


def test_unlimited_step_is_null_in_json(tmp_path) -> None:
    path = tmp_path / "free.spr"
    path.write_text("M1 a m=1\n")
    report = compiler.build(path)
    assert report.dt_max == np.inf and report.to_json()["dt_max"] is None
    assert "unlimited" in report.summary()


def test_summary_text(netlist) -> None:
    text = compiler.build(netlist).summary()
    assert "dofs        3" in text and "M=3, K=2, C=1, F=1" in text and "(osc: 2)" in text
    assert "1100 Hz" in text and "chosen for tolerance 0.001" in text
    assert "zero-stiffness" in text
    pinned = compiler.build(netlist, method="rk4").summary()
    assert "stable" in pinned and "chosen" not in pinned


def test_errors_carry_every_failed_check(tmp_path) -> None:
    path = tmp_path / "bad.spr"
    path.write_text("M1 a m=-1\nK1 a k=-1\n")
    with pytest.raises(CheckError) as info:
        compiler.build(path)
    assert [d.loc.line for d in info.value.diagnostics] == [1, 2]
    assert info.value.format().startswith(f"{path}:1:1: error: M1: mass m=-1 must be > 0")


def test_front_end_errors_pass_through(tmp_path) -> None:
    path = tmp_path / "syntax.spr"
    path.write_text("M1 a m=\n")
    with pytest.raises(NetlistError):
        compiler.build(path)
