"""What a notebook gets from a result: `Result`, `AcFamily` (and, in their own test files,
`AcResult` and `NoiseResult`) draw into a caller's matplotlib Axes and become xarray Datasets
whose variables carry their SI units; neither library is imported before it is asked for."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from matplotlib.figure import Figure

import springc
from springc.sim.results import units

PNG = b"\x89PNG\r\n\x1a\n"
M, B, K, G = 1.0, 0.5, 100.0, 2.0
OSC = f"""M1 a m={M} b={B}
K1 a k={K}
F1 a step(1 0) gain={G}
.probe x(a) v(a)
.tran 10m 2
"""
REDUCE = ["final:x(a)", "final:v(a)", "msq:x(a)", "msq:v(a):0.5:2", "work:in",
          "dissipated:all", "energy", "loss:M1"]


@pytest.fixture(scope="module")
def res():
    return springc.load(OSC).simulate(reduce=REDUCE, method="rk4", substeps=4)


@pytest.mark.parametrize("name, unit", [
    ("x(X1.out)", "m"), ("v(a)", "m/s"), ("final:x(a)", "m"), ("final:v(a)", "m/s"),
    ("msq:x(a)", "m^2"), ("msq:v(a):0.5:2", "m^2/s^2"), ("work:in", "J"), ("work:F1", "J"),
    ("dissipated:all", "J"), ("dissipated:B3", "J"), ("energy", "J"), ("loss:M1", "dB"),
    ("gram:0.1:a,b", "m^2 s"), ("phi", None), ("x", None), ("energy:x", None),
    ("work", None),
])
def test_units_of_every_probe_and_reduction_kind(name, unit):
    assert units(name) == unit


def test_to_xarray_values_are_the_arrays_with_their_units(res):
    ds = res.to_xarray()
    assert ds["time"].attrs["units"] == "s"
    np.testing.assert_array_equal(ds["time"], res.t)
    for name in ("x(a)", "v(a)", *REDUCE):
        np.testing.assert_array_equal(ds[name].values[0], res[name])
        assert ds[name].attrs["units"] == units(name)
    # the joules agree with each other: the input work is dissipated or still stored
    work, dissipated, energy = (ds[k].item() for k in ("work:in", "dissipated:all", "energy"))
    assert work == pytest.approx(dissipated + energy, rel=1e-6)
    # after 2 s the oscillator has settled near x = G / K, v = 0 (damping time 2 M / B = 4 s
    # leaves e^-0.5 of the swing: only the sign and scale are checked)
    assert 0 < ds["final:x(a)"].item() < 2 * G / K


def test_plot_draws_every_probe_into_one_given_axes(res, tmp_path):
    ax = Figure().subplots()
    assert res.plot(tmp_path / "r.png", ax=ax) is ax
    assert [line.get_label() for line in ax.lines] == ["x(a) run0", "v(a) run0"]
    np.testing.assert_array_equal(ax.lines[0].get_xdata(), res.t)
    np.testing.assert_array_equal(ax.lines[0].get_ydata(), res["x(a)"][0])
    np.testing.assert_array_equal(ax.lines[1].get_ydata(), res["v(a)"][0])
    assert ax.get_xlabel() == "t (s)"
    assert (tmp_path / "r.png").read_bytes()[:8] == PNG


def test_plot_draws_one_probe_per_given_axes_or_makes_a_figure(res):
    top, bottom = Figure().subplots(2)
    assert res.plot(ax=[top, bottom]) == [top, bottom]
    np.testing.assert_array_equal(top.lines[0].get_ydata(), res["x(a)"][0])
    np.testing.assert_array_equal(bottom.lines[0].get_ydata(), res["v(a)"][0])
    assert (top.get_ylabel(), bottom.get_ylabel()) == ("x(a)", "v(a)")
    with pytest.raises(ValueError, match="ax: an Axes or up to 2 of them, not 3"):
        res.plot(ax=Figure().subplots(3))
    fig = res.plot()
    assert [a.get_ylabel() for a in fig.axes] == ["x(a)", "v(a)"]
    np.testing.assert_array_equal(fig.axes[1].lines[0].get_ydata(), res["v(a)"][0])


FAMILY = f"""M1 a m={M} b={B}
K1 a k={{k0}}
F1 a in(0) gain={G}
.param k0=1
.step k0 list 100 400
.ac a 0.1 100 points=30
"""


def test_ac_family_to_xarray_and_plot():
    fam = springc.load(FAMILY).ac()
    ds = fam.to_xarray()
    assert ds["h"].dims == ("point", "f") and ds["k0"].values.tolist() == [100, 400]
    assert ds["point"].values.tolist() == [0, 1]
    np.testing.assert_array_equal(ds["f"], fam.f_hz)
    np.testing.assert_array_equal(ds["h"], fam.h)
    w = 2 * np.pi * fam.f_hz
    for i, k in enumerate((100.0, 400.0)):  # each point is its own driven oscillator
        np.testing.assert_allclose(ds["h"][i], G / (k - w**2 * M + 1j * w * B), rtol=1e-9)
    assert [ds[v].attrs["units"] for v in ("h", "mag", "phase", "f")] == ["m", "m", "rad",
                                                                           "Hz"]
    ax = Figure().subplots()
    assert fam.plot(ax=ax) is ax and len(ax.lines) == 2
    np.testing.assert_array_equal(ax.lines[1].get_xdata(), fam.f_hz)
    np.testing.assert_array_equal(ax.lines[1].get_ydata(), fam.mag[1])
    top, bottom = fam.plot().axes
    np.testing.assert_array_equal(bottom.lines[0].get_ydata(), fam.phase[0])


def test_results_import_neither_matplotlib_nor_xarray():
    code = ("import sys, springc.api, springc.analyses.ac, springc.analyses.noise, "
            "springc.analyses.family, springc.sim.results, springc.kws.evaluation.api; "
            "print([m for m in ('matplotlib', 'xarray') if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "[]"
