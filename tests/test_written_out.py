"""Kernels with the force code written out per node (`terms.node_terms`, `emit_nodes`): the
same trajectories as the shared kernel, which loops over the runtime index arrays, and as
scipy; which simulations get them."""

from __future__ import annotations

import numpy as np
import pytest
from reference_nets import assert_matches_scipy, every_kind, inputs

from springc.bench import suite as benchsuite
from springc.kernels import regkernel, terms
from springc.sim import marshal
from springc.sim import simulate as sm
from springc.kernels.codegen import KernelOptions, generate
from springc.check import check

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
    co = marshal.coefficient_arrays(net, np.float64)
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
    co = marshal.coefficient_arrays(dense, np.float64)
    assert max(len(r) for r in np.split(co["l_col"], co["l_ptr"][1:-1])) > terms.NODE_TERMS_MAX
    assert terms.node_terms(co, dense.n) is None
    big = benchsuite.feature_extractor(bands=terms.NODES_MAX // 3 + 1)
    assert big.n > terms.NODES_MAX
    assert terms.node_terms(marshal.coefficient_arrays(big, np.float64), big.n) is None
    small = benchsuite.feature_extractor(bands=terms.NODES_MAX // 3)
    assert terms.node_terms(marshal.coefficient_arrays(small, np.float64), small.n) is not None


def test_long_simulations_get_the_written_out_kernel():
    """`write_out=None`: from `WRITE_OUT_FROM` dof-steps (dofs x steps x runs) on; an
    explicit choice wins."""
    net = every_kind()
    co = marshal.coefficient_arrays(net, np.float64)
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
    nodes = terms.node_terms(marshal.coefficient_arrays(net, np.float64), net.n)
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
