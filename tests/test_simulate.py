"""The runtime against physics: analytic solutions, matrix exponentials, scipy, conservation.

Numba compiles each distinct kernel once (cached on disk); the networks here are chosen so
that few kernels serve many tests (parameters are runtime arguments)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from scipy.integrate import solve_ivp
from scipy.linalg import expm
from reference_nets import nonlinear_net

from springc.lang import physics
from springc.kernels.codegen import nystrom_coefficients
from springc.errors import CheckError, DivergedRuns, SimulationError, UsageError
from springc.kernels.integrators import TABLEAUX, amplification, get_tableau, stability_polynomial
from springc.lang.ir import IRBuilder, Source, Tran
from springc.bench.reference import rk4_numpy, solve_ivp_reference
from springc.sim import execute
from springc.sim.marshal import linear_rows
from springc.sim.simulate import simulate
from springc.check import check

W0 = 2 * np.pi * 10.0  # oscillator natural frequency (rad/s)
WF = 2 * np.pi * 8.0  # drive frequency
B_LOCAL, B_POT, AMP = 25.0, 15.0, 2.0
ALL_REDUCTIONS = ["work:in", "dissipated:all", "dissipated:M1", "dissipated:B1", "energy",
                  "msq:x(a):0.5:1.5", "final:x(a)", "loss:all"]


def oscillator(tstep: float = 1e-3, tstop: float = 3.0) -> object:
    """m x'' + (b_local + b_pot) x' + w0^2 x = AMP sin(wf t), from rest."""
    b = IRBuilder("driven damped oscillator")
    b.mass("M1", "a", 1.0, B_LOCAL)
    b.spring("K1", "a", W0**2)
    b.dashpot("B1", "a", "0", B_POT)
    b.force("F1", "a", Source("sin", (AMP, WF / (2 * np.pi))))
    b.probe("x", "a")
    b.probe("v", "a")
    b.tran = Tran(tstep, tstop, None)
    return b.finish()


def sim_osc(tstep: float, tstop: float = 3.0, **kw):
    """Every oscillator run requests the same reductions, so they all share one kernel."""
    return simulate(check(oscillator(tstep, tstop)), reductions=ALL_REDUCTIONS, **kw)


def exact_oscillator(t: np.ndarray) -> np.ndarray:
    """Exact (x, v) from rest via the matrix exponential of the system augmented with the
    drive's own oscillator (s' = wf c, c' = -wf s)."""
    bt = B_LOCAL + B_POT
    a = np.array([[0, 1, 0, 0], [-W0**2, -bt, AMP, 0], [0, 0, 0, WF], [0, 0, -WF, 0]])
    y0 = np.array([0.0, 0.0, 0.0, 1.0])
    return np.stack([expm(a * tk) @ y0 for tk in t])[:, :2].T


def test_driven_oscillator_matches_analytic_steady_state():
    res = sim_osc(2.5e-4)
    t, x = res.t, res.probes["x(a)"][0]
    late = t > 2.0  # transient decays as exp(-20 t)
    design = np.stack([np.sin(WF * t[late]), np.cos(WF * t[late])], axis=1)
    (cs, cc), *_ = np.linalg.lstsq(design, x[late], rcond=None)
    h = 1.0 / (W0**2 - WF**2 + 1j * (B_LOCAL + B_POT) * WF)
    assert abs(np.hypot(cs, cc) / (AMP * abs(h)) - 1) < 5e-9
    assert abs(np.arctan2(cc, cs) - np.angle(h)) < 5e-9


def test_rk4_global_error_order_is_four():
    errors = []
    for tstep in (4e-3, 2e-3, 1e-3):
        res = sim_osc(tstep, tstop=1.0)
        exact = exact_oscillator(res.t)[0]
        errors.append(np.abs(res.probes["x(a)"][0] - exact).max())
    ratios = np.array(errors[:-1]) / np.array(errors[1:])
    assert np.all(np.abs(ratios - 16) < 1.0), ratios


def test_other_scheme_has_its_order():
    errors = []
    for tstep in (2e-3, 1e-3):
        res = sim_osc(tstep, tstop=1.0, method="ssprk3")
        errors.append(np.abs(res.probes["x(a)"][0] - exact_oscillator(res.t)[0]).max())
    assert abs(errors[0] / errors[1] - 8) < 0.8


