"""Transient thermal noise (`.options temp=`, `springc sim --temp`): the kernels' draws against
the generator's numpy form, equipartition and the displacement PSD of `springc noise` on an
oscillator, bitwise reproducibility across batch sizes, the same run in every kernel form,
no noise code without a temperature, bad temperatures as user errors, and the cost bench.

The oscillator is in scaled form: m = k = k_B * 300 K (so x_rms = 1 m at 300 K and
omega_0 = 1 rad/s), b = m (Q = 1)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.signal
from click.testing import CliRunner

import springc
from springc.analyses.noise import K_B, noise
from springc.check import check
from springc.bench.noise import cost_of_noise
from springc.kernels import codegen, terms, thermal
from springc.kernels.lower import kernel_netlist
from springc.sim import marshal
from springc.sim import simulate as sim
from springc.sim.thermal import with_overrides
from springc_cli.main import main

KT = K_B * 300.0
OSC = (f"M1 a m={KT!r} b={KT!r}\nK1 a k={KT!r}\n"
       ".options temp=300 seed=5 method=rk4 substeps=1\n.probe x(a)\n.probe v(a)\n")
# three nodes: dampers to ground (M b=, B to 0) and between nodes, all in one driven block
NET = (f"M1 a m={KT!r} b={0.5 * KT!r}\nK1 a k={KT!r}\nM2 b m={2 * KT!r}\nK2 b k={3 * KT!r}\n"
       f"C1 a b k={0.5 * KT!r}\nB1 a b b={0.4 * KT!r}\nB2 b 0 b={0.3 * KT!r}\n"
       f"M3 c m={KT!r}\nK3 c k={KT!r}\nB3 c a b={0.2 * KT!r}\nF1 a in gain=0\n"
       ".tran 0.05 5\n.options temp=300 seed=7\n.probe x(a)\n.probe v(b)\n.probe x(c)\n")
RUNS = 64


def probes(res) -> np.ndarray:
    return np.stack([res.probes[k] for k in res.probes])


def run_res(text: str = NET, runs: int = RUNS, **kw):
    u = np.zeros((runs, 1, 101))
    return sim.simulate(springc.load(text).checked, u, substeps=1,
                        method=kw.pop("method", "rk4"), **kw)


def run_net(text: str = NET, runs: int = RUNS, **kw) -> np.ndarray:
    return probes(run_res(text, runs, **kw))


def test_the_generator_is_standard_normal_and_independent() -> None:
    z = thermal.normals(3, np.arange(50), np.arange(4), np.arange(5000))
    assert abs(z.mean()) < 3e-3 and abs(z.var() - 1) < 5e-3
    assert abs(np.mean(z**4) - 3) < 0.03  # Gaussian kurtosis
    flat = z.transpose(1, 0, 2).reshape(4, -1)
    assert np.abs(np.corrcoef(flat) - np.eye(4)).max() < 5e-3  # pairs share a draw


def test_the_kernel_draws_what_the_generator_says() -> None:
    """Nearly free masses (b/m h = 5e-14) with the midpoint rule: each step's velocity change
    is h times the held noise force over the mass, so the draws can be read back. Runs are
    split into kernel calls of two (their global index reaches the kernel)."""
    b = 1e-12
    text = (f"M1 a m=1 b={b}\nK1 a k=1e-12\nM2 b m=2\nK2 b k=1e-12\nB1 a b b={b}\n"
            ".options temp=300 seed=11\n.probe v(a)\n.probe v(b)\n")
    h, steps = 0.05, 40
    res = sim.simulate(springc.load(text).checked, np.zeros((4, 0, steps + 1)), tstep=h,
                       tstop=steps * h, method="midpoint", substeps=1, batch=2)
    sigma = np.sqrt(2 * K_B * 300 * b / h)
    dva, dvb = (np.diff(res.probes[k], axis=1) / h for k in ("v(a)", "v(b)"))
    z1 = -dvb * 2 / sigma  # B1 pushes b by -sigma z1 / m_b
    z0 = (dva - sigma * z1) / sigma
    want = thermal.normals(11, np.arange(4), [0, 1], np.arange(steps))
    np.testing.assert_allclose(np.stack([z0, z1], axis=1), want, rtol=1e-7, atol=1e-7)


@pytest.fixture(scope="module")
def oscillator():
    """256 runs of 1000 s (20000 RK4 steps of h = 0.05 s, omega_0 h = 0.05), the register
    kernel of 32 lanes (half the text of the shared one: the draws are those of every form)."""
    net = springc.load(OSC)
    res = sim.simulate(net.checked, np.zeros((256, 0, 20001)), tstep=0.05, tstop=1000.0,
                       write_out=True)
    return net, res


def test_equipartition(oscillator) -> None:
    """RK4, h = 0.05 s (omega_0 h = 0.05): after 20 s (20 damping times) the mean of
    k x^2 / 2 and of m v^2 / 2 over 256 runs x 980 s is k_B T / 2 within 2%."""
    _, res = oscillator
    keep = res.t >= 20.0
    for label in ("x(a)", "v(a)"):
        energy = KT * np.mean(res.probes[label][:, keep] ** 2) / 2
        assert energy / (KT / 2) == pytest.approx(1.0, abs=0.02), label


def test_the_psd_is_the_noise_analysis(oscillator) -> None:
    """Welch's PSD of x against `springc noise` from 0.05 Hz to 1 Hz (the resonance is at
    0.16 Hz; the held force's sinc^2 is above 0.99 there), within 10% at every bin."""
    net, res = oscillator
    x = res.probes["x(a)"][:, res.t >= 20.0]
    f, psd = scipy.signal.welch(x, fs=20.0, nperseg=2048, axis=-1)
    psd = psd.mean(axis=0)
    band = (f >= 0.05) & (f <= 1.0)
    want = noise(net.checked, "a", f[band], 300.0).psd
    np.testing.assert_allclose(psd[band], want, rtol=0.10)


