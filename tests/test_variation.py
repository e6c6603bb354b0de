"""`.step`, `.mc` and the random functions (springc.lang.draws, springc.lang.variation,
springc.check.points): the draws' statistics against their distributions, reproducibility
whatever the order or batch, who shares a draw, the order of points, and every misuse refused
by `springc build` with a located message."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import scipy.stats
from click.testing import CliRunner
from springc_cli.main import main

import springc
from springc.check.points import check_points
from springc.lang import draws, parse, variation

N = 10_000


def _variation(text: str) -> variation.Variation:
    return variation.read(parse(text, "<test>"))


def _points(text: str) -> variation.PointSet:
    return _variation(text).point_set()


# --- statistics -----------------------------------------------------------------------------

# func, args, mean, standard deviation, fourth central moment / sigma^4, scipy distribution
CASES = [
    ("gauss", [2.0, 0.05], 2.0, 0.1, 3.0, scipy.stats.norm(2.0, 0.1)),
    ("gauss", [-4.0, 0.3, 3.0], -4.0, 0.4, 3.0, scipy.stats.norm(-4.0, 0.4)),
    ("agauss", [1.0, 0.2], 1.0, 0.2, 3.0, scipy.stats.norm(1.0, 0.2)),
    ("agauss", [0.0, 0.6, 2.0], 0.0, 0.3, 3.0, scipy.stats.norm(0.0, 0.3)),
    ("unif", [5.0, 0.1], 5.0, 0.5 / math.sqrt(3), 1.8, scipy.stats.uniform(4.5, 1.0)),
    ("aunif", [1.0, 0.25], 1.0, 0.25 / math.sqrt(3), 1.8, scipy.stats.uniform(0.75, 0.5)),
]


@pytest.mark.parametrize("func, args, mean, sd, kurtosis, dist", CASES,
                         ids=[f"{c[0]}{c[1]}" for c in CASES])
def test_sample_statistics_match_the_distribution(func, args, mean, sd, kurtosis, dist):
    x = draws.values(func, args, 7, np.arange(N), "X1", "m")
    # standard errors of the mean and of the sample deviation (delta method on s^2)
    se_mean = sd / math.sqrt(N)
    se_sd = math.sqrt((kurtosis - 1) * sd**4 / N) / (2 * sd)
    assert abs(x.mean() - mean) < 3 * se_mean
    assert abs(x.std(ddof=1) - sd) < 3 * se_sd
    assert scipy.stats.kstest(x, dist.cdf).pvalue > 1e-3


def test_uniform_draws_stay_in_their_interval():
    x = draws.values("unif", [-2.0, 0.5], 1, np.arange(N), "", "p")
    assert x.min() >= -3.0 and x.max() <= -1.0
    y = draws.values("aunif", [3.0, 0.5], 1, np.arange(N), "", "p")
    assert y.min() >= 2.5 and y.max() <= 3.5


def test_sites_and_seeds_draw_independently():
    a = draws.values("gauss", [0.0 + 1, 1.0], 3, np.arange(N), "X1", "k")
    b = draws.values("gauss", [0.0 + 1, 1.0], 3, np.arange(N), "X2", "k")
    c = draws.values("gauss", [0.0 + 1, 1.0], 4, np.arange(N), "X1", "k")
    d = draws.values("gauss", [0.0 + 1, 1.0], 3, np.arange(N), "X1", "k", 1)
    for other in (b, c, d):
        assert abs(np.corrcoef(a, other)[0, 1]) < 4 / math.sqrt(N)


# --- reproducibility --------------------------------------------------------------------------

def test_batches_draw_bitwise_the_same():
    whole = draws.values("gauss", [1.0, 0.1], 9, np.arange(512), "X3.M1", "m")
    for size in (1, 7, 256):
        parts = [draws.values("gauss", [1.0, 0.1], 9, np.arange(s, min(s + size, 512)),
                              "X3.M1", "m") for s in range(0, 512, size)]
        assert np.array_equal(np.concatenate(parts), whole)
    backwards = draws.values("gauss", [1.0, 0.1], 9, np.arange(511, -1, -1), "X3.M1", "m")
    assert np.array_equal(backwards[::-1], whole)


MC = """\
.param g={gauss(1, 0.1)} k0=2
.subckt osc a kk={agauss(4, 0.5)}
.param mm={unif(1, 0.2)}
M1 a m={mm} b={aunif(0.1, 0.01)}
K1 a k={kk * g}
.ends
X1 p osc
X2 q osc
C1 p q k={gauss(k0, 0.05)}
.step k0 list 1 2
.mc 5 seed=11
"""


def _coefficients(net) -> np.ndarray:
    return np.concatenate([net.masses.m, net.masses.b, net.springs.k, net.couplings.k])


def test_points_are_the_same_however_they_are_computed():
    var = _variation(MC)
    together = [_coefficients(n) for n in var.point_set().nets]
    points = var.points()
    one_by_one = [_coefficients(var.netlist(p)) for p in points]
    backwards = [_coefficients(var.netlist(p)) for p in reversed(points)][::-1]
    assert len(together) == 10
    for a, b, c in zip(together, one_by_one, backwards):
        assert np.array_equal(a, b) and np.array_equal(a, c)


def test_a_draw_depends_on_its_site_not_on_the_order_of_lines():
    lines = MC.splitlines()
    swapped = "\n".join([lines[0]] + lines[1:6] + [lines[7], lines[6]] + lines[8:]) + "\n"
    a, b = _points(MC), _points(swapped)
    for net_a, net_b in zip(a.nets, b.nets):
        for table in ("masses", "springs"):
            ta, tb = getattr(net_a, table), getattr(net_b, table)
            by_name = dict(zip(tb.names, tb.m if table == "masses" else tb.k))
            values = ta.m if table == "masses" else ta.k
            assert all(by_name[n] == v for n, v in zip(ta.names, values))


def test_element_values_are_the_vectorised_draws_at_their_site():
    ps = _points(MC)
    b = [net.masses.b[0] for net in ps.nets[:5]]  # X1.M1's b= in samples 0..4 at k0=1
    assert np.array_equal(b, draws.values("aunif", [0.1, 0.01], 11, np.arange(5), "X1.M1", "b"))
    kc = [net.couplings.k[0] for net in ps.nets[5:]]  # C1 at k0=2
    assert np.array_equal(kc, draws.values("gauss", [2.0, 0.05], 11, np.arange(5), "C1", "k"))


# --- who shares a draw ----------------------------------------------------------------------

def test_instances_draw_their_own_values_and_share_the_global_ones():
    ps = _points(MC)
    for net in ps.nets:
        m = dict(zip(net.masses.names, net.masses.m))
        assert m["X1.M1"] != m["X2.M1"]  # a subcircuit's own .param: per instance
        kk1 = draws.values("agauss", [4.0, 0.5], 11, [0], "X1", "kk")[0]
        kk2 = draws.values("agauss", [4.0, 0.5], 11, [0], "X2", "kk")[0]
        assert kk1 != kk2
    first = ps.nets[0]
    g = draws.values("gauss", [1.0, 0.1], 11, [0], "", "g")[0]  # the global, once per sample
    kk = [draws.values("agauss", [4.0, 0.5], 11, [0], x, "kk")[0] for x in ("X1", "X2")]
    assert first.springs.k[0] == kk[0] * g and first.springs.k[1] == kk[1] * g


def test_an_override_draws_per_instance_like_a_default():
    text = MC.replace("X2 q osc", "X2 q osc kk={agauss(4, 0.5)}")
    assert np.array_equal(_coefficients(_points(text).nets[3]),
                          _coefficients(_points(MC).nets[3]))


def test_without_mc_every_random_function_is_its_nominal_value():
    net = _variation(MC.replace(".mc 5 seed=11\n", "")).point_set().nets[0]
    assert list(net.masses.m) == [1.0, 1.0] and list(net.masses.b) == [0.1, 0.1]
    assert list(net.springs.k) == [4.0, 4.0] and list(net.couplings.k) == [1.0]


def test_gauss_after_a_force_is_still_the_pulse_source():
    text = ".param g={gauss(2, 0.1)}\nM1 a m=1\nK1 a k=1\nF1 a gauss(1 0.5 0.1) gain={g}\n.mc 3\n"
    ps = _points(text)
    for net in ps.nets:
        assert net.forces.source[0].kind == "gauss" and net.forces.source[0].args == (1, 0.5, 0.1)
    assert len({net.forces.gain[0] for net in ps.nets}) == 3


def test_mc_seed_defaults_to_the_options_seed():
    base = ".param g={gauss(2, 0.1)}\nM1 a m=1\nK1 a k={g}\n.mc 2\n"
    seeded = _points(base + ".options seed=4\n")
    explicit = _points(base.replace(".mc 2", ".mc 2 seed=4"))
    assert [p.seed for p in seeded.points] == [4, 4]
    assert [n.springs.k[0] for n in seeded.nets] == [n.springs.k[0] for n in explicit.nets]
    assert [p.seed for p in _points(base).points] == [0, 0]


# --- .step ----------------------------------------------------------------------------------

BASE = ".param a=1 b=1 c=1\nM1 x m={a}\nK1 x k={b * c}\n"


def test_step_lines_form_their_product_first_line_outermost():
    ps = _points(BASE + ".step a list 1 2\n.step param b 10 30 10\n.mc 2\n")
    steps = [(dict(p.steps)["a"], dict(p.steps)["b"], p.sample) for p in ps.points]
    assert steps == [(a, b, s) for a in (1, 2) for b in (10, 20, 30) for s in (0, 1)]
    assert [net.masses.m[0] for net in ps.nets] == [s[0] for s in steps]
    assert [net.springs.k[0] for net in ps.nets] == [s[1] for s in steps]


@pytest.mark.parametrize("line, values", [
    (".step a list 3 1 2", [3, 1, 2]),
    (".step a 1 2 0.25", [1, 1.25, 1.5, 1.75, 2]),
    (".step a 0 1 0.1", [0.1 * k for k in range(10)] + [1.0]),
    (".step a 5 1 -2", [5, 3, 1]),
    (".step a 1 1.9 0.5", [1, 1.5]),
    (".step a dec 1 100 2", [1, 10**0.5, 10, 10**1.5, 100]),
    (".step dec param a 1 100 2", [1, 10**0.5, 10, 10**1.5, 100]),
    (".step oct param a 1 8 1", [1, 2, 4, 8]),
    (".step param a list 1k 2meg", [1e3, 2e6]),
])
def test_step_spellings(line, values):
    (axis,) = _variation(BASE + line + "\n").axes
    assert np.allclose(axis.values, values, rtol=1e-14, atol=0)
    assert axis.values[-1] == values[-1]


def test_a_point_is_the_netlist_with_its_values_written_in():
    ps = _points(BASE.replace("c=1", "c={2*a}") + ".step a 1 3 1\n")
    for point, net in zip(ps.points, ps.nets):
        a = dict(point.steps)["a"]
        written = variation.read(parse(BASE.replace("a=1", f"a={a!r}").replace(
            "c=1", "c={2*a}"), "<test>")).nominal()
        assert net.text() == written.text()


def test_points_are_grouped_by_structure():
    loop = (".param n=2 k0=1\n.for i 1 {n}\nM{i} x{i} m=1\nK{i} x{i} k={k0}\n.endfor\n")
    assert _points(loop + ".step k0 list 1 2 3\n").groups == ((0, 1, 2),)
    grouped = _points(loop + ".step n list 1 2\n.step k0 list 1 2\n")
    assert grouped.groups == ((0, 1), (2, 3))


# --- checks, build report, API --------------------------------------------------------------

def test_every_point_is_checked_and_build_reports_the_worst(tmp_path):
    path = tmp_path / "osc.spr"
    path.write_text(BASE + ".step b list 1 400 100\n.step c list 1 0.5\n.tran 10m 1\n")
    res = CliRunner().invoke(main, ["build", str(path), "--json"], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    report = json.loads(res.output)
    assert report["points"] == 6 and report["structures"] == 1
    assert report["worst_point"] == {"index": 2, "steps": {"b": 400.0, "c": 1.0},
                                     "sample": None, "seed": None}
    alone = tmp_path / "alone.spr"
    alone.write_text(BASE.replace("b=1", "b=400") + ".tran 10m 1\n")
    single = json.loads(CliRunner().invoke(main, ["build", str(alone), "--json"]).output)
    assert report["dt_max"] == single["dt_max"] and report["omega_max"] == single["omega_max"]
    assert single["points"] == 1 and single["worst_point"] is None
    text = CliRunner().invoke(main, ["build", str(path)]).output
    assert "points      6 (1 structure(s)); worst point 2 of 6 (b=400, c=1), reported below" in text


def test_load_gives_the_checked_points():
    net = springc.load(MC + "\n")
    assert len(net.points) == 10 and len(net.points.checked) == 10
    assert net.points.checked[3].net is net.points.nets[3]
    assert net.flat.masses.m.tolist() == [1.0, 1.0]  # the nominal netlist
    assert len(springc.load(BASE + "\n").points) == 1


def test_check_points_names_the_failing_point():
    ps = _points(".param m0={gauss(1, 0.8)}\nM1 a m={m0}\nK1 a k=1\n.mc 50 seed=2\n")
    with pytest.raises(springc.errors.CheckError) as err:
        check_points(ps)
    bad = next(i for i, net in enumerate(ps.nets) if net.masses.m[0] <= 0)
    assert err.value.message == (f"M1: mass m={ps.nets[bad].masses.m[0]:g} must be > 0 at "
                                 f"point {bad} of 50 (sample {bad}, seed 2)")


# --- misuse ---------------------------------------------------------------------------------

ERRORS = [
    (".step kx list 1 2", "4:7", ".step kx: unknown parameter 'kx'"),
    (".step p list 1 2", "4:7", ".step p: 'p' is not a top-level parameter"),
    (".step a list", "4:1", ".step a list has no values"),
    (".step a 1 2 0", "4:13", ".step a: the increment is zero"),
    (".step a 1 2 -1", "4:13", ".step a: an increment of -1 never reaches 2 from 1"),
    (".step a dec 0 10 5", "4:13", ".step a dec: the start must be > 0, got 0"),
    (".step dec param a -1 10 5", "4:19", ".step a dec: the start must be > 0, got -1"),
    (".step a oct 1 10 0", "4:18", ".step a oct: points must be >= 1, got 0"),
    (".step a oct 10 1 2", "4:16", ".step a oct: the stop 1 is below the start 10"),
    (".step a 0 1 1e-9", "4:13", ".step a has 1000000001 values (more than 10000000)"),
    (".step a list 1\n.step a list 2", "5:1", ".step a given twice"),
    (".step", "4:1", ".step needs a parameter name"),
    (".mc -3", "4:5", "the .mc count must be >= 1, got -3"),
    (".mc 0", "4:5", "the .mc count must be >= 1, got 0"),
    (".mc 2.5", "4:5", "the .mc count must be an integer, got 2.5"),
    (".mc 3 seed=-1", "4:12", "the .mc seed must be an integer >= 0, got -1"),
    (".mc 3 sead=1", "4:7", ".mc has no parameter 'sead'"),
    (".mc 3\n.mc 4", "5:1", "a second .mc"),
    (".subckt s n\nM1 n m=1\n.step a list 1\n.ends", "6:1",
     ".step is only allowed at the top level, not inside a subcircuit"),
    (".subckt s n\nM1 n m=1\n.mc 3\n.ends\nX1 y s", "6:1",
     ".mc is only allowed at the top level, not inside a subcircuit"),
    (".for i 1 2\n.mc 3\n.endfor", "5:1",
     ".mc is only allowed at the top level, not inside a .for loop"),
    ("M2 y m={gauss(1, -0.1)}", "4:9", "gauss(): rvar must be >= 0, got -0.1"),
    ("M2 y m={agauss(1, 0.1, 0)}", "4:9", "agauss(): sigma must be > 0, got 0"),
    ("M2 y m={unif(1, 0.1, 2)}", "4:9", "unif() takes 2 arguments, got 3"),
    ("M2 y m={aunif(1)}", "4:9", "aunif() takes 2 arguments, got 1"),
    (".tran {gauss(1m, 0.1)} 1", "4:8", "gauss() cannot be used in a .tran line"),
    (".for i 1 {unif(2, 0.1)}\nM{i} z{i} m=1\n.endfor", "4:11",
     "unif() cannot be used in a .for bound"),
    (".for i 1 2\n.param w={gauss(1, 0.1)}\nM{i} z{i} m={w}\n.endfor", "5:11",
     "gauss() cannot be used in a .param inside a .for loop"),
    ("F1 x sin({gauss(1, 0.1)} 50)", "4:11", "gauss() cannot be used in a source's arguments"),
    (".step a list 1 0\nK2 x k={1/a}", "5:10", "division by zero at point 1 of 2 (a=0)"),
    (".param m0={gauss(1, 0.8)}\nM2 y m={m0}\n.mc 50 seed=2", "5:1",
     "M2: mass m=-0.905171 must be > 0 at point 34 of 50 (sample 34, seed 2)"),
    (".step b dec 1 1e8 1\n.tran 1m 1\n.options method=rk4", "5:1",
     "time step 0.001 s is unstable for rk4"),
]


@pytest.mark.parametrize("extra, where, message", ERRORS, ids=[e[2][:40] for e in ERRORS])
def test_misuse_is_a_located_error_of_build(tmp_path, extra, where, message):
    path = tmp_path / "bad.spr"
    sub = ".subckt s n p=1\nM1 n m={p}\n.ends\nX9 w s\n" if "'p'" in message else ""
    path.write_text(BASE + extra + "\n" + sub)
    res = CliRunner().invoke(main, ["build", str(path)], catch_exceptions=False)
    assert res.exit_code == 1, res.output
    first = res.output.splitlines()[0]
    assert first.startswith(f"{path}:{where}: error: {message}"), res.output
    assert "Traceback" not in res.output
