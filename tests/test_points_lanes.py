"""The points of a `.step`/`.mc` netlist in the lanes of one kernel call
(springc.sim.simulate.simulate_lanes, springc.sim.points): every point equals a separate
simulation of its own netlist in every kernel form that takes per-run coefficients (shared,
written out per node, register, the exponential form's Runge-Kutta part), the exponential
form falls back to a call per point where its exact blocks differ between points, the same
seed gives bitwise the same results whatever the batch and the threads, and a netlist
without points gets the kernel text it always had."""

from __future__ import annotations

import numpy as np
import pytest

import springc
from springc.check import check
from springc.kernels import codegen
from springc.sim import marshal
from springc.sim import execute
from springc.sim import simulate as sm

# every term kind, with global and local draws on masses, dampers, springs, couplings,
# quadratic couplings, Duffing terms, dashpots, input and shared-signal gains, x0
NET = """\
.param k0=30 kc={agauss(2, 0.3)} g={gauss(1, 0.1)}
M1 a m={unif(1, 0.05)} b=0.4 x0={agauss(0.01, 0.002)}
M2 b m={gauss(0.5, 0.02)} b={gauss(0.2, 0.1)}
K1 a k={k0}
K2 b k={gauss(20, 0.05)}
C1 a b k={kc} a={gauss(1.5, 0.02)}
D1 b l={gauss(5, 0.1)}
Q1 a b g={gauss(1.5, 0.1)} a=1
B1 a b b={gauss(0.25, 0.1)}
F1 a in gain={g}
F2 b sin(0.3 2) gain={gauss(1, 0.1)}
.probe x(a) v(b)
.step k0 list 30 45
.mc 3 seed=11
.tran 20m 0.4
.options method=rk4 substeps=2
"""
MONOMIAL = "P1 c={gauss(0.01, 0.1)} a^2 b^2\n"  # the shared and written-out forms' loop
# a driven linear block (c, d) that the exponential schemes integrate exactly
BLOCK = """\
M3 c m=1 b=0.05
M4 d m=1 b=0.05
K3 c k={kb}
K4 d k=120
C2 c d k=5
F3 c in gain=1
"""


def _inputs(runs: int = 2) -> np.ndarray:
    t = np.arange(21) * 0.02
    return np.stack([[np.sin(2 * np.pi * (1 + r) * t)] for r in range(runs)])


def _one(flat, kernel: str, method: str, reduce: list[str]):
    """A separate simulation of one point's netlist (its values written in)."""
    write_out = {"shared": False, "written-out": True}[kernel]
    return sm.simulate(check(flat), _inputs(), method=method, reductions=reduce,
                       write_out=write_out)


def _close(a: np.ndarray, b: np.ndarray) -> None:
    assert a.shape == b.shape
    scale = max(float(np.abs(b).max()), 1e-300)
    assert np.abs(a - b).max() <= 1e-12 * scale, np.abs(a - b).max() / scale


def _check_points(text: str, kernel: str, method: str, reduce: list[str], form: str) -> dict:
    net = springc.load(text)
    res = net.simulate(_inputs(), reduce=reduce, kernel=kernel, method=method, substeps=2)
    kernels = set(res.info["kernels"])
    assert len(kernels) == 1
    source = open(kernels.pop()).read()
    assert form in source  # the header's force code, or the scheme
    for i, flat in enumerate(net.points.nets):
        one = _one(flat, kernel, method, reduce)
        for name, value in {**one.probes, **one.reductions}.items():
            _close(res[name][i], value)
    return res.info


@pytest.mark.parametrize("kernel, reduce, extra, form", [
    ("shared", ["final:x(a)", "msq:v(b)", "energy", "work:in", "dissipated:all"], MONOMIAL,
     "force code: loops over the runtime index arrays"),
    ("written-out", ["final:x(a)", "energy"], MONOMIAL, "force code: written out per node\n"),
    ("written-out", [], "", "the state in registers"),
])
def test_every_point_in_one_call_equals_its_netlist(kernel, reduce, extra, form):
    info = _check_points(NET + extra, kernel, "rk4", reduce, form)
    assert info["calls"] == 1 and info["per_point"] == []


# the exponential schemes' cases: a pair (a, b) with a stepped spring, a drawn spring on the
# nonlinear node b and a drawn input gain beside the block, whose stiffness kb is drawn
NET_BLOCK = """\
.param k0=30 g={gauss(1, 0.1)} kb={gauss(100, 0.05)}
M1 a m=1 b=0.4
M2 b m=0.5 b=0.2
K1 a k={k0}
K2 b k={gauss(20, 0.05)}
D1 b l=5
Q1 a b g=1.5 a=1
F1 a in gain={g}
.probe x(a) v(b)
.step k0 list 30 45
.mc 3 seed=11
.tran 20m 0.4
.options method=rk4 substeps=2
""" + BLOCK


