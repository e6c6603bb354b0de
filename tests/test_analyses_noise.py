"""`.noise` / `springc noise`: thermal noise at rest against the damped oscillator's closed
form 4 k_B T b / |k - m w^2 + i b w|^2, equipartition (its integral is k_B T / k), and a direct
complex solve per source on a network with dashpots between nodes; user errors through the
command (exit 1, located, no output)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

import springc
from springc.analyses.noise import K_B
from springc_cli.main import main

OSC = "M1 a m=2 b=0.3\nK1 a k=50\n"


def test_oscillator_psd_is_the_closed_form() -> None:
    res = springc.load(OSC + ".noise a 0.01 100 points=400\n.options temp=300\n").noise()
    w = 2 * np.pi * res.f_hz
    exact = 4 * K_B * 300 * 0.3 / np.abs(50 - 2 * w**2 + 0.3j * w) ** 2
    np.testing.assert_allclose(res.psd, exact, rtol=1e-9, atol=0)
    assert list(res.sources) == ["M1"] and res.input_referred is None


def test_the_psd_integrates_to_equipartition() -> None:
    # 1e-7 .. 1e4 Hz leaves out 4 k_B T b / k^2 * 1e-7 Hz and the w^-4 tail: 1e-9 of it
    res = springc.load(OSC).noise("a", temp=77.0, fmin=1e-7, fmax=1e4, points=40000)
    assert res.rms**2 == pytest.approx(K_B * 77.0 / 50, rel=1e-4)


NETWORK = """* three masses, dashpots between nodes and to ground, one driven
M1 a m=1 b=0.2
M2 b m=0.5
M3 c m=2 b=0.1
K1 a k=40
K3 c k=10
C12 a b k=30
C23 b c k=20 a=2
B12 a b b=0.5
B3 c 0 b=0.05
F1 a in(0) gain=3
.noise c 0.05 20 points=60
"""


def test_network_matches_a_direct_solve_per_source() -> None:
    net = springc.load(NETWORK)
    res = net.noise(temp=4.0)
    n, names = net.flat.n, net.nodes
    # C: V = k/(2a) (x_i - a x_j)^2 adds k/a at i, k a at j and -k between them
    lin_k = np.array([[40 + 30, -30, 0], [-30, 30 + 20 / 2, -20], [0, -20, 10 + 20 * 2]])
    lin_m = np.diag([1.0, 0.5, 2.0])
    lin_b = np.array([[0.2 + 0.5, -0.5, 0], [-0.5, 0.5, 0], [0, 0, 0.1 + 0.05]])
    patterns = {"M1": ([1, 0, 0], 0.2), "M3": ([0, 0, 1], 0.1), "B12": ([1, -1, 0], 0.5),
                "B3": ([0, 0, 1], 0.05)}
    out = names.index("c")
    total = np.zeros(len(res.f_hz))
    gain = np.zeros(len(res.f_hz))
    for f, freq in enumerate(res.f_hz):
        w = 2 * np.pi * freq
        g = lin_k - w**2 * lin_m + 1j * w * lin_b
        for name, (d, b) in patterns.items():
            share = 4 * K_B * 4.0 * b * abs(np.linalg.solve(g, np.array(d, complex))[out]) ** 2
            assert res.sources[name][f] == pytest.approx(share, rel=1e-9)
            total[f] += share
        gain[f] = abs(np.linalg.solve(g, np.array([3.0, 0, 0], complex))[out])
    assert n == 3
    np.testing.assert_allclose(res.psd, total, rtol=1e-9)
    np.testing.assert_allclose(res.input_referred, total / gain**2, rtol=1e-9)


def invoke(*args):
    return CliRunner().invoke(main, ["noise", *map(str, args)])


def test_plot_draws_into_a_given_axes(tmp_path) -> None:
    from matplotlib.figure import Figure

    res = springc.load(NETWORK).noise()
    ax = Figure().subplots()
    assert res.plot(tmp_path / "n.png", ax=ax, largest=2) is ax
    total, *shares = ax.lines
    np.testing.assert_array_equal(total.get_xdata(), res.f_hz)
    np.testing.assert_array_equal(total.get_ydata(), res.psd)
    band = {name: np.trapezoid(s, res.f_hz) for name, s in res.sources.items()}
    assert [line.get_label() for line in shares] == sorted(band, key=lambda n: -band[n])[:2]
    assert (tmp_path / "n.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_to_xarray_is_the_psd_with_its_units() -> None:
    net = springc.load(NETWORK)
    res = net.noise()
    ds = res.to_xarray()
    np.testing.assert_array_equal(ds["f"], res.f_hz)
    np.testing.assert_array_equal(ds["psd"], res.psd)
    assert ds["source"].values.tolist() == list(res.sources) == ["M1", "M3", "B12", "B3"]
    np.testing.assert_array_equal(ds["share"].sel(source="B12"), res.sources["B12"])
    # independent sources add in power
    np.testing.assert_allclose(ds["share"].sum("source"), ds["psd"], rtol=1e-12)
    # referred to the input: the PSD of in(0) that moves c as much, |H|^2 S_in = S_c
    h = net.ac("c", fmin=res.f_hz[0], fmax=res.f_hz[-1], points=len(res.f_hz))
    np.testing.assert_allclose(ds["input_referred"] * h.mag**2, ds["psd"], rtol=1e-9)
    assert ds["rms"].item() == res.rms and ds["temp"].item() == 300.0
    units = {k: ds[k].attrs["units"] for k in ("f", "psd", "share", "input_referred", "rms",
                                               "temp")}
    assert units == {"f": "Hz", "psd": "m^2/Hz", "share": "m^2/Hz", "input_referred": "1/Hz",
                     "rms": "m", "temp": "K"}
    alone = springc.load(OSC + ".noise a 1 10 points=3\n").noise().to_xarray()
    assert "input_referred" not in alone  # no input drives the oscillator


def test_command_writes_csv_json_and_plot(tmp_path) -> None:
    (tmp_path / "net.spr").write_text(NETWORK)
    res = invoke(tmp_path / "net.spr", "--temp", "300", "-o", tmp_path / "psd.csv", "--json",
                 "--plot", tmp_path / "psd.png")
    assert res.exit_code == 0, res.output
    data = json.loads(res.output)
    assert {"f", "psd", "sources", "rms", "input_referred"} <= set(data)
    assert data["rms"] == pytest.approx(np.sqrt(np.trapezoid(data["psd"], data["f"])))
    header = (tmp_path / "psd.csv").read_text().splitlines()[0].split(",")
    assert header == ["f_hz", "psd_m2_per_hz", "input_referred", "psd:M1", "psd:M3",
                      "psd:B12", "psd:B3"]
    assert (tmp_path / "psd.png").read_bytes()[:4] == b"\x89PNG"


@pytest.mark.parametrize("text, args, message", [
    (OSC + ".options temp=-3\n", [], "3:15: error: temp must be a finite temperature"),
    (OSC, ["--node", "a", "--temp", "-1"], "finite temperature >= 0 K"),
    (OSC, ["--node", "a", "--temp", "nan"], "finite temperature >= 0 K"),
    (OSC + ".noise q 1 10\n", [], "3:8: error: node 'q' has no mass"),
    (OSC + ".noise a 10 1\n", [], "needs 0 < fstart <= fstop"),
    (OSC, ["--node", "a", "--fmin", "0", "--fmax", "-5"], "bad sweep"),
    ("M1 a m=1\nK1 a k=1\n.noise a 1 10\n", [], "has no damper"),
    (OSC, [], "no output node"),
    (OSC + ".noise a 1 10 input=1\n", ["--input", "1"], "no F element is driven by in(1)"),
])
def test_bad_noise_requests_are_user_errors(tmp_path, text, args, message) -> None:
    (tmp_path / "n.spr").write_text(text)
    res = invoke(tmp_path / "n.spr", *args, "-o", tmp_path / "out.csv")
    assert res.exit_code == 1, res.output
    assert message in res.output and "Traceback" not in res.output
    assert not list(tmp_path.glob("*out.csv*"))
