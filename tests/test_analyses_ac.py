"""Frequency response of the linearisation against closed forms and the paper's two-mode
filter response (Eq. filter-response)."""

from __future__ import annotations

import numpy as np
import pytest

from springc.analyses import ac
from springc.design.filters import two_mode_response
from springc.errors import UsageError
from springc.lang.ir import IRBuilder, Source
from springc.lang import load_text
from springc.check import check

SPEC_FILTER = """\
.title two-mode band-pass filter
.param wa={2*pi*1000} delta=1.1 alpha=400
Ma xa m=1 b={alpha}
Mb xb m=1 b={alpha}
Ka xa k={wa**2}
Kb xb k={wa**2}
Cab xa xb k={(delta**2 - 1) * wa**2 / 2}
Fa xa in(0) gain={alpha * (1 + delta**2) * wa**2}
Fb xb in(0) gain={alpha * (1 - delta**2) * wa**2}
.ac xb 100 10k points=301
"""


def _oscillator(m=2.0, b=0.6, k=50.0, gain=3.0):
    net = IRBuilder()
    net.mass("M", "x", m, b)
    net.spring("K", "x", k)
    net.force("F", "x", Source("in", channel=0), gain)
    net.force("G", "x", Source("in", channel=1), 100.0)  # another channel: must not count
    net.force("S", "x", Source("sin", (1.0, 5.0)), 7.0)  # not an input at all
    return net.finish()


def test_driven_damped_oscillator() -> None:
    m, b, k, g = 2.0, 0.6, 50.0, 3.0
    f = np.geomspace(0.01, 100, 500)
    result = ac.response(check(_oscillator(m, b, k, g)), "x", f)
    w = 2 * np.pi * f
    exact = g / (k - w**2 * m + 1j * w * b)
    np.testing.assert_allclose(result.mag, np.abs(exact), rtol=1e-9)
    np.testing.assert_allclose(result.phase, np.angle(exact), atol=1e-9)
    # Below resonance the response is in phase with the force, above it lags by ~pi.
    assert result.phase[0] == pytest.approx(0, abs=1e-3)
    assert result.phase[-1] == pytest.approx(-np.pi, abs=1e-2)


def test_input_channel_selects_forces() -> None:
    f = np.array([1.0, 2.0])
    net = _oscillator()
    checked = check(net)
    ratio = ac.response(checked, "x", f, channel=1).h / ac.response(checked, "x", f, channel=0).h
    np.testing.assert_allclose(ratio, 100.0 / 3.0, rtol=1e-12)
    with pytest.raises(UsageError, match=r"no F element is driven by in\(2\)"):
        ac.response(check(net), "x", f, channel=2)


def test_two_mode_filter_matches_the_paper() -> None:
    """The spec's filter: x_b = S - D with S, D the symmetric and antisymmetric modes, which
    is exactly `two_mode_response(f, 1000, 1.1, 400)`."""
    net = load_text(SPEC_FILTER, "filter.spr")
    sweep = ac.default_sweep(net)
    assert (sweep.fmin, sweep.fmax, sweep.points) == (100, 10_000, 301)
    f = sweep.frequencies()
    result = ac.response(check(net), "xb", f)
    expected = two_mode_response(f, 1000.0, 1.1, 400.0)
    np.testing.assert_allclose(result.h, expected, rtol=1e-6)


def test_sparse_solver_agrees_with_dense(monkeypatch) -> None:
    net = load_text(SPEC_FILTER, "filter.spr")
    f = np.geomspace(200, 5000, 40)
    dense = ac.response(check(net), "xa", f).h
    monkeypatch.setattr(ac, "DENSE_MAX", 0)
    np.testing.assert_allclose(ac.response(check(net), "xa", f).h, dense, rtol=1e-10)


def test_unknown_node_suggests_close_names() -> None:
    net = load_text(SPEC_FILTER, "filter.spr")
    with pytest.raises(UsageError) as info:
        ac.response(check(net), "xc", np.array([1.0]))
    assert "unknown node 'xc'" in info.value.format() and "did you mean" in info.value.format()


def test_bad_sweep_is_a_usage_error() -> None:
    with pytest.raises(UsageError, match="fmin < fmax"):
        ac.Sweep(100.0, 10.0, 5).frequencies()


def test_csv_and_plot_are_written_atomically(tmp_path) -> None:
    f = np.geomspace(1, 10, 5)
    result = ac.response(check(_oscillator()), "x", f)
    ac.write_csv(result, tmp_path / "h.csv")
    ac.plot(result, tmp_path / "h.png")
    lines = (tmp_path / "h.csv").read_text().splitlines()
    assert lines[0] == "f_hz,mag,phase_rad"
    table = np.loadtxt(tmp_path / "h.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(table, np.column_stack([f, result.mag, result.phase]), rtol=1e-15)
    assert (tmp_path / "h.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["h.csv", "h.png"]


def test_plot_draws_into_given_axes_and_saves_their_figure(tmp_path) -> None:
    from matplotlib.figure import Figure

    f = np.geomspace(1, 10, 5)
    result = ac.response(check(_oscillator()), "x", f)
    top, bottom = Figure().subplots(2)
    assert result.plot(tmp_path / "h.png", ax=(top, bottom)) == (top, bottom)
    np.testing.assert_array_equal(top.lines[0].get_xdata(), f)
    np.testing.assert_array_equal(top.lines[0].get_ydata(), result.mag)
    np.testing.assert_array_equal(bottom.lines[0].get_ydata(), result.phase)
    assert (top.get_yscale(), bottom.get_xscale(), bottom.get_ylabel()) == ("log", "log",
                                                                          "phase (rad)")
    assert (tmp_path / "h.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    alone = Figure().subplots()
    assert result.plot(ax=alone) is alone and len(alone.lines) == 1  # the magnitude only
    with pytest.raises(ValueError, match="up to 2 of them, not 3"):
        result.plot(ax=Figure().subplots(3))
    fig = result.plot()
    np.testing.assert_array_equal(fig.axes[1].lines[0].get_xdata(), f)


def test_to_xarray_is_the_response_with_its_units() -> None:
    m, b, k, g = 2.0, 0.6, 50.0, 3.0
    f = np.geomspace(0.1, 10, 7)
    ds = ac.response(check(_oscillator(m, b, k, g)), "x", f).to_xarray()
    w = 2 * np.pi * f
    np.testing.assert_array_equal(ds["f"], f)
    np.testing.assert_allclose(ds["h"], g / (k - w**2 * m + 1j * w * b), rtol=1e-9)
    np.testing.assert_array_equal(ds["mag"], np.abs(ds["h"]))
    np.testing.assert_array_equal(ds["phase"], np.angle(ds["h"]))
    units = {name: ds[name].attrs["units"] for name in ("f", "h", "mag", "phase")}
    assert units == {"f": "Hz", "h": "m", "mag": "m", "phase": "rad"}
    assert ds.attrs == {"node": "x", "input": 0}


def test_default_sweep_spans_the_modes() -> None:
    sweep = ac.default_sweep(_oscillator(m=1.0, b=0.0, k=(2 * np.pi * 50) ** 2))
    assert sweep.fmin == pytest.approx(5.0) and sweep.fmax == pytest.approx(500.0)
