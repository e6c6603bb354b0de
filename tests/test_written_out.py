"""Kernels with the force code written out per node (`terms.node_terms`, `emit_nodes`): the
same trajectories as the shared kernel, which loops over the runtime index arrays, and as
scipy; which simulations get them."""

from __future__ import annotations

import functools

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from springc.bench import suite as benchsuite
from springc.kernels import regkernel, terms
from springc.sim import simulate as sm
from springc.kernels.codegen import KernelOptions, generate
from springc.lang.ir import IRBuilder, Source, Tran
from springc.check import check

W = 2 * np.pi * 40.0  # rad/s: every node's local frequency scale
H = 1e-4  # s: tstep, about 40 steps per period of the fastest mode
T = 0.05  # s
RUNS = 8  # 4 runs a thread: kernels of 4 lanes (vector code)


def every_kind() -> object:
    """Four masses with every force kind: a, b damped, c undamped, d undamped; springs on
    all; a coupling a-b; quadratic couplings a->c and b->c (c is the second end of two);
    a Duffing term on d; a dashpot b-d; inputs on a (channel 0), b (channel 1) and c
    (channel 0, twice); a sine drive on d."""
    b = IRBuilder("every force kind", "every_kind.spr")
    for name, node, m, damp in (("1", "a", 1.0, 30.0), ("2", "b", 2.0, 10.0),
                                ("3", "c", 0.5, 0.0), ("4", "d", 1.0, 0.0)):
        b.mass(f"M{name}", node, m, damp)
        b.spring(f"K{name}", node, W**2 * m)
    b.coupling("C1", "a", "b", 0.3 * W**2, a=1.5)
    b.quad("Q1", "a", "c", 2e3, a=0.5)
    b.quad("Q2", "b", "c", 1e3, a=2.0)
    b.duffing("D1", "d", 1e7)
    b.dashpot("B1", "b", "d", 5.0)
    b.force("F1", "a", Source("in", channel=0), 1e3)
    b.force("F2", "b", Source("in", channel=1), 2e3)
    b.force("F3", "c", Source("in", channel=0), 5e2)
    b.force("F4", "c", Source("in", channel=0), -2e2)
    b.force("F5", "d", Source("sin", (50.0, 60.0)))
    for node in "abcd":
        b.probe("x", node)
    b.tran = Tran(H, T, None)
    return b.finish()


def inputs(seed: int = 0) -> np.ndarray:
    """(runs, 2 channels, samples) of smooth random signals at 1/H."""
    t = np.arange(int(round(T / H)) + 2) * H
    rng = np.random.default_rng(seed)
    f = rng.uniform(20.0, 120.0, (RUNS, 2, 3))
    return np.sin(2 * np.pi * f[..., None] * t).sum(axis=2) * 1e-3


