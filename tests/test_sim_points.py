"""Simulating the points of a `.step`/`.mc` netlist (springc.sim.points) and their statistics
(springc.sim.stats): every point equals the netlist with its values written in, the points
of one structure share one compiled kernel, the output files carry the points table, the
Monte Carlo moments match the distribution and the first-order prediction the linearised
deviation, and misuse exits 1 with a located message and no output file."""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest
from click.testing import CliRunner
from springc_cli.main import main

import springc
from springc.kernels import loader

# two coupled resonators: a stepped stiffness, a global draw, local (per-element) draws
PAIR = """\
.param k0=30 g={gauss(1, 0.1)} kc={agauss(2, 0.3)}
M1 a m={unif(1, 0.05)} b=0.4
M2 b m={gauss(0.5, 0.02)} b=0.2
K1 a k={k0}
K2 b k=20
C1 a b k={kc}
D1 b l=5
F1 a in gain={g}
F2 b sin(0.3 2) gain=1
.probe x(a) v(b)
.step k0 list 30 45
.mc 3 seed=11
.tran 20m 1
.options method=rk4 substeps=2
"""
REDUCE = ["final:x(a)", "msq:v(b)", "work:in"]


def _inputs(runs: int = 2) -> np.ndarray:
    t = np.arange(51) * 0.02
    return np.stack([[np.sin(2 * np.pi * (1 + r) * t)] for r in range(runs)])


def _written_in(net, i: int) -> str:
    """PAIR with point i's drawn and stepped values written in as numbers (no .step/.mc)."""
    flat = net.points.nets[i]
    m, k, c, f = (a.tolist() for a in (flat.masses.m, flat.springs.k, flat.couplings.k,
                                       flat.forces.gain))
    lines = [line for line in PAIR.splitlines()
             if not line.startswith((".param", ".step", ".mc"))]
    values = {"M1 a m={unif(1, 0.05)}": f"M1 a m={m[0]!r}",
              "M2 b m={gauss(0.5, 0.02)}": f"M2 b m={m[1]!r}",
              "K1 a k={k0}": f"K1 a k={k[0]!r}", "C1 a b k={kc}": f"C1 a b k={c[0]!r}",
              "F1 a in gain={g}": f"F1 a in gain={f[0]!r}"}
    for old, new in values.items():
        lines = [line.replace(old, new) for line in lines]
    return "\n".join(lines) + "\n"


def _close(a: np.ndarray, b: np.ndarray) -> None:
    scale = np.maximum(np.abs(b), 1e-300)
    assert np.all(np.abs(a - b) <= 1e-12 * np.maximum(scale, np.abs(b).max())), \
        np.abs(a - b).max()


@pytest.mark.parametrize("kernel", ["shared", "written-out"])
def test_every_point_equals_its_netlist_written_out(kernel):
    net = springc.load(PAIR)
    res = net.simulate(_inputs(), reduce=REDUCE, kernel=kernel)
    assert len(res.points) == 6 and [p.steps[0][1] for p in res.points] == [30.0] * 3 + [45.0] * 3
    for i in range(6):
        one = springc.load(_written_in(net, i)).simulate(_inputs(), reduce=REDUCE,
                                                         kernel=kernel)
        assert one.points is None
        for name in [*one.probes, *one.reductions]:
            _close(res[name][i], one[name])
    # samples differ (the draws are live) and the same sample draws the same at both steps
    x = res["final:x(a)"]
    assert len({float(v) for v in x[:3, 0]}) == 3
    assert net.points.nets[0].forces.gain[0] == net.points.nets[3].forces.gain[0]


def test_points_of_one_structure_compile_one_kernel(monkeypatch):
    """The six points, work sums included, in the lanes of one call of one kernel (where
    they run point by point, the calls share one kernel too: tests/test_points_lanes.py)."""
    compiles = []
    compile_ = loader.Kernel.compile
    monkeypatch.setattr(loader.Kernel, "compile",
                        lambda self, values: (compiles.append(self.path), compile_(self, values)))
    loader.forget()  # loaded again from the cache: every compile is counted
    res = springc.load(PAIR).simulate(_inputs(), reduce=REDUCE, kernel="shared")
    assert res.info["calls"] == 1 and res.info["per_point"] == []
    assert len(set(compiles)) == 1 and set(res.info["kernels"]) == {str(compiles[0])}