def test_reductions_match_scipy_energy_integrals():
    res = sim_osc(2.5e-4, tstop=2.0)
    bt = B_LOCAL + B_POT

    def rhs(t, y):  # x, v, input work, dissipated local, dissipated dashpot
        f = AMP * np.sin(WF * t)
        return [y[1], f - bt * y[1] - W0**2 * y[0], f * y[1], B_LOCAL * y[1] ** 2,
                B_POT * y[1] ** 2]

    ref = solve_ivp(rhs, (0, 2.0), np.zeros(5), method="DOP853", rtol=1e-12, atol=1e-16).y[:, -1]
    red = res.reductions
    assert red["work:in"][0] == pytest.approx(ref[2], rel=1e-8)
    assert red["dissipated:M1"][0] == pytest.approx(ref[3], rel=1e-8)
    assert red["dissipated:B1"][0] == pytest.approx(ref[4], rel=1e-8)
    assert red["dissipated:all"][0] == pytest.approx(red["dissipated:M1"][0]
                                                     + red["dissipated:B1"][0], rel=1e-12)
    energy = 0.5 * ref[1] ** 2 + 0.5 * W0**2 * ref[0] ** 2
    assert red["energy"][0] == pytest.approx(energy, rel=1e-8)
    # energy balance: final energy = work in - dissipated (to RK4's error)
    assert red["energy"][0] == pytest.approx(red["work:in"][0] - red["dissipated:all"][0],
                                             rel=1e-7)
    loss = -10 * np.log10(red["dissipated:all"][0] / red["work:in"][0])
    assert red["loss:all"][0] == pytest.approx(loss, rel=1e-12)


def test_undamped_nodes_with_a_dashpot_and_work_reductions():
    """Masses with no local damping: the kernel computes stage velocities only on nodes
    something reads them on (`codegen.velocity_needed`): the ends of the dashpot coupling a
    and c (checked without reductions), and the driven node d for the input-work reduction."""
    kc, kd, bd = (0.5 * W0) ** 2, (0.63 * W0) ** 2, B_LOCAL + B_POT
    b = IRBuilder("dashpot-coupled pair and a driven mass")
    for name, node, mass, k in (("1", "a", 1.0, W0**2), ("2", "c", 2.0, kc), ("3", "d", 1.0, kd)):
        b.mass(f"M{name}", node, mass, 0.0)
        b.spring(f"K{name}", node, k)
    b.dashpot("B1", "a", "c", bd)
    b.force("F1", "a", Source("sin", (AMP, WF / (2 * np.pi))))
    b.force("F3", "d", Source("sin", (AMP, WF / (2 * np.pi))))
    b.probe("x", "a")
    b.probe("x", "c")
    b.tran = Tran(2.5e-4, 1.0, None)
    net = b.finish()
    res = simulate(check(net))

    def rhs(t, y):  # xa, va, xc, vc, xd, vd, input work, dissipated by the dashpot
        f, fd = AMP * np.sin(WF * t), bd * (y[1] - y[3])
        return [y[1], f - W0**2 * y[0] - fd, y[3], (fd - kc * y[2]) / 2.0, y[5],
                f - kd * y[4], f * (y[1] + y[5]), fd * (y[1] - y[3])]

    ref = solve_ivp(rhs, (0, 1.0), np.zeros(8), method="DOP853", t_eval=res.t, rtol=1e-12,
                    atol=1e-16).y
    for k, label in ((0, "x(a)"), (2, "x(c)")):
        got, want = res.probes[label][0], ref[k]
        assert np.abs(got - want).max() < 1e-8 * np.abs(want).max(), label  # RK4's error
    # both reductions in one kernel (one compile, not one each): work:in alone would read
    # the same velocities, those of d and of the dashpot's ends
    red = simulate(check(net), probes=[], reductions=["work:in", "dissipated:B1"]).reductions
    for reduction, want in (("work:in", ref[6, -1]), ("dissipated:B1", ref[7, -1])):
        assert red[reduction][0] == pytest.approx(want, rel=1e-8), reduction


