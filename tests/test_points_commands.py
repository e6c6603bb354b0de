"""`ac`, `modes`, `grad` and `export` at every `.step`/`.mc` point (springc.analyses.family,
springc.grad.gradient.at_points, the commands in cli/): each point's curve, mode table,
gradient and circuit against the netlist with that point's values written in."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from click.testing import CliRunner
from springc_cli.main import main

import springc
from springc.errors import UsageError
from springc.grad import gradient
from springc.grad.params import ParamNetlist, coefficients
from springc.lang.draws import Sample
from reference_nets import GRAD_NETLIST

# two masses, a stepped stiffness, a global and two local draws: 3 steps x 2 samples
NET = """* a driven pair under spread
.param k0=1 g={gauss(1, 0.05)}
M1 a m={unif(1, 0.05)} b=0.1
M2 b m=2 b={agauss(0.2, 0.01)}
K1 a k={k0 * g}
C1 a b k={gauss(3, 0.1)}
F1 a in(0) gain=1
.probe x(a)
.tran 10m 1
.step k0 list 1 4 9
.mc 2 seed=5
"""
COUNT = 6


def written_in(net) -> str:
    """The point's netlist with every coefficient written as a number (no .step, no .mc)."""
    (m1, m2), (b1, b2) = net.masses.m.tolist(), net.masses.b.tolist()
    k, c = float(net.springs.k[0]), float(net.couplings.k[0])
    return (f"M1 a m={m1!r} b={b1!r}\nM2 b m={m2!r} b={b2!r}\nK1 a k={k!r}\nC1 a b k={c!r}\n"
            "F1 a in(0) gain=1\n.probe x(a)\n.tran 10m 1\n")


@pytest.fixture(scope="module")
def pop():
    return springc.load(NET)


def rel(a, b) -> float:
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b)) / np.abs(np.asarray(b))))


def test_the_points_draw_distinct_netlists(pop):
    nets = pop.points.nets
    assert len(nets) == COUNT and len({written_in(n) for n in nets}) == COUNT


def test_every_points_response_is_its_written_in_netlists(pop):
    fam = pop.ac("b", points=40)
    assert fam.h.shape == (COUNT, 40) and len(fam) == COUNT
    for i, net in enumerate(pop.points.nets):
        one = springc.load(written_in(net)).ac("b", fmin=fam.f_hz[0], fmax=fam.f_hz[-1],
                                               points=40)
        assert rel(fam.h[i], one.h) < 1e-12
        assert np.array_equal(fam[i].h, fam.h[i])


def test_the_grid_covers_every_points_band(pop):
    fam = pop.ac("a")
    for net in pop.points.nets:
        band = springc.load(written_in(net)).modes()["modes"]
        freqs = [m["freq_hz"] for m in band]
        assert fam.f_hz[0] <= min(freqs) / 10 * (1 + 1e-12)
        assert fam.f_hz[-1] >= max(freqs) * 10 * (1 - 1e-12)


def test_every_points_modes_are_its_written_in_netlists(pop):
    report = pop.modes()
    assert [r["point"]["index"] for r in report["points"]] == list(range(COUNT))
    for row, net in zip(report["points"], pop.points.nets):
        one = springc.load(written_in(net)).modes()
        got = [m["freq_hz"] for m in row["modes"]]
        assert rel(got, [m["freq_hz"] for m in one["modes"]]) < 1e-12
        assert rel([m["damping_rate"] for m in row["modes"]],
                   [m["damping_rate"] for m in one["modes"]]) < 1e-12


def invoke(*args) -> str:
    res = CliRunner().invoke(main, [str(a) for a in args])
    assert res.exit_code == 0, res.output
    return res.output


