"""`springc design scale`: a normalised design at a physical mass and length scale is the same
dynamics (positions and velocities x lambda) to 1e-12 in every kernel form; the flat `.spr`
it writes reads back to the same coefficients; sound pressure sets the input gains."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import springc
from springc.design.scale import P_REF, acoustic_gains, flat_text, probe_names, scale_netlist
from springc.lang import load_text
from springc_cli.main import main

NET = """* every element kind, in normalised units
.subckt pair p q
Kp p k=25
Cpq p q k=5 a=1.5
.ends pair
Ma a m=1 b=0.3 x0=0.2
Mb b m=2 b=0.1 v0=-0.1
Mc c m=0.5
Ka a k=40
Kc c k=10
Da a l=3
X1 b a pair
Qac a c g=0.8 a=2
Bbc b c b=0.2
Pab c=0.1 a^2 b^2
Fa a in(0) gain=2
Fs b sin(0.5 3)
.probe x(a) v(b) x(c)
.tran 1m 1
"""
MASS, LENGTH = 3e-9, 2e-6
U = np.sin(2 * np.pi * 7 * np.arange(1001) / 1000.0)[None, None] * 0.4


def simulated(text: str, form: str, **kw) -> dict[str, np.ndarray]:
    """The probes, after checking that the kernel of `form` ran (its generated header)."""
    res = springc.load(text).simulate(U, **kw)
    head = Path(res.info["kernel"]).read_text()[:2000]
    assert form in head, head
    assert form != "springc.kernels.codegen;" or "written out per node" not in head
    return res.probes


@pytest.mark.parametrize("form, kw, monomial", [
    ("springc.kernels.codegen;", dict(method="rk4", substeps=2, kernel="shared"), True),
    ("written out per node", dict(method="rk4", substeps=2, kernel="written-out"), True),
    ("springc.kernels.regkernel", dict(method="rk4", substeps=2, kernel="written-out"), False),
    ("springc.kernels.expint", dict(method="exp-rk4", substeps=2), True),
])
def test_scaled_design_is_the_same_dynamics(form, kw, monomial) -> None:
    text = NET if monomial else NET.replace("Pab c=0.1 a^2 b^2\n", "")
    flat = load_text(text)
    scaled = flat_text(scale_netlist(flat, MASS, LENGTH))
    base, phys = simulated(text, form, **kw), simulated(scaled, form, **kw)
    names = probe_names(flat)
    for label, y in base.items():
        got = phys[names[label]] / LENGTH
        assert np.linalg.norm(got - y) <= 1e-12 * np.linalg.norm(y), (form, label)


def test_flat_text_reads_back_the_same_coefficients() -> None:
    flat = load_text(NET)
    again = load_text(flat_text(flat))
    for table in ("masses", "springs", "duffings", "couplings", "quads", "dashpots",
                  "monomials", "forces"):
        a, b = getattr(flat, table), getattr(again, table)
        for key, value in vars(a).items():
            if isinstance(value, np.ndarray) and value.dtype.kind == "f":
                np.testing.assert_array_equal(getattr(b, key), value)
    assert len(again.nodes) == len(flat.nodes) and "X1_p" not in again.nodes


def test_the_factors_follow_each_coefficient_s_degree() -> None:
    flat = load_text(NET)
    s = scale_netlist(flat, MASS, LENGTH)
    assert s.masses.m[0] == MASS * 1 and s.masses.x0[0] == 0.2 * LENGTH
    assert s.duffings.l[0] == pytest.approx(3 * MASS / LENGTH**2, rel=1e-15)
    assert s.quads.g[0] == pytest.approx(0.8 * MASS / LENGTH, rel=1e-15)
    assert s.quads.a[0] == pytest.approx(2 * LENGTH, rel=1e-15)
    assert s.monomials.c[0] == pytest.approx(0.1 * MASS / LENGTH**2, rel=1e-15)  # degree 4
    assert s.forces.gain[0] == pytest.approx(2 * MASS * LENGTH, rel=1e-15)


def test_sound_pressure_sets_the_largest_input_gain_to_p_times_area() -> None:
    flat = load_text(NET.replace("Fs b sin(0.5 3)", "Fb b in(0) gain=-0.5"))
    acoustic = acoustic_gains(flat, 60.0, 1e-6)
    force = P_REF * 1e3 * 1e-6  # 60 dB SPL is 20 mPa
    assert acoustic.forces.gain[0] == pytest.approx(force, rel=1e-12)
    assert acoustic.forces.gain[1] == pytest.approx(-0.25 * force, rel=1e-12)


def invoke(*args):
    return CliRunner().invoke(main, ["design", "scale", *map(str, args)])


def test_command_writes_a_netlist_that_builds(tmp_path) -> None:
    (tmp_path / "n.spr").write_text(NET)
    res = invoke(tmp_path / "n.spr", "--mass", MASS, "--length", LENGTH, "-o",
                 tmp_path / "phys.spr")
    assert res.exit_code == 0, res.output
    assert springc.load(tmp_path / "phys.spr").flat.masses.m[1] == 2 * MASS


@pytest.mark.parametrize("args, message", [
    (["--mass", "0", "--length", "1"], "--mass must be a positive finite number"),
    (["--mass", "1", "--length", "-2"], "--length must be a positive finite number"),
    (["--mass", "1", "--length", "1", "--spl", "60"], "--spl and --area go together"),
    (["--mass", "1", "--length", "1", "--spl", "60", "--area", "0"], "--area must be"),
])
def test_bad_scales_are_user_errors(tmp_path, args, message) -> None:
    (tmp_path / "n.spr").write_text(NET.replace("Fa a in(0) gain=2\n", ""))
    res = invoke(tmp_path / "n.spr", *args, "-o", tmp_path / "out.spr")
    assert res.exit_code == 1 and message in res.output and "Traceback" not in res.output
    assert not list(tmp_path.glob("*out.spr*"))