def test_msq_and_final_match_the_recorded_trajectory():
    res = sim_osc(1e-3, tstop=2.0, outrate=1e3)
    t, x = res.t, res.probes["x(a)"][0]
    window = (t > 0.5 + 1e-9) & (t <= 1.5 + 1e-9)
    assert res.reductions["msq:x(a):0.5:1.5"][0] == pytest.approx(np.mean(x[window] ** 2),
                                                                  rel=1e-12)
    assert res.reductions["final:x(a)"][0] == x[-1]


def test_substeps_and_outrate_set_the_grid():
    res = sim_osc(1e-3, tstop=0.5, substeps=4, outrate=500)
    assert res.t[1] == pytest.approx(2e-3) and len(res.t) == 251
    exact = exact_oscillator(res.t)
    assert np.abs(res.probes["v(a)"][0] - exact[1]).max() < 5e-9 * np.abs(exact[1]).max()


def test_float32_agrees_with_float64_to_single_precision():
    lo = sim_osc(1e-3, tstop=1.0, precision="float32").probes["x(a)"][0]
    hi = sim_osc(1e-3, tstop=1.0).probes["x(a)"][0]
    assert lo.dtype == np.float32
    assert np.abs(lo - hi).max() < 1e-5 * np.abs(hi).max()


def test_an_unstable_step_is_refused_before_running_with_builds_message():
    net = oscillator(0.05, tstop=100.0)
    with pytest.raises(CheckError) as built:
        check(net, "rk4")
    checked = check(net, judge_step=False)
    with pytest.raises(CheckError) as simulated:
        simulate(checked, reductions=ALL_REDUCTIONS)
    assert simulated.value.format() == built.value.format()
    assert "time step 0.05 s is unstable for rk4" in built.value.format()
    with pytest.raises(CheckError, match="unstable for rk4"):
        simulate(check(oscillator(0.04, tstop=100.0), "rk4"), tstep=0.05)
    simulate(checked, substeps=2, tstop=0.5)  # 0.025 s: stable


def test_simulate_takes_only_a_checked_netlist():
    with pytest.raises(TypeError, match="call springc.check.check"):
        simulate(oscillator(1e-3))


def test_divergence_names_time_node_and_unstable_step():
    """Past the stability limit on purpose (`check_step=False`): the divergence guard stops
    the run and names the step."""
    with pytest.raises(SimulationError) as info:
        simulate(check(oscillator(0.05, 100.0), judge_step=False), reductions=ALL_REDUCTIONS,
                 check_step=False)
    err = info.value.format()
    assert "node a" in err and "diverged by t =" in err
    assert "unstable step" in err and "largest stable step" in err


# --- linear networks: exact discretisation and energy conservation -----------------------

def linear_net(damped: bool, n: int = 6):
    """A chain with springs to ground, leverage couplings (a != 1) and dashpots; initial
    displacement and velocity, no forces."""
    b = IRBuilder("linear chain")
    rng = np.random.default_rng(3)
    for i in range(n):
        b.mass(f"M{i}", f"n{i}", rng.uniform(0.5, 2), rng.uniform(0.5, 2) * damped,
               x0=rng.uniform(-1, 1), v0=rng.uniform(-5, 5))
        b.spring(f"K{i}", f"n{i}", rng.uniform(50, 200))
    for i in range(n - 1):
        b.coupling(f"C{i}", f"n{i}", f"n{i + 1}", rng.uniform(100, 300),
                   a=1.3 if i % 2 else 1.0)
        b.dashpot(f"B{i}", f"n{i}", f"n{i + 1}", rng.uniform(0.1, 1) * damped)
    for i in range(n):
        b.probe("x", f"n{i}")
        b.probe("v", f"n{i}")
    b.tran = Tran(2e-3, 2.0, None)
    return b.finish()