def scipy_runs(u: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Positions of a, b, c, d of every run, (runs, 4, len(t)), from scipy DOP853 on the same
    equations (the input linearly interpolated between samples, as the kernel reads it). The
    runs are one system for scipy (its steps are those of `max_step` for every run alone, so
    each run's solution is the one it gets alone), solved once per module (`_scipy_cached`:
    both forms' tests, and the register kernel's, compare the same runs)."""
    return _scipy_cached(u.tobytes(), u.shape, t.tobytes())


@functools.cache
def _scipy_cached(u_bytes: bytes, shape: tuple, t_bytes: bytes) -> np.ndarray:
    u = np.frombuffer(u_bytes).reshape(shape)
    t = np.frombuffer(t_bytes)
    runs = shape[0]
    grid = np.arange(u.shape[2]) * H
    m = np.array([1.0, 2.0, 0.5, 1.0])[:, None]
    damp = np.array([30.0, 10.0, 0.0, 0.0])[:, None]

    def rhs(time, y):
        x, v = y[:4 * runs].reshape(4, runs), y[4 * runs:].reshape(4, runs)
        u0, u1 = (np.array([np.interp(time, grid, run[ch]) for run in u]) for ch in (0, 1))
        f = -W**2 * m * x - damp * v
        k, a = 0.3 * W**2, 1.5  # k/(2a) (x_a - a x_b)^2
        s = x[0] - a * x[1]
        f[0] -= k / a * s
        f[1] += k * s
        for i, g, aq in ((0, 2e3, 0.5), (1, 1e3, 2.0)):  # g/(2a) (x_i^2 - a x_c)^2
            s = x[i] ** 2 - aq * x[2]
            f[i] -= 2 * g / aq * x[i] * s
            f[2] += g * s
        f[3] -= 1e7 * x[3] ** 3
        fd = 5.0 * (v[1] - v[3])
        f[1] -= fd
        f[3] += fd
        f += np.stack([1e3 * u0, 2e3 * u1, 3e2 * u0,
                       np.full(runs, 50.0 * np.sin(2 * np.pi * 60.0 * time))])
        return np.concatenate([v.ravel(), (f / m).ravel()])

    sol = solve_ivp(rhs, (0, t[-1]), np.zeros(8 * runs), method="DOP853", t_eval=t,
                    rtol=1e-11, atol=1e-15, max_step=H / 4)
    return sol.y[:4 * runs].reshape(4, runs, -1).transpose(1, 0, 2)


FORMS = {"registers": "the state in registers", "nodes": "# force code: written out per node\n"}


@pytest.fixture(params=sorted(FORMS))
def form(request, monkeypatch) -> str:
    """Both written-out forms: the register kernel (`springc.kernels.regkernel`, chosen where it
    serves) and the per-node force code (`codegen.emit_nodes`, where it does not)."""
    if request.param == "nodes":
        monkeypatch.setattr(regkernel, "eligible", lambda net, opts: False)
    return request.param


def _form_of(res) -> str:
    text = open(res.info["kernel"]).read()
    return next(name for name, mark in FORMS.items() if mark in text)


@pytest.mark.parametrize("method", ["rk4", "rk38"])
def test_written_out_kernel_gives_the_shared_kernels_trajectories(method, form):
    """Within a few round-offs: the same sums in the same order (FMA contraction may pair
    them differently), only the indices constant."""
    net, u = every_kind(), inputs()
    kw = dict(method=method, precision="float64")
    out = sm.simulate(check(net), u, write_out=True, **kw)
    # the shared kernel at one lane a run (`chunk`): half the text of its 4-lane form, and
    # lanes never change a run's sums
    ref = sm.simulate(check(net), u, write_out=False, chunk=1, **kw)
    assert _form_of(out) == form
    for label, want in ref.probes.items():
        scale = np.abs(want).max()
        assert scale > 1e-6, label  # every node moves
        assert np.abs(out.probes[label] - want).max() <= 1e-12 * scale, (method, label)


def assert_matches_scipy(net, u: np.ndarray, res, tol: float = 1e-6) -> None:
    """Every run's positions of a, b, c, d within `tol` (relative L2) of `scipy_runs`."""
    every = scipy_runs(u, res.t)
    for r in range(len(u)):
        want = every[r]
        for k, node in enumerate("abcd"):
            got = res.probes[f"x({node})"][r]
            err = np.linalg.norm(got - want[k]) / np.linalg.norm(want[k])
            assert err < tol, (r, node, err)


def test_written_out_kernel_matches_scipy(form):
    net, u = every_kind(), inputs(seed=1)
    res = sm.simulate(check(net), u, write_out=True, substeps=4)
    assert _form_of(res) == form
    assert_matches_scipy(net, u, res)


def test_written_out_float32_agrees_with_float64(form):
    net, u = every_kind(), inputs(seed=2)
    lo = sm.simulate(check(net), u, write_out=True, precision="float32")
    hi = sm.simulate(check(net), u, write_out=True, precision="float64")
    assert _form_of(lo) == form
    for label, want in hi.probes.items():
        err = np.linalg.norm(lo.probes[label] - want) / np.linalg.norm(want)
        assert err < 1e-4, (label, err)


def test_node_terms_of_the_feature_extractor():
    """Per node of a Mel band (fa, fb, lp): the coupling between the pair, the input on both,
    and the squarer's quadratic coupling from fa (its first end) to lp (its second)."""
    net = benchsuite.feature_extractor(bands=2)
    co = sm.coefficient_arrays(net, np.float64)
    nodes = terms.node_terms(co, net.n)
    names = net.nodes
    by_name = dict(zip(names, nodes))
    fa, fb, lp = (by_name[n] for n in ("f0a", "f0b", "lp0"))
    assert all(t.damped and t.sprung and not t.looped for t in (fa, fb, lp))
    assert [names[j] for _, j in fa.row] == ["f0b"] and [names[j] for _, j in fb.row] == ["f0a"]
    assert len(fa.ins) == len(fb.ins) == 1 and lp.row == lp.ins == ()
    assert [(k, end, names[j]) for k, _, end, j in fa.ends] == [("quad", "i", "lp0")]
    assert [(k, end, names[j]) for k, _, end, j in lp.ends] == [("quad", "j", "f0a")]
    assert fb.ends == ()


def test_too_large_or_too_dense_networks_keep_the_shared_kernel():
    dense = benchsuite.stiff_block()  # 23 couplings on every node
    co = sm.coefficient_arrays(dense, np.float64)
    assert max(len(r) for r in np.split(co["l_col"], co["l_ptr"][1:-1])) > terms.NODE_TERMS_MAX
    assert terms.node_terms(co, dense.n) is None
    big = benchsuite.feature_extractor(bands=terms.NODES_MAX // 3 + 1)
    assert big.n > terms.NODES_MAX
    assert terms.node_terms(sm.coefficient_arrays(big, np.float64), big.n) is None
    small = benchsuite.feature_extractor(bands=terms.NODES_MAX // 3)
    assert terms.node_terms(sm.coefficient_arrays(small, np.float64), small.n) is not None


def test_long_simulations_get_the_written_out_kernel():
    """`write_out=None`: from `WRITE_OUT_FROM` dof-steps (dofs x steps x runs) on; an
    explicit choice wins."""
    net = every_kind()
    co = sm.coefficient_arrays(net, np.float64)
    st = sm.settings(net)
    steps = st.nsteps * net.n
    enough = -(-sm.WRITE_OUT_FROM // steps)
    assert sm.written_out(net, co, st, enough - 1, None) is None
    assert sm.written_out(net, co, st, enough, None) == terms.node_terms(co, net.n)
    assert sm.written_out(net, co, st, enough, False) is None
    assert sm.written_out(net, co, st, 1, True) is not None
    split = sm.settings(net, method="exp-rk4")
    assert sm.written_out(net, co, split, enough, True) is None  # splitting schemes: shared


def test_written_out_text_has_constant_rows_and_no_index_loops():
    net = every_kind()
    nodes = terms.node_terms(sm.coefficient_arrays(net, np.float64), net.n)
    text = generate(net, KernelOptions(lanes=4, nodes=nodes))
    shared = generate(net, KernelOptions(lanes=4))
    assert "# force code: written out per node" in text
    assert "ka[2, b] =" in text and "for e in range(l_ptr[i]" not in text
    step = text[text.index("for ci in range(c0, c1)"):]  # after the once-per-call set-up
    shared_step = shared[shared.index("for ci in range(c0, c1)"):]
    for array in ("q_i", "d_node", "b_i", "fc_node"):  # every kind in the nodes' sums
        assert f"for e in range({array}.shape[0])" not in step
        assert f"for e in range({array}.shape[0])" in shared_step
    assert "for e in range(l_ptr[i], l_ptr[i + 1])" in shared