@pytest.mark.parametrize("lanes", [4, 16])
def test_same_seed_is_bitwise_equal_for_batch_1_7_and_64(lanes) -> None:
    """The same kernel (shared, `lanes` wide: `chunk`, whatever the threads) for batches of 1
    and 7 runs (rounded up to whole chunks: a run keeps its lane) and one call of 64: bitwise
    equal (another lane count is another kernel form, equal to rounding; at 4 lanes, lanes of
    one chunk round differently)."""
    all_ = run_net(batch=64, write_out=False, chunk=lanes)
    for batch in (1, 7):
        assert np.array_equal(run_net(batch=batch, write_out=False, chunk=lanes), all_), batch
    assert not np.array_equal(all_[:, 0], all_[:, 1])  # runs differ from each other
    other = run_net(batch=64, write_out=False, chunk=lanes, seed=8)
    assert not np.allclose(other, all_)


def test_every_kernel_form_runs_the_same_noise() -> None:
    """Shared (lanes 1 and 16), register (lanes 1 and 32), written out per node (4 lanes; an
    in-kernel reduction, `msq`, rules out the register form, where `energy`, taken from the
    final state, would not) agree to rounding; the exponential schemes, whose
    block holds every node here, to their integrators' error (at lanes 1: their kernels of 32
    lanes are twice the text, twice the compile, and the draws do not depend on the lanes)."""
    ref = run_net(batch=64, write_out=False, chunk=16)
    scale = np.abs(ref).max()
    for kw in (dict(batch=1, write_out=False), dict(batch=1), dict(write_out=True),
               dict(write_out=True, reductions=["msq:x(a)"], chunk=4)):
        res = run_res(**kw)
        got = probes(res)
        assert np.abs(got - ref).max() < 1e-12 * scale, kw
    assert "# force code: written out per node\n" in open(res.info["kernel"]).read()
    for method, tol in (("exp-rk4", 1e-5), ("strang-rk4", 2e-3)):
        got = run_net(method=method, batch=1)
        assert np.abs(got - ref).max() < tol * scale, method