def test_ac_command_writes_the_points_table_and_the_family_plot(pop, tmp_path):
    (tmp_path / "pop.spr").write_text(NET)
    out = invoke("ac", tmp_path / "pop.spr", "--node", "b", "--points", "12", "-o",
                 tmp_path / "ac.csv", "--plot", tmp_path / "ac.png")
    assert f"{COUNT} point(s) x 12 frequencies" in out
    rows = list(csv.DictReader((tmp_path / "ac.csv").open()))
    assert list(rows[0]) == ["point", "k0", "sample", "seed", "f_hz", "mag", "phase_rad"]
    assert len(rows) == COUNT * 12
    fam = pop.ac("b", points=12)
    for p, point in enumerate(fam.points):
        mine = rows[12 * p:12 * (p + 1)]
        assert {(r["point"], r["k0"], r["sample"], r["seed"]) for r in mine} == {
            (str(p), repr(dict(point.steps)["k0"]), str(point.sample), "5")}
        assert [float(r["mag"]) for r in mine] == fam.mag[p].tolist()
        assert [float(r["phase_rad"]) for r in mine] == fam.phase[p].tolist()
    assert (tmp_path / "ac.png").read_bytes()[:4] == b"\x89PNG"


def test_modes_command_gives_a_table_per_point(pop, tmp_path):
    (tmp_path / "pop.spr").write_text(NET)
    report = json.loads(invoke("modes", tmp_path / "pop.spr", "--json"))
    first = report["points"][3]
    assert first["point"] == {"index": 3, "steps": {"k0": 4.0}, "sample": 1, "seed": 5}
    assert first["modes"] == pop.modes()["points"][3]["modes"]
    text = invoke("modes", tmp_path / "pop.spr", "--plot", tmp_path / "m.png")
    assert text.count("== point ") == COUNT and "point 5 of 6 (k0=9, sample 1, seed 5)" in text
    assert (tmp_path / "m.png").read_bytes()[:4] == b"\x89PNG"


def test_export_writes_one_circuit_per_point(pop, tmp_path):
    text = NET.replace("F1 a in(0) gain=1", "F1 a step(1 0)")
    (tmp_path / "pop.spr").write_text(text)
    invoke("export", tmp_path / "pop.spr", "--spice", "-o", tmp_path / "out.cir")
    files = sorted(tmp_path.glob("out.p*.cir"))
    assert [f.name for f in files] == [f"out.p{i}.cir" for i in range(COUNT)]
    assert not (tmp_path / "out.cir").exists()
    for i, net in enumerate(springc.load(text).points.nets):
        one = springc.load(written_in(net).replace("in(0) gain=1", "step(1 0)"))
        body = [s for s in one.export_spice().splitlines() if not s.startswith("*")]
        got = files[i].read_text().splitlines()
        assert got[0].startswith(f"* point {i} of {COUNT} (k0=")
        assert [s for s in got if not s.startswith("*")] == body


def test_export_refuses_compare_with_points(tmp_path):
    (tmp_path / "pop.spr").write_text(NET)
    res = CliRunner().invoke(main, ["export", str(tmp_path / "pop.spr"), "--spice",
                                    "--compare", "-o", str(tmp_path / "o.cir")])
    assert res.exit_code == 1 and "--compare runs one circuit" in res.output
    assert not list(tmp_path.glob("o*.cir"))


# every random function, a nested draw, a drawn parameter and a drawn subcircuit default and
# override, all with arguments that depend on k0: their derivatives hold each draw's unit
# deviate fixed
SPREAD = """* spread
.param k0=2 g={gauss(k0, 0.05)} h={agauss(k0, 0.1*k0, 2)}
.subckt cell n kc={gauss(3*k0, 0.1)}
K1 n k={kc + aunif(k0, 0.5)}
.ends
M1 a m={unif(k0, 0.05)} b={aunif(0.2*k0, 0.01*k0)}
M2 b m=2 b=0.1
K1 a k={g * gauss(3*k0, 0.1) + h}
C1 a b k={gauss(gauss(k0, 0.2), 0.1)}
X1 a cell
X2 b cell kc={unif(k0**2, 0.2)}
.mc 4 seed=5
"""


