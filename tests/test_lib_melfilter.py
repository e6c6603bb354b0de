"""netlists/lib/melfilter.spr through `springc ac`: the two-mode filter realises the paper's
Eq. (filter-response), the single-mode one a Lorentzian (paper Sec. III.A, Fig. 4)."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner
from springc_cli.main import main

from springc.analyses.ac import response
from springc.design.filters import mel_edges, single_mode_response, two_mode_response
from springc.design.melbank import design_melbank, melbank_text
from springc.lang import load_text
from springc.check import check

FA, DELTA, ALPHA, GAIN = 1234.5, 1.17, 650.0, 3.7e-4


def test_ac_of_the_two_mode_filter_is_eq_filter_response(tmp_path):
    """`springc ac` on melfilter's output mass equals gain * Eq. (filter-response) to 1e-6."""
    net = tmp_path / "f.spr"
    net.write_text(f'.include "melfilter.spr"\nXf out melfilter fa={FA} delta={DELTA} '
                   f"alpha={ALPHA} ch=0 gain={GAIN}\n")
    csv = tmp_path / "h.csv"
    res = CliRunner().invoke(main, ["ac", str(net), "--node", "out", "--fmin", "10", "--fmax",
                                    "20000", "--points", "300", "-o", str(csv)])
    assert res.exit_code == 0, res.output
    data = np.genfromtxt(csv, delimiter=",", names=True)
    h = data["mag"] * np.exp(1j * data["phase_rad"])
    want = GAIN * two_mode_response(data["f_hz"], FA, DELTA, ALPHA)
    assert np.abs(h / want - 1).max() < 1e-6


def test_output_is_the_b_mass_the_other_mass_carries_the_sum():
    """x_out = gain H (zero at DC); x_a = gain (mode a + mode b), which is not."""
    net = load_text(f'.include "melfilter.spr"\nXf out melfilter fa={FA} delta={DELTA} '
                    f"alpha={ALPHA} ch=0 gain={GAIN}\n")
    f = np.geomspace(1, 1e4, 50)
    w, wa = 2 * np.pi * f, 2 * np.pi * FA
    wb = DELTA * wa

    def mode(w0):
        return ALPHA * w0**2 / (w0**2 - w**2 + 1j * ALPHA * w)

    got = response(check(net), "Xf.a", f).h
    assert got == pytest.approx(GAIN * (mode(wa) + mode(wb)), rel=1e-9)
    dc = np.array([1e-3])
    out, a = response(check(net), "out", dc).h[0], response(check(net), "Xf.a", dc).h[0]
    assert abs(out) < 1e-5 * abs(a)  # near DC the two modes cancel only on the output mass
    assert out == pytest.approx(GAIN * two_mode_response(dc, FA, DELTA, ALPHA)[0], rel=1e-6)


def test_single_mode_filter_is_a_lorentzian():
    net = load_text('.include "melfilter.spr"\nXs out melfilter1 f0=800 alpha=500 ch=2 '
                    "gain=0.5\n")
    f = np.geomspace(10, 1e4, 100)
    got = response(check(net), "out", f, channel=2).h
    assert got == pytest.approx(0.5 * single_mode_response(f, 800.0, 500.0), rel=1e-9)


def test_eight_bin_melbank_netlist_peaks_at_the_mel_centres(tmp_path):
    """The designed 8-bin filterbank, compiled: each output's |H| (from ac, 0.05% frequency
    steps) peaks within 5% of its Mel centre with height 1, and matches the fitted filter."""
    bank = design_melbank(8)
    (tmp_path / "bank.spr").write_text(melbank_text(bank))
    outs = " ".join(f"o{i}" for i in range(8))
    net = load_text(f'.include "bank.spr"\nXb {outs} melbank ch=0\n', str(tmp_path / "t.spr"))
    for i, centre in enumerate(mel_edges(8)[1:-1]):
        f = centre * np.geomspace(0.7, 1.4, 1400)
        h = response(check(net), f"o{i}", f).h
        assert f[np.argmax(np.abs(h))] == pytest.approx(centre, rel=0.05)
        assert np.abs(h).max() == pytest.approx(1.0, abs=1e-6)
        assert h == pytest.approx(bank.two_mode[i].response(f), rel=1e-6)