# kernels of the test above that call every intrinsic with a Python stand-in: streaming
# stores and the aligned frame (the 32-lane register kernel), the generator's square root and
# leading zeros (all of them)
AS_PYTHON = {"shared, 16 lanes": dict(write_out=False, chunk=16),
             "register, 32 lanes": dict(write_out=True),
             "exp-rk4": dict(method="exp-rk4", batch=1)}


def test_kernels_run_as_python_under_numba_disable_jit(tmp_path) -> None:
    """`NUMBA_DISABLE_JIT=1`, numba's switch for stepping through code in a debugger, runs the
    generated kernels as Python: the compiled kernels' runs to rounding (FMA contraction)."""
    code = ("import sys, numpy as np\n"
            f"sys.path.insert(0, {str(Path(__file__).parent)!r})\n"
            "from test_thermal_noise import AS_PYTHON, run_net\n"
            "from springc.kernels.loader import as_python\n"
            "assert as_python()\n"
            "np.savez(sys.argv[1], *[run_net(**kw) for kw in AS_PYTHON.values()])")
    out = tmp_path / "python.npz"
    proc = subprocess.run([sys.executable, "-c", code, str(out)], capture_output=True,
                          text=True, env={**os.environ, "NUMBA_DISABLE_JIT": "1"}, timeout=300)
    assert proc.returncode == 0, proc.stderr
    with np.load(out) as python:
        for k, (name, kw) in enumerate(AS_PYTHON.items()):
            compiled = run_net(**kw)
            got = python[f"arr_{k}"]
            assert np.abs(got - compiled).max() < 1e-13 * np.abs(compiled).max(), name


def kernel_text(text: str, temp: float | None = None) -> str:
    """The kernels of every form for `text` (`temp`: the caller's override)."""
    net = with_overrides(springc.load(text).flat, temp, None)
    coeffs = marshal.coefficient_arrays(kernel_netlist(net), np.float64)
    out = []
    for form in (dict(), dict(nodes=terms.node_terms(coeffs, net.n)),
                 dict(registers=terms.node_terms(coeffs, net.n)), dict(lanes=1)):
        opts = codegen.KernelOptions(**{"lanes": 16, **form})
        out.append(sim.kernel_source(kernel_netlist(net), opts))
    opts = codegen.KernelOptions(method="exp-rk4")
    return "\n".join(out + [sim.kernel_source(kernel_netlist(net), opts)])


def test_no_temperature_no_noise_code() -> None:
    quiet = NET.replace(".options temp=300 seed=7\n", "")
    plain = kernel_text(quiet)
    assert "nz_" not in plain
    assert kernel_text(quiet.replace(".tran", ".options temp=0\n.tran")) == plain
    assert kernel_text(NET, temp=0.0) == plain
    assert "nz_normals" in kernel_text(NET)


@pytest.mark.parametrize("value", ["-3", "nan", "inf", "-inf"])
def test_bad_temperatures_are_user_errors(tmp_path, value) -> None:
    (tmp_path / "n.spr").write_text(OSC + ".tran 0.05 1\n")
    res = CliRunner().invoke(main, ["sim", str(tmp_path / "n.spr"), f"--temp={value}",
                                    "-o", str(tmp_path / "o.npz")])
    assert res.exit_code == 1 and "Traceback" not in res.output
    assert "temp must be a finite temperature >= 0 K" in res.output
    assert not list(tmp_path.glob("*o.npz*"))