def test_linear_rows_are_minus_m_inverse_k_with_duplicates_summed():
    """The kernel's gathered stiffness rows (diagonal + CSR) rebuild -M^-1 K of
    physics.stiffness_matrix, with a pair coupled twice (once each way) summed into one
    entry per row, columns sorted, no diagonal entry in the rows."""
    b = IRBuilder("twice coupled")
    for i, m in enumerate((1.0, 2.0, 0.5)):
        b.mass(f"M{i}", f"n{i}", m)
        b.spring(f"K{i}", f"n{i}", 10.0 * (i + 1))
    b.coupling("C0", "n0", "n1", 100.0, a=1.3)
    b.coupling("C1", "n1", "n0", 40.0, a=0.7)  # the same pair again, the other way round
    b.coupling("C2", "n2", "n0", 5.0)
    net = b.finish()
    minv = 1 / net.mass()
    diag, ptr, col, val = linear_rows(net, minv)
    got = np.diag(-diag)
    for i in range(net.n):
        assert list(col[ptr[i]:ptr[i + 1]]) == sorted(set(col[ptr[i]:ptr[i + 1]]) - {i})
        got[i, col[ptr[i]:ptr[i + 1]]] += val[ptr[i]:ptr[i + 1]]
    want = -minv[:, None] * physics.stiffness_matrix(net)
    assert np.allclose(got, want, rtol=1e-14, atol=0)
    assert len(col) == 4  # (0,1), (0,2), (1,0), (2,0)


def first_order_matrix(net) -> np.ndarray:
    n = net.n
    minv = 1 / net.mass()
    a = np.zeros((2 * n, 2 * n))
    a[:n, n:] = np.eye(n)
    a[n:, :n] = -minv[:, None] * physics.stiffness_matrix(net)
    a[n:, n:] = -minv[:, None] * physics.damping_matrix(net)
    return a


def state_matrix(res, net) -> np.ndarray:
    xs = [res.probes[f"x({name})"][0] for name in net.nodes]
    vs = [res.probes[f"v({name})"][0] for name in net.nodes]
    return np.array(xs + vs)


def test_linear_network_matches_exact_discretisation_and_matrix_exponential():
    net = linear_net(damped=True)
    res = simulate(check(net), reductions=["energy"])
    y = state_matrix(res, net)
    a = first_order_matrix(net)
    h = net.tran.tstep
    # one RK4 step of a linear system is the matrix polynomial R(hA), R from the tableau
    coeffs = stability_polynomial(get_tableau("rk4"))
    step = sum(c * np.linalg.matrix_power(h * a, k) for k, c in enumerate(coeffs))
    y0 = y[:, 0]
    powers = [y0]
    for _ in range(len(res.t) - 1):
        powers.append(step @ powers[-1])
    discrete = np.array(powers).T
    scale = np.abs(y).max()
    assert np.abs(y - discrete).max() < 1e-12 * scale * len(res.t) ** 0.5
    exact = np.array([expm(a * t) @ y0 for t in res.t[::50]]).T
    err = np.abs(y[:, ::50] - exact).max() / scale
    w_max = np.abs(np.linalg.eigvals(a)).max()
    # global RK4 error bound of the fastest mode: t * (w h)^5 / 120 per unit amplitude
    assert 1e-12 < err < 2.0 * w_max * (w_max * h) ** 4 / 120


def test_undamped_chain_conserves_energy_to_rk4_drift():
    net = linear_net(damped=False)
    res = simulate(check(net), reductions=["energy"])
    x0, v0 = net.initial_state()
    e0 = physics.energy(net, x0, v0)
    # modal energies: each mode loses |R(i w h)|^2 per step (RK4 is dissipative)
    k, m = physics.stiffness_matrix(net), net.mass()
    w2, modes = np.linalg.eigh(k / np.sqrt(np.outer(m, m)))
    q, p = modes.T @ (np.sqrt(m) * x0), modes.T @ (np.sqrt(m) * v0)
    modal = 0.5 * (p**2 + w2 * q**2)
    h, nsteps = net.tran.tstep, len(res.t) - 1
    gain = np.abs(amplification(get_tableau("rk4"), 1j * np.sqrt(w2) * h)) ** (2 * nsteps)
    predicted = np.sum(modal * gain)
    e_end = res.reductions["energy"][0]
    assert 1e-8 < (e0 - e_end) / e0 < 1e-3  # a real drift of the expected sign
    assert e_end == pytest.approx(predicted, rel=1e-10)


