"""The shared kernel with its nodes split over threads (`KernelOptions.parallel`,
`simulate.split_nodes`): the serial kernel's trajectories and reductions, and which
simulations get it."""

from __future__ import annotations

import numpy as np
import pytest

from springc.bench.lattices import lattice_net
from springc.check import check
from springc.kernels import codegen, terms
from springc.lang.ir import IRBuilder, Source, Tran
from springc.sim import marshal
from springc.sim import execute
from springc.sim import simulate as sm

W = 2 * np.pi * 40.0
H = 1e-4
REDUCTIONS = ["energy", "work:in", "dissipated:all", "msq:x(a)", "gram:0.01:a,b"]


def every_end() -> object:
    """Five masses with every element kind, a node at the second end of a quadratic
    coupling and of a dashpot, two Duffing terms on one node, a dashpot to ground, a
    monomial, inputs on two channels and sine drives."""
    b = IRBuilder("every element end", "every_end.spr")
    for name, node, m, damp in (("1", "a", 1.0, 30.0), ("2", "b", 2.0, 10.0),
                                ("3", "c", 0.5, 0.0), ("4", "d", 1.0, 0.0),
                                ("5", "e", 1.0, 0.0)):
        b.mass(f"M{name}", node, m, damp)
        b.spring(f"K{name}", node, W**2 * m)
    b.coupling("C1", "a", "b", 0.3 * W**2, a=1.5)
    b.coupling("C2", "d", "e", 0.2 * W**2)
    b.quad("Q1", "a", "c", 2e3, a=0.5)
    b.quad("Q2", "c", "b", 1e3, a=2.0)
    b.duffing("D1", "d", 1e7)
    b.duffing("D2", "d", 3e6)
    b.duffing("D3", "a", 1e6)
    b.dashpot("B1", "b", "d", 5.0)
    b.dashpot("B2", "e", "0", 2.0)
    b.dashpot("B3", "c", "a", 1.0)
    b.monomial("P1", 1e3, [("a", 2), ("e", 2)])
    b.force("F1", "a", Source("in", channel=0), 1e3)
    b.force("F2", "b", Source("in", channel=1), 2e3)
    b.force("F3", "d", Source("sin", (50.0, 60.0)))
    b.force("F4", "e", Source("sin", (20.0, 30.0)))
    for node in "abcde":
        b.probe("x", node)
        b.probe("v", node)
    b.tran = Tran(H, 0.06, None)
    return b.finish()


def inputs(runs: int) -> np.ndarray:
    t = np.arange(602) * H
    f = np.random.default_rng(0).uniform(20.0, 120.0, (runs, 2, 1))
    return np.sin(2 * np.pi * f * t) * 1e-3


@pytest.mark.parametrize("runs", [1, 3])
def test_split_kernel_gives_the_serial_kernels_results(runs):
    checked = check(every_end())
    u = inputs(runs)
    serial = sm.simulate(checked, u, write_out=False, node_threads=False,
                         reductions=REDUCTIONS)
    split = sm.simulate(checked, u, write_out=False, node_threads=True, reductions=REDUCTIONS)
    assert "nodes split over threads" in open(split.info["kernel"]).read()
    assert "nodes split" not in open(serial.info["kernel"]).read()
    for key, want in serial.probes.items():
        assert np.max(np.abs(want)) > 0
        np.testing.assert_allclose(split.probes[key], want, rtol=0,
                                   atol=1e-12 * np.max(np.abs(want)))
    for key, want in serial.reductions.items():
        np.testing.assert_allclose(split.reductions[key], want, rtol=1e-12, atol=0)


def test_node_ends_follow_the_element_loops_order():
    net = every_end()
    co = marshal.coefficient_arrays(net, np.float64)
    ends = terms.node_ends(co, net.n)
    c = net.node_index("c")
    lo, hi = ends["quad_ptr"][c], ends["quad_ptr"][c + 1]
    # c is end j of Q1 (a -> c), then end i of Q2 (c -> b)
    assert ends["quad_e"][lo:hi].tolist() == [0, 1]
    assert ends["quad_end"][lo:hi].tolist() == [1, 0]
    assert ends["quad_o"][lo:hi].tolist() == [net.node_index("a"), net.node_index("b")]
    d = net.node_index("d")
    assert ends["duffing_e"][ends["duffing_ptr"][d]:ends["duffing_ptr"][d + 1]].tolist() == [0, 1]
    e = net.node_index("e")
    lo, hi = ends["dashpot_ptr"][e], ends["dashpot_ptr"][e + 1]
    assert ends["dashpot_o"][lo:hi].tolist() == [-1]  # B2 to ground
    assert int(ends["quad_ptr"][-1]) == 2 * len(net.quads)  # both ends of each


def test_serial_kernel_text_does_not_name_the_option():
    net = every_end()
    serial = codegen.generate(net, codegen.KernelOptions("rk4", lanes=1))
    split = codegen.generate(net, codegen.KernelOptions("rk4", lanes=1, parallel=True))
    assert "parallel" not in serial and "prange" not in serial
    # RK4: the stage states (stages 1-3 one code, codegen.uniform_stages), forces, combine;
    # the 3/8 rule's stages read several force stages: a stage state each
    assert split.count("nb.prange(n)") == 3
    rk38 = codegen.generate(net, codegen.KernelOptions("rk38", lanes=1, parallel=True))
    assert rk38.count("nb.prange(n)") == 5
    assert "NODE_THREADS = True" in split


def settings(method: str = "rk4") -> sm.Settings:
    return sm.Settings(1e-3, 1.0, 1, method, "float64", 1e3)


@pytest.mark.parametrize("cores", [1, 2, 16])
def test_nodes_are_split_above_the_threshold_for_fewer_runs_than_cores(monkeypatch, cores):
    monkeypatch.setattr(execute, "threads", lambda: cores)
    net = lattice_net(2, 10)  # 100 masses
    monkeypatch.setattr(sm, "NODE_THREADS_FROM", 200)
    st = settings()
    assert sm.split_nodes(net, st, 2, None) is (2 < cores)
    assert sm.split_nodes(net, st, 1, None) is False  # 100 dofs x 1 run: below
    assert sm.split_nodes(net, st, cores, None) is False  # the runs fill the cores
    assert sm.split_nodes(net, st, 1, True) is True  # asked for
    assert sm.split_nodes(net, settings("exp-heun3"), 2, True) is False  # no split form


def test_kernel_form_puts_every_run_in_one_chunk_when_split(monkeypatch):
    monkeypatch.setattr(execute, "threads", lambda: 16)
    net = lattice_net(1, 100)
    co = marshal.coefficient_arrays(net, np.float64)
    opts = codegen.KernelOptions("rk4", lanes=1)
    split = sm.kernel_form(net, opts, co, settings(), 8, None, True)
    assert split.parallel and split.lanes == 4 and split.registers is None
    assert not sm.kernel_form(net, opts, co, settings(), 8, None, False).parallel