def test_shapes_and_the_points_table(tmp_path):
    net = springc.load(PAIR)
    res = net.simulate(_inputs(), reduce=REDUCE, kernel="shared")
    assert res["x(a)"].shape == (6, 2, 51) and res["work:in"].shape == (6, 2)
    res.save(tmp_path / "o.npz")
    with np.load(tmp_path / "o.npz") as z:
        assert z["x(a)"].shape == (6, 2, 51) and z["msq:v(b)"].shape == (6, 2)
        assert z["points_k0"].tolist() == [30, 30, 30, 45, 45, 45]
        assert z["points_sample"].tolist() == [0, 1, 2, 0, 1, 2]
        assert z["points_seed"].tolist() == [11] * 6
        np.testing.assert_array_equal(z["final:x(a)"], res["final:x(a)"])
    res.save(tmp_path / "o.csv")
    with open(tmp_path / "o.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == ["point", "k0", "sample", "seed", "run", "quantity", "t", "value"]
    assert len(rows) == 6 * 2 * (2 * 51 + 3)
    last = [r for r in rows if r["point"] == "4" and r["run"] == "run1"
            and r["quantity"] == "work:in"]
    assert (last[0]["k0"], last[0]["sample"]) == ("45.0", "1")
    assert float(last[0]["value"]) == res["work:in"][4, 1]
    ds = res.to_xarray()
    assert ds["x(a)"].dims == ("point", "run", "time") and ds.sizes["point"] == 6
    assert ds["k0"].values.tolist() == [30, 30, 30, 45, 45, 45]
    assert ds["sample"].values.tolist() == [0, 1, 2, 0, 1, 2]


def test_without_points_the_shapes_stay():
    text = "\n".join(line for line in PAIR.splitlines()
                     if not line.startswith((".step", ".mc"))) + "\n"
    res = springc.load(text).simulate(_inputs(), reduce=REDUCE, kernel="shared")
    assert res.points is None
    assert res["x(a)"].shape == (2, 51) and res["work:in"].shape == (2,)
    assert res.to_xarray()["x(a)"].shape == (1, 2, 51)


# --- statistics ---------------------------------------------------------------------------

N = 200
# critically damped (omega 2, b = 2 sqrt(k m)) and settled by t = 20 s (e^-40): x = g / k
STATIC = """\
.param g={{gauss(1, 0.1)}} k={k}
M1 a m={{unif(1, 0.01)}} b=4
K1 a k={{k}}
F1 a step(1 0) gain={{g}}
.mc {n} seed=3
.tran 50m 20
.options method=rk4 substeps=1
"""


def _se(sd: float, n: int) -> tuple[float, float]:
    """Standard errors of a normal sample's mean and deviation."""
    return sd / math.sqrt(n), sd / math.sqrt(2 * (n - 1))


def test_statistics_of_a_linear_reduction():
    # x = g / 4 with g ~ N(1, 0.1): exactly normal, mean 0.25, deviation 0.025; the
    # per-element mass draw leaves a static displacement alone
    res = springc.load(STATIC.format(k="4", n=N)).simulate(reduce=["final:x(a)"],
                                                            kernel="shared")
    report = res.stats()
    (row,) = report.rows
    se_mean, se_sd = _se(0.025, N)
    assert abs(row.mean - 0.25) < 3 * se_mean and abs(row.std - 0.025) < 3 * se_sd
    assert row.quantiles[0] < row.quantiles[1] < row.quantiles[2]
    assert row.samples.min() <= row.quantiles[0] and row.quantiles[2] <= row.samples.max()
    # linear in g: the first-order prediction is the exact deviation
    assert report.sigmas == pytest.approx({"g": 0.1})
    assert row.nominal == pytest.approx(0.25, rel=1e-12)
    assert row.predicted_std == pytest.approx(0.025, rel=1e-10)
    assert report.local and "local" in report.text()


def test_first_order_prediction_of_a_nonlinear_reduction():
    # x = g / k with k ~ N(4, 0.08): linearised, var = (sigma_g / k)^2 + (g sigma_k / k^2)^2
    res = springc.load(STATIC.format(k="{gauss(4, 0.02)}", n=N)).simulate(
        reduce=["final:x(a)"], kernel="shared")
    report = res.stats()
    (row,) = report.rows
    linear = math.hypot(0.1 / 4, 0.08 / 16)
    assert report.sigmas == pytest.approx({"g": 0.1, "k": 0.08})
    assert row.predicted_std == pytest.approx(linear, rel=1e-10)
    se_mean, se_sd = _se(linear, N)
    assert abs(row.mean - 0.25) < 3 * se_mean + 0.25 * 0.02**2  # + the 1/k bias
    assert abs(row.std - linear) < 3 * se_sd


# --- the command line -----------------------------------------------------------------------


def _sim(tmp_path, text: str, *args: str):
    path = tmp_path / "n.spr"
    path.write_text(text)
    out = tmp_path / "o.npz"
    result = CliRunner().invoke(main, ["sim", str(path), "-o", str(out), *args])
    return result, out


def test_cli_stats_prints_the_table_and_plots_the_histograms(tmp_path):
    # 32 samples: the 32-lane kernel of the library tests' 200
    result, out = _sim(tmp_path, STATIC.format(k="4", n=32), "--reduce", "final:x(a)",
                       "--stats", "--kernel", "shared", "--plot", str(tmp_path / "h.png"))
    assert result.exit_code == 0, result.output
    assert "std(pred)" in result.output and "g (sigma 0.1)" in result.output
    assert "32 point(s) x 1 run(s)" in result.output
    assert out.exists() and (tmp_path / "h.png").stat().st_size > 0
    with np.load(out) as z:
        assert z["final:x(a)"].shape == (32, 1) and z["points_sample"].tolist() == [*range(32)]


@pytest.mark.parametrize("text, args, message", [
    (STATIC.format(k="4", n=5), ["--stats"], "--stats needs --reduce"),
    (STATIC.format(k="4", n=5).replace(".mc 5 seed=3\n", ""),
     ["--stats", "--reduce", "final:x(a)"], "has no .mc line"),
    (".param m0={gauss(1, 0.8)}\nM1 a m={m0}\nK1 a k=1\n.mc 50 seed=2\n.tran 10m 1\n",
     [], "n.spr:2:1: error: M1: mass m=-0.905171 must be > 0 at point 34 of 50 "
         "(sample 34, seed 2)"),
    (".param k0=1\nM1 a m=1 b=0.1\nK1 a k={k0}\n.step k0 list 1 1e6\n.tran 10m 1\n"
     ".options method=rk4 substeps=1\n", [], "at point 1 of 2 (k0=1e+06)"),
    (".param ts=10m\nM1 a m=1 b=0.1\nK1 a k=1\n.step ts list 10m 20m\n.tran {ts} 1\n"
     ".options method=rk4 substeps=1\n", [],
     "n.spr:5:1: error: the .tran of point 1 of 2 (ts=0.02) differs from point 0's"),
])
def test_cli_refuses_with_a_located_message_and_no_output(tmp_path, text, args, message):
    result, out = _sim(tmp_path, text, *args)
    assert result.exit_code == 1, result.output
    assert message in result.output and "Traceback" not in result.output
    assert not out.exists()


def test_cli_memory_check_counts_the_points(tmp_path, monkeypatch):
    from springc.sim import execute

    # one point's records (1 probe x 1 run x 10,001 samples) fit; 50 points' do not
    monkeypatch.setattr(execute, "available_memory", lambda: 2_000_000)
    text = ".param m0={gauss(1, 0.01)}\nM1 a m={m0}\nK1 a k=1\n.probe x(a)\n.mc 50\n" \
           ".tran 1m 10\n.options method=rk4 substeps=1\n"
    result, out = _sim(tmp_path, text)
    assert result.exit_code == 1, result.output
    assert "records would take" in result.output and "50 point(s) x 1 run(s)" in result.output
    assert not out.exists()
