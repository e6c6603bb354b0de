"""The checks' sparse path (`springc.check.sparse`, used above `linear.DENSE_MAX` and
`checks.PSD_SPARSE_FROM`) against the dense one: the same verdicts, zero-mode counts and step
limits on small netlists forced through it (singular, indefinite, floating, near-singular,
leveraged, heavily damped) and on a chain of 2,000 masses run both ways; and its pieces
against numpy's dense eigenvalues."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from springc.check import checks, linear, sparse
from springc.errors import CheckError
from springc.lang.ir import IRBuilder, Tran


def _chain(n: int, ground=1.0, coupling=10.0, mass=1e-3, damping=0.0, lever=1.0):
    """n masses in a chain, a spring to ground on every mass (`ground` a number, a list per
    mass, or None for none)."""
    b = IRBuilder()
    grounds = [ground] * n if np.isscalar(ground) or ground is None else ground
    for i in range(n):
        b.mass(f"M{i}", f"n{i}", mass, b=damping * mass)
        if grounds[i] is not None:
            b.spring(f"K{i}", f"n{i}", grounds[i])
        if i:
            b.coupling(f"C{i}", f"n{i - 1}", f"n{i}", coupling, a=lever)
    return b


def _floating_pair_and_free_mass(b: IRBuilder) -> None:
    """A floating pair (one rigid mode) and a free mass, tied to the rest by a dashpot."""
    b.mass("Mp", "p", 1e-3)
    b.mass("Mq", "q", 2e-3)
    b.coupling("Cpq", "p", "q", 5.0)
    b.mass("Mf", "f", 1e-3)
    b.dashpot("Bn0p", "n0", "p", 0.01)
    b.dashpot("Bpf", "p", "f", 0.01)


def _nets() -> dict[str, IRBuilder]:
    rng = np.random.default_rng(7)
    out = {
        "grounded": _chain(12),
        "floating": _chain(12, ground=None),
        "one end held": _chain(12, ground=[1.0] + [None] * 11),
        "near-singular": _chain(12, ground=[1e-14] + [None] * 11),
        "weakly held": _chain(12, ground=[1e-6] + [None] * 11),
        "leveraged": _chain(12, ground=None, lever=1.5),
        "heavily damped": _chain(12, ground=[1.0] + [None] * 11, damping=5e3),
        "varying": _chain(12, ground=list(rng.uniform(0.5, 2, 12)), mass=1e-3,
                          damping=30.0),
    }
    out["with free parts"] = _chain(12)
    _floating_pair_and_free_mass(out["with free parts"])
    out["indefinite"] = _chain(12)
    out["indefinite"].monomial("P1", -8.0, [("n5", 2)])
    out["semidefinite P"] = _chain(12, ground=None)
    out["semidefinite P"].monomial("P1", 0.5, [("n3", 1), ("n4", 1)])
    return out


def _verdict(net, tstep: float | None):
    """Error messages (first words), zero-mode counts, step limit and omega_max."""
    if tstep is not None:
        net.tran = Tran(tstep, 1.0, net.masses.locs[0])
    try:
        result = checks.check(net, judge_step=True)  # the step as configured
    except CheckError as err:
        return [d.message.split(":")[0] + ": " + d.message.split(":")[1][:40]
                for d in err.diagnostics], None
    return [], result


@pytest.mark.parametrize("name", list(_nets()))
def test_sparse_and_dense_paths_agree_on_small_netlists(name: str, monkeypatch) -> None:
    net = _nets()[name].finish()
    _, dense = _verdict(net, None)
    monkeypatch.setattr(linear, "DENSE_MAX", 0)
    monkeypatch.setattr(checks, "PSD_SPARSE_FROM", 0)
    errors_sparse, found = _verdict(net, None)
    monkeypatch.undo()
    errors_dense, _ = _verdict(net, None)
    assert errors_sparse == errors_dense
    if dense is None:
        return
    assert [z.count for z in found.modes.zero_modes] == [z.count for z in dense.modes.zero_modes]
    # a single zero mode's dominant nodes weigh the same (names may differ where they tie)
    for mine, theirs in zip(found.modes.zero_modes, dense.modes.zero_modes):
        if mine.count == 1:
            assert [w for _, w in mine.nodes] == pytest.approx([w for _, w in theirs.nodes],
                                                               rel=1e-6)
    # an upper bound of omega_max, above the truth by at most the margin it states
    margin = found.modes.omega_margin
    assert dense.modes.omega_max * (1 - 1e-9) <= found.modes.omega_max
    assert found.modes.omega_max**2 <= dense.modes.omega_max**2 * (1 + margin) * (1 + 1e-9)
    # the step limit: never above the exact one, and within 0.1 % of it
    assert found.step.dt <= dense.step.dt * (1 + 1e-9)
    assert found.step.dt >= dense.step.dt * (1 - 1e-3)
    # the same verdict on a step just below and just above the limit
    for factor, refused in ((0.99, False), (1.01, True)):
        monkeypatch.setattr(linear, "DENSE_MAX", 0)
        monkeypatch.setattr(checks, "PSD_SPARSE_FROM", 0)
        assert (_verdict(net, dense.step.dt * factor)[1] is None) == refused
        monkeypatch.undo()
        assert (_verdict(net, dense.step.dt * factor)[1] is None) == refused


def test_a_chain_of_800_masses_both_ways(monkeypatch) -> None:
    """A grounded, damped chain with a floating tail and a P term, above the dense limit
    (`linear.DENSE_MAX`, 300): every check run densely (dense eigenvalues of the whole
    component) and sparsely."""
    b = _chain(800, ground=[1.0] * 600 + [None] * 200, damping=10.0)
    b.monomial("P1", 0.25, [("n10", 2)])
    net = b.finish()
    sparse_result = checks.check(net)
    monkeypatch.setattr(linear, "DENSE_MAX", 800)
    monkeypatch.setattr(checks, "PSD_SPARSE_FROM", 800)
    dense_result = checks.check(net)
    assert dense_result.modes.complete and not sparse_result.modes.complete
    assert sparse_result.modes.zero_count == dense_result.modes.zero_count == 0
    assert sparse_result.modes.omega_max >= dense_result.modes.omega_max * (1 - 1e-12)
    assert sparse_result.step.dt == pytest.approx(dense_result.step.dt, rel=1e-3)
    assert sparse_result.step.dt <= dense_result.step.dt * (1 + 1e-9)
    # a negative curvature anywhere is refused both ways, with the same message
    b.monomial("P2", -1.0, [("n700", 2)])
    refused = b.finish()
    with pytest.raises(CheckError) as dense_error:
        checks.check(refused)
    monkeypatch.undo()
    with pytest.raises(CheckError) as sparse_error:
        checks.check(refused)
    assert sparse_error.value.format() == dense_error.value.format()


def _random_psd(n: int, rank: int, seed: int) -> sp.csr_matrix:
    """A sparse positive semidefinite matrix of the given rank: sum of rank-one couplings."""
    rng = np.random.default_rng(seed)
    rows = rng.integers(0, n, size=(rank, 2))
    vecs = sp.lil_matrix((rank, n))
    for r, (i, j) in enumerate(rows):
        vecs[r, i] += rng.uniform(0.5, 2)
        vecs[r, j] -= rng.uniform(0.5, 2)
    vecs = vecs.tocsr()
    return (vecs.T @ vecs).tocsr()


@pytest.mark.parametrize("seed", range(4))
def test_top_bound_inertia_and_null_space_against_dense(seed: int) -> None:
    a = _random_psd(300, 250, seed)
    exact = np.linalg.eigvalsh(a.toarray())
    found = sparse.top(a, 2)
    assert found.ritz <= exact[-1] * (1 + 1e-12)
    assert found.bound >= exact[-1] * (1 - 1e-12)
    assert found.bound <= exact[-1] * (1 + found.margin) * (1 + 1e-12)
    tau = 1e-12 * exact[-1]
    factor = sparse.Factor(a, tau)
    assert factor.negative == int(np.sum(exact < tau))
    vals, vecs = sparse.lowest(a, factor, factor.negative)
    np.testing.assert_allclose(vals, 0.0, atol=1e-9 * exact[-1])
    assert np.linalg.norm(a @ vecs) <= 1e-8 * exact[-1]


def test_a_bound_by_perturbation_is_above_the_top_and_close_to_it() -> None:
    """`sparse.near` on a chain stiffness of 400 masses with 1% of spread on every entry:
    never below the largest eigenvalue (dense eigvalsh), within `NEAR_MARGIN` of it; a
    matrix of another sparsity pattern, or one whose top modes the reference's Ritz vectors do
    not resolve within the margin, gets None."""
    import scipy.sparse as sp

    from springc.check import sparse

    rng = np.random.default_rng(5)
    n = 400
    chain = (sp.diags(np.full(n, 3.0)) - sp.diags(np.ones(n - 1), 1)
             - sp.diags(np.ones(n - 1), -1)).tocsr()
    ref_top = sparse.top(chain, 6)
    for _ in range(5):
        a = chain.copy()
        a.data = a.data * (1 + 0.01 * rng.standard_normal(a.nnz))
        a = ((a + a.T) / 2).tocsr()
        (got,) = sparse.near(chain, ref_top, [a])
        top = np.linalg.eigvalsh(a.toarray())[-1]
        assert got is not None and got.ritz <= top * (1 + 1e-12) and got.bound >= top
        assert got.bound <= top * (1 + sparse.NEAR_MARGIN)
    wider = sp.diags(np.full(n, 3.0)).tocsr()
    far = (chain + sp.diags(rng.uniform(0, 3, n))).tocsr()  # its top modes are local
    assert sparse.near(chain, ref_top, [wider, far]) == [None, None]