def test_sim_temp_and_seed_override_the_netlist(tmp_path) -> None:
    quiet = NET.replace(".options temp=300 seed=7\n", ".options method=rk4 substeps=1\n")
    (tmp_path / "n.spr").write_text(quiet)
    res = CliRunner().invoke(main, ["sim", str(tmp_path / "n.spr"), "--temp", "300",
                                    "--seed", "7", "--kernel", "shared", "-o",
                                    str(tmp_path / "o.npz")])
    assert res.exit_code == 0, res.output
    with np.load(tmp_path / "o.npz") as saved:
        got = saved["x(a)"]
    # run 0 without input: the same draws as run 0 of the array runs
    np.testing.assert_array_equal(got[0], run_net(batch=1, write_out=False)[0, 0])


def test_the_cost_bench_runs() -> None:
    ratio = cost_of_noise(springc.load(NET).flat, runs=2, seconds=0.01, rounds=1)
    assert np.isfinite(ratio) and ratio > 0


@pytest.mark.parametrize("values, calls", [((0.4, 0.8, 1.6), 1), ((0.0, 0.8, 1.6), 3)])
def test_a_populations_points_meet_their_own_noise(values, calls) -> None:
    """Three `.step` points of B1's coefficient (and so of its noise force), 2 runs each: in
    the lanes of one call, or (B1 noiseless at the first point: other noisy dampers) one call
    per point. Either way point p's runs are runs 2p, 2p + 1 of the population and draw those
    runs' streams, so they equal runs 2p, 2p + 1 of a separate simulation of p's netlist (to
    rounding), and every device meets noise of its own."""
    b1 = f"B1 a b b={0.4 * KT!r}"
    listed = " ".join(repr(v * KT) for v in values)
    text = (f".param bb={0.4 * KT!r}\n" + NET.replace(b1, "B1 a b b={bb}")
            + f".step bb list {listed}\n")
    net = springc.load(text)
    res = net.simulate(np.zeros((2, 1, 101)), substeps=1, method="rk4", kernel="shared")
    assert res.info["calls"] == calls
    got = np.stack([res[k] for k in res.probes])  # (probe, point, run, time)
    for p, flat in enumerate(net.points.nets):
        alone = probes(sim.simulate(check(flat), np.zeros((2 * p + 2, 1, 101)),
                                    substeps=1, method="rk4", write_out=False, chunk=4))
        scale = np.abs(alone).max()
        assert np.abs(got[:, p] - alone[:, 2 * p:]).max() <= 1e-9 * scale, p
    assert not np.allclose(got[:, 1, 0], got[:, 2, 0])  # another damper, another noise


def test_scattered_structure_groups_keep_each_points_streams() -> None:
    """A structural parameter stepped inside another (`.for` bound n): the points of one
    structure are 0, 2 and 1, 3. Each call numbers its runs' streams from its first, so the
    scattered groups run point by point, and point p's runs still equal runs 2p, 2p + 1 of a
    separate simulation of p's netlist: no two devices share noise."""
    b1 = f"B1 a b b={0.4 * KT!r}"
    text = (f".param bb={0.4 * KT!r} n=1\n" + NET.replace(b1, "B1 a b b={bb}")
            + ".for i 1 {n}\n" + f"Me{{i}} e{{i}} m={KT!r} b={0.1 * KT!r}\n"
            + f"Ke{{i}} e{{i}} k={KT!r}\n.endfor\n"
            + f".step bb list {0.4 * KT!r} {0.8 * KT!r}\n.step n list 1 2\n")
    net = springc.load(text)
    assert net.points.groups == ((0, 2), (1, 3))
    res = net.simulate(np.zeros((2, 1, 101)), substeps=1, method="rk4", kernel="shared")
    assert res.info["calls"] == 4
    got = np.stack([res[k] for k in res.probes])
    for p, flat in enumerate(net.points.nets):
        alone = probes(sim.simulate(check(flat), np.zeros((2 * p + 2, 1, 101)),
                                    substeps=1, method="rk4", write_out=False, chunk=4))
        assert np.abs(got[:, p] - alone[:, 2 * p:]).max() <= 1e-9 * np.abs(alone).max(), p
    assert not np.allclose(got[:, 0, 0], got[:, 2, 0])  # other streams, other noise