# --- nonlinear networks against DOP853 --------------------------------------------------

def smooth_inputs(runs: int, samples: int = 1001) -> np.ndarray:
    t = np.arange(samples) * 1e-3
    freqs = 1.0 + np.arange(runs)[:, None]
    return np.sin(2 * np.pi * freqs * t)[:, None, :] * 0.5


def test_nonlinear_network_matches_dop853():
    net = nonlinear_net()
    u = smooth_inputs(1)
    res = simulate(check(net), u, substeps=16, tstop=0.5)
    t, ref, _ = solve_ivp_reference(net, u, tstep=1e-3, tstop=0.5, rtol=1e-10, atol=1e-13)
    for label, want in ref.items():
        got = res.probes[label][0]
        assert np.abs(got - want[0]).max() < 1e-10 * np.abs(want).max(), label


def test_batch_equals_runs_one_at_a_time():
    net = nonlinear_net()
    u = np.random.default_rng(5).standard_normal((5, 1, 1001))
    together = simulate(check(net), u)
    for r in range(5):
        alone = simulate(check(net), u[r:r + 1])
        for label, arr in together.probes.items():
            np.testing.assert_allclose(arr[r], alone.probes[label][0], rtol=0, atol=1e-12)


@pytest.mark.parametrize("precision", ["float64", "float32"])
def test_runs_over_several_calls_equal_one_call(precision):
    """14 runs in two calls of 8 and 6 (chunks of 4 lanes on two threads, the last chunk
    partial), all recording into one buffer from their own rows, equal the same runs in one
    call bitwise: run r is in lane r mod 4 of the same kernel either way (the kernel of the
    records test below)."""
    net = nonlinear_net()
    u = np.random.default_rng(6).standard_normal((14, 1, 501))
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(execute, "threads", lambda: 2)  # 4 lanes: 14 / 2 and 8 / 2 runs per thread
        one = simulate(check(net), u, tstop=0.5, precision=precision, reductions=["msq:x(a)"])
        calls = simulate(check(net), u, tstop=0.5, precision=precision, batch=8,
                         reductions=["msq:x(a)"])
    assert calls.info["kernel"] == one.info["kernel"]
    assert "LANES = 4 " in Path(one.info["kernel"]).read_text()
    assert calls.reductions["msq:x(a)"].shape == (14,)
    np.testing.assert_array_equal(calls.reductions["msq:x(a)"], one.reductions["msq:x(a)"])
    for label, arr in one.probes.items():
        assert calls.probes[label].shape == arr.shape == (14, 501)
        np.testing.assert_array_equal(calls.probes[label], arr)