def test_coefficient_derivatives_at_each_sample_are_central_differences():
    pn = ParamNetlist.from_text(SPREAD)
    h = 1e-6
    for index in range(4):
        sample = Sample(index, 5)
        jac = pn.jacobian({"k0": 2.0}, ["k0"], sample)["k0"]
        up = coefficients(pn.netlist({"k0": 2.0 + h}, sample))
        down = coefficients(pn.netlist({"k0": 2.0 - h}, sample))
        moved = 0
        for key, d in jac.items():
            fd = (up[key] - down[key]) / (2 * h)
            assert d == pytest.approx(fd, rel=1e-7, abs=1e-9), (index, key)
            moved += int(np.count_nonzero(d))
        assert moved == 6  # m and b of M1, K1 and both cells' springs, the coupling
    # outside a sample the derivative is the nominal value's: d unif(k0, .) / d k0 = 1
    assert pn.jacobian({"k0": 2.0}, ["k0"])["k0"][("masses", "m")][0] == 1.0


# tests/test_grad_cli.py's netlist (`reference_nets.GRAD_NETLIST`), its stiffnesses drawn (its
# gradient kernel is shared with that file's)
DRAWN = (GRAD_NETLIST.replace("k={k0}", "k={gauss(k0, 0.05)}")
         .replace("k={2*k0}", "k={unif(2*k0, 0.1)}") + ".mc 3 seed=3\n")


def test_grad_at_each_monte_carlo_sample_is_the_central_difference_there(tmp_path):
    (tmp_path / "d.spr").write_text(DRAWN)
    rows = json.loads(invoke("grad", tmp_path / "d.spr", "--of", "final:x(a)", "--wrt", "k0",
                             "--json"))
    pn = ParamNetlist.from_text(DRAWN)
    assert [r["point"]["sample"] for r in rows] == [0, 1, 2]
    for row in rows:
        sample = Sample(row["point"]["sample"], 3)
        value = lambda k0: float(gradient(pn, "final:x(a)", ["k0"], values={"k0": k0},  # noqa: E731
                                          sample=sample).values["final:x(a)"][0])
        h = 4e5 * 1e-4
        fd = (value(4e5 + h) - value(4e5 - h)) / (2 * h)
        assert row["value"] == pytest.approx(value(4e5), rel=1e-12)
        assert row["grad"]["k0"] == pytest.approx(fd, rel=1e-5)
    assert len({r["grad"]["k0"] for r in rows}) == 3


def test_noise_refuses_points_at_the_step_line(pop):
    with pytest.raises(UsageError) as info:
        pop.noise("a", temp=300)
    assert info.value.diagnostic.loc.line == 10


# tests/test_grad_cli.py's netlist, stepped: its gradient kernel is shared with that file's
STEPPED = GRAD_NETLIST + ".step k0 list 4e5 5e5\n"


def test_grad_at_every_step_point_is_the_written_in_netlists(tmp_path):
    (tmp_path / "s.spr").write_text(STEPPED)
    rows = json.loads(invoke("grad", tmp_path / "s.spr", "--of", "final:x(a)", "--wrt", "k0",
                             "--wrt", "l0", "--json"))
    assert [r["point"]["steps"] for r in rows] == [{"k0": 4e5}, {"k0": 5e5}]
    for row, k0 in zip(rows, (4e5, 5e5)):
        one = springc.load(STEPPED.replace("k0=4e5", f"k0={k0!r}")
                           .replace(".step k0 list 4e5 5e5\n", ""))
        g = one.grad("final:x(a)", ["k0", "l0"])
        assert row["value"] == pytest.approx(float(g.values["final:x(a)"][0]), rel=1e-12)
        assert [row["grad"]["k0"], row["grad"]["l0"]] == pytest.approx(g.grad[0], rel=1e-12)
    assert rows[0]["grad"]["k0"] != rows[1]["grad"]["k0"]