def test_exponential_blocks_that_differ_share_the_call():
    # each point's exact blocks (their propagators E and q) read per lane, and the input
    # work: its Lawson sums read the inputs' own gains per run (g is drawn)
    info = _check_points(NET_BLOCK, "shared", "exp-rk4", ["final:x(c)", "work:in"],
                         "exp-rk4")
    assert info["calls"] == 1 and info["per_point"] == []
    header = open(info["kernels"][0]).read().splitlines()[1]
    assert all(f"'{k}'" in header for k in ("lw2_e", "lw2_p0", "lw2_p1", "fi_w", "km"))
    assert "'lw2_node'" not in header and "'frz'" not in header


def test_split_blocks_that_differ_run_point_by_point():
    # the Strang scheme's block flows are a function of their own (no lanes of points)
    info = _check_points(NET_BLOCK, "shared", "strang-rk4", ["final:x(c)"], "strang-rk4")
    assert info["calls"] == 6
    assert info["per_point"] == ["the split scheme's exact blocks differ between points"]


@pytest.fixture(scope="module")
def population():
    """12 Monte Carlo samples x 1 input (the shared case's kernel: 12 runs, 4 lanes)."""
    return springc.load(NET.replace(".step k0 list 30 45\n", "").replace(".mc 3", ".mc 12")
                        + MONOMIAL)


@pytest.mark.parametrize("batch, threads", [(7, 2), (256, 2), (256, 1), (1, 1)])
def test_same_seed_same_bits_whatever_the_batch_and_threads(population, monkeypatch, batch,
                                                           threads):
    reduce = ["final:x(a)", "msq:v(b)", "energy", "work:in", "dissipated:all"]
    reference = population.simulate(_inputs(1), reduce=reduce, kernel="shared", batch=12)
    monkeypatch.setattr(execute, "threads", lambda: threads)
    res = population.simulate(_inputs(1), reduce=reduce, kernel="shared", batch=batch)
    assert res.info["calls"] == 1 and res.info["kernels"] == reference.info["kernels"]
    for name in ("x(a)", "v(b)", *reduce):
        assert res[name].shape[:2] == (12, 1)
        np.testing.assert_array_equal(res[name], reference[name])


def test_without_points_the_kernel_text_stays():
    """No per-run arrays: the options' header, and so the cached kernel, as before."""
    net = springc.load(NET.replace(".step k0 list 30 45\n", "").replace(".mc 3 seed=11\n",
                                                                         "")).checked.net
    text = sm.kernel_source(net, codegen.KernelOptions())
    assert "per_run" not in text and "_l[" not in text
    lanes = sm.kernel_source(net, codegen.KernelOptions(per_run=("km", "minv")))
    assert "'per_run': ('km', 'minv')" in lanes and "km_l[i, 0]" in lanes
    sums = sm.kernel_source(net, codegen.KernelOptions(work=True, dissipation=True))
    assert "per_run" not in sums and "_l[" not in sums  # the sums read the shared arrays


def test_a_populations_coefficient_arrays_are_each_netlists_own() -> None:
    """`coefficient_columns` computes the kernel arrays of netlists of one pattern at once:
    row s of every coefficient array is bitwise what netlist s has alone, in both
    precisions, and the index arrays are the shared ones (the every-kind network with every
    coefficient scaled by its own random factor)."""
    from dataclasses import replace

    from reference_nets import every_kind

    base = every_kind()
    rng = np.random.default_rng(3)

    def vary(tab, *keys):
        return replace(tab, **{k: getattr(tab, k) * rng.uniform(0.5, 1.5, len(tab))
                               for k in keys})

    nets = [replace(base, masses=vary(base.masses, "m", "b"), springs=vary(base.springs, "k"),
                    duffings=vary(base.duffings, "l"), couplings=vary(base.couplings, "k", "a"),
                    quads=vary(base.quads, "g", "a"), dashpots=vary(base.dashpots, "b"),
                    forces=vary(base.forces, "gain")) for _ in range(5)]
    for dtype in (np.float64, np.float32):
        together = marshal.coefficient_columns(nets, dtype)
        for s, net in enumerate(nets):
            alone = marshal.coefficient_arrays(net, dtype)
            assert together.keys() == alone.keys()
            for key, value in alone.items():
                got = together[key][s] if key in marshal.COEFFICIENT_KEYS else together[key]
                assert got.dtype == value.dtype, key
                np.testing.assert_array_equal(got, value, err_msg=key)
        assert not np.array_equal(together["km"][0], together["km"][1])