@pytest.mark.parametrize("precision", ["float64", "float32"])
@pytest.mark.parametrize("every", [1, 100, 400])
def test_records_on_any_output_grid_equal_plain_numpy_rk4(precision, every):
    """The kernel stages records per run and writes them a line (8 float64, 16 float32) at
    a time, the last, partial line at the end: 1001, 11 or 3 records (1001 % 8, 11 % 8 and
    all 3 in a partial line) equal numpy RK4 recording the same samples; 7 runs leave a chunk
    partial."""
    net = nonlinear_net()
    u = np.random.default_rng(8).standard_normal((7, 1, 1001))
    t, want, _ = rk4_numpy(net, u, tstep=1e-3, tstop=1.0, rec_every=every)
    # msq asked for too: these runs take the lanes-4 kernels of the several-calls test
    got = simulate(check(net), u, precision=precision, outrate=1e3 / every,
                   reductions=["msq:x(a)"])
    np.testing.assert_allclose(got.t, t, rtol=1e-12)
    tol = 1e-9 if precision == "float64" else 1e-4
    for label, arr in want.items():
        assert got.probes[label].shape == arr.shape == (7, 1000 // every + 1)
        np.testing.assert_allclose(got.probes[label], arr, rtol=0,
                                   atol=tol * np.abs(arr).max())


def test_record_into_an_earlier_calls_buffer():
    """`record_into`: the same records as into fresh memory, written into the given buffer
    (the earlier result's probes are views of it); a buffer of another shape or precision is
    a usage error naming both."""
    net = nonlinear_net()
    u = np.random.default_rng(9).standard_normal((14, 1, 501))
    kw = dict(tstop=0.5, reductions=["msq:x(a)"])  # the several-calls test's kernel
    first = simulate(check(net), u, **kw)
    buf = first.info["records"]
    again = simulate(check(net), 0.5 * u, record_into=buf, **kw)
    fresh = simulate(check(net), 0.5 * u, **kw)
    assert again.info["records"] is buf
    for label, arr in fresh.probes.items():
        np.testing.assert_array_equal(again.probes[label], arr)
        np.testing.assert_array_equal(first.probes[label], arr)  # overwritten in place
    with pytest.raises(UsageError, match=r"float64 buffer of shape \(3, 14, 504\); this call "
                                         r"records into float64 \(3, 6, 504\)"):
        simulate(check(net), u[:6], tstop=0.5, record_into=buf)
    with pytest.raises(UsageError, match="records into float32"):
        simulate(check(net), u, tstop=0.5, precision="float32", record_into=buf)


def test_a_batch_of_no_runs_is_a_usage_error():
    with pytest.raises(UsageError, match="batch must be a positive number of runs, not 0"):
        simulate(check(nonlinear_net()), np.zeros((3, 1, 11)), batch=0)


def test_sound_file_input_equals_analytic_source(tmp_path):
    t = np.arange(1001) * 1e-3
    wav = tmp_path / "sine.wav"
    sf.write(wav, np.sin(2 * np.pi * 5.0 * t), 1000, subtype="DOUBLE")
    from_file = simulate(check(nonlinear_net(in_gain=1.5, sin_gain=0.0)), [wav])
    from_array = simulate(check(nonlinear_net(in_gain=1.5, sin_gain=0.0)), np.sin(2 * np.pi * 5 * t)
                          [None, None, :])
    analytic = simulate(check(nonlinear_net(in_gain=0.0, sin_gain=1.5)))
    assert from_file.runs == [str(wav)]
    for label, want in analytic.probes.items():
        np.testing.assert_allclose(from_file.probes[label], from_array.probes[label],
                                   rtol=0, atol=1e-14)
        # linear interpolation between samples: relative error ~ (w tstep)^2 / 8 = 1.2e-4
        assert np.abs(from_file.probes[label] - want).max() < 2e-4 * np.abs(want).max()


def test_input_resampled_from_another_rate():
    t = np.arange(4001) / 4000
    u = np.sin(2 * np.pi * 3.0 * t)[None, None, :]
    res = simulate(check(nonlinear_net()), u, input_rate=4000.0)
    ref = simulate(check(nonlinear_net()), np.sin(2 * np.pi * 3.0 * t[::4])[None, None, :])
    for label, want in ref.probes.items():
        assert np.abs(res.probes[label][0, :900] - want[0, :900]).max() < 1e-4 * np.abs(
            want).max()


# --- golden trajectories of the example netlists (regenerate: python tests/regen_golden.py) --

GOLDEN_DIR = Path(__file__).parent / "golden"
EXAMPLES = sorted((Path(__file__).parents[1] / "netlists" / "examples").glob("*.spr"))


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.stem)
def test_golden_trajectories(path):
    from regen_golden import simulate_example

    stored = np.load(GOLDEN_DIR / f"{path.stem}.npz")
    res = simulate_example(path)
    assert sorted(stored.files) == sorted(["t", *res.probes])
    np.testing.assert_allclose(res.t, stored["t"], rtol=1e-12)
    for label, got in res.probes.items():
        want = stored[label]
        assert got.shape == want.shape
        # round-off only: other machines and numba versions may reorder a few operations
        assert np.abs(got - want).max() <= 1e-9 * np.abs(want).max(), label


@pytest.mark.parametrize("method", sorted(TABLEAUX))
def test_nystrom_kernel_equals_the_textbook_tableau(method: str):
    """The kernels take the stage positions from the force stages alone (Runge-Kutta-Nystrom
    form, `codegen.nystrom_coefficients`); in exact arithmetic that is the tableau applied to
    x' = v, v' = f. Against the textbook stages (`reference.rk4_numpy`) on a damped, driven
    pair with a quadratic coupling, over 200 steps: equal to round-off."""
    b = IRBuilder("nystrom check")
    b.mass("M1", "a", 1.0, 3.0)
    b.mass("M2", "c", 2.0, 1.0)
    b.spring("K1", "a", 400.0)
    b.spring("K2", "c", 900.0)
    b.coupling("C1", "a", "c", 100.0, a=2.0)
    b.quad("Q1", "a", "c", 50.0)
    b.force("F1", "a", Source("in"), 30.0)
    b.probe("x", "a")
    b.probe("v", "c")
    b.tran = Tran(2e-3, 0.4, None)
    net = b.finish()
    u = np.random.default_rng(5).standard_normal((2, 1, 201))
    res = simulate(check(net), u, tstep=2e-3, method=method)
    _, want, _ = rk4_numpy(net, u, tstep=2e-3, tstop=0.4, method=method)
    for label, got in res.probes.items():
        scale = np.abs(want[label]).max()
        assert scale > 1e-3
        assert np.abs(got - want[label]).max() <= 1e-12 * scale, label


def test_nystrom_coefficients_of_classic_rk4():
    """RK4 for x'' = f in Nystrom form: x_new = x + h v + h^2/6 (K0 + K1 + K2), stage
    positions x + h/2 v, x + h/2 v + h^2/4 K0, x + h v + h^2/2 K1."""
    cs, aa, ba, bsum = nystrom_coefficients(get_tableau("rk4"))
    assert bsum == 1.0 and list(cs) == [0.0, 0.5, 0.5, 1.0]
    assert np.allclose(ba, [1 / 6, 1 / 6, 1 / 6, 0.0], rtol=0, atol=1e-16)
    want = np.zeros((4, 4))
    want[2, 0], want[3, 1] = 0.25, 0.5
    assert np.array_equal(aa, want)


def test_records_that_cannot_fit_are_refused_before_running() -> None:
    # 3e11 steps: 2 probes x 8 bytes plus the 8-byte time axis per sample, about 7e3 GiB
    net = check(oscillator(tstep=1e-3, tstop=3e8))
    with pytest.raises(UsageError, match=r"the records would take 6\.7\de\+03 GiB \(2 probe"):
        simulate(net)
    # with no probe the time axis alone still needs 2.2e3 GiB
    with pytest.raises(UsageError, match=r"would take 2\.2\de\+03 GiB \(0 probe"):
        simulate(net, probes=[], reductions=["energy"])


def test_dissipation_in_a_network_without_dampers_is_zero() -> None:
    # raised KeyError before: a conservative oscillator dissipates nothing, exactly
    b = IRBuilder("undamped")
    b.mass("M1", "a", 1.0, x0=1.0)
    b.spring("K1", "a", W0**2)
    b.tran = Tran(1e-3, 0.1, None)
    res = simulate(check(b.finish()), reductions=["dissipated:all", "energy"], probes=[])
    assert res.reductions["dissipated:all"].tolist() == [0.0]
    np.testing.assert_allclose(res.reductions["energy"], W0**2 / 2, rtol=1e-3)


def test_a_diverging_run_leaves_the_others_of_its_call_intact() -> None:
    # the nonlinear network driven by in(0) in the records test's 4-lane kernel: run 1 is loud
    # enough to blow up at this step, runs 0 and 2 are not; their results equal those of the
    # same call with run 1 quiet
    net = check(nonlinear_net())
    t = np.arange(501) * 1e-3
    loud = np.stack([a * np.sin(2 * np.pi * 3 * t) for a in (0.5, 1e9, 1.0)])[:, None, :]
    quiet = loud.copy()
    quiet[1] = quiet[0]
    kw = dict(reductions=["msq:x(a)"], tstop=0.5, chunk=4)
    with pytest.raises(DivergedRuns) as info:
        simulate(net, loud, 1000.0, **kw)
    assert info.value.diverged.tolist() == [1]
    calm = simulate(net, quiet, 1000.0, **kw)
    assert "LANES = 4 " in Path(calm.info["kernel"]).read_text()
    got = info.value.reductions["msq:x(a)"]
    assert got[[0, 2]].tolist() == calm.reductions["msq:x(a)"][[0, 2]].tolist()
