"""Linear analysis: the sparse linearisation against the reference physics, components,
modes against analytic spectra, and the step limit against the RK stability polynomials."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from springc.check import linear
from springc.lang import physics
from springc.kernels.integrators import TABLEAUX, max_stable_step
from springc.lang.ir import IRBuilder


def _mixed():
    """Every element kind, P terms of degree 1 to 3, dashpots to ground and between nodes."""
    b = IRBuilder()
    for idx, name in enumerate("abcde"):
        b.mass(f"M{name}", name, 1.0 + idx, b=0.1 * idx)
    b.spring("Ka", "a", 3.0)
    b.duffing("Da", "a", 5.0)
    b.coupling("Cab", "a", "b", 2.0, a=1.5)
    b.coupling("Cbc", "b", "c", -1.0, a=-0.5)
    b.quad("Qcd", "c", "d", 0.7, a=2.0)
    b.dashpot("Bd0", "d", "0", 0.3)
    b.dashpot("Bde", "d", "e", 0.4)
    b.monomial("P2", 0.25, [("e", 1), ("a", 1)])
    b.monomial("P3", 0.5, [("e", 2)])
    b.monomial("P4", 1.0, [("b", 2), ("c", 1)])
    return b.finish()


def test_linearisation_matches_the_reference_physics() -> None:
    net = _mixed()
    lin = linear.linearise(net)
    np.testing.assert_allclose(lin.K.toarray(), physics.stiffness_matrix(net), atol=1e-14)
    np.testing.assert_allclose(lin.B.toarray(), physics.damping_matrix(net), atol=1e-14)
    np.testing.assert_allclose(lin.M.diagonal(), net.mass())


def test_components() -> None:
    b = IRBuilder()
    for name in ["a", "b", "c", "d", "e", "f"]:
        b.mass(f"M{name}", name, 1.0)
    b.coupling("C1", "a", "c", 1.0)
    b.dashpot("B1", "d", "0", 1.0)  # ground joins nothing
    b.dashpot("B2", "b", "e", 1.0)
    b.monomial("P1", 1.0, [("f", 2), ("d", 2)])
    parts = linear.components(b.finish())
    assert [list(p) for p in parts] == [[0, 2], [1, 4], [3, 5]]


def _chain(n: int, k: float, m: float, alpha: float = 0.0):
    """n masses, nearest-neighbour couplings k, both ends held by springs k (fixed ends)."""
    b = IRBuilder()
    for i in range(n):
        b.mass(f"M{i}", f"n{i}", m, b=alpha * m)
    b.spring("KL", "n0", k)
    b.spring("KR", f"n{n - 1}", k)
    for i in range(n - 1):
        b.coupling(f"C{i}", f"n{i}", f"n{i + 1}", k)
    return b.finish()


@pytest.mark.parametrize("n", [1, 7, 40, 400])
def test_chain_spectrum(n: int) -> None:
    """Fixed-end chain: omega_j = 2 sqrt(k/m) sin(j pi / (2(n+1))), j = 1..n (400: sparse)."""
    k, m = 3.0, 2.0
    found = linear.modes(_chain(n, k, m))
    top = 2 * np.sqrt(k / m) * np.sin(n * np.pi / (2 * (n + 1)))
    assert found.omega_max == pytest.approx(top, rel=1e-12)
    assert found.complete == (n <= linear.DENSE_MAX)
    if found.complete:
        theory = 2 * np.sqrt(k / m) * np.sin(np.arange(1, n + 1) * np.pi / (2 * (n + 1)))
        np.testing.assert_allclose(2 * np.pi * found.freqs_hz, theory, rtol=1e-10)
        assert np.all(np.isinf(found.q_factors)) and np.all(found.damping_rates == 0)


def test_single_oscillator_step_limits_match_the_stability_polynomials() -> None:
    """dt_max * w is the imaginary-axis limit of each tableau: 2 sqrt 2 for the RK4 family,
    sqrt 3 for the third-order schemes, 0 for midpoint."""
    w = 2 * np.pi * 440
    b = IRBuilder()
    b.mass("M", "a", 0.5)
    b.spring("K", "a", 0.5 * w**2)
    net = b.finish()
    expected = {"rk4": 2 * np.sqrt(2), "rk38": 2 * np.sqrt(2), "ssprk3": np.sqrt(3),
                "heun3": np.sqrt(3), "midpoint": 0.0}
    assert set(expected) == set(TABLEAUX)
    for method, limit in expected.items():
        assert linear.dt_max(net, method) * w == pytest.approx(limit, abs=1e-6), method


def test_damped_modes_are_exact() -> None:
    """A damped two-mass system with non-proportional damping (dense eig path) against the
    eigenvalues of the first-order matrix computed by scipy."""
    b = IRBuilder()
    b.mass("M1", "a", 1.0, b=0.3)
    b.mass("M2", "b", 2.0)
    b.spring("K1", "a", 4.0)
    b.coupling("C", "a", "b", 1.0)
    net = b.finish()
    found = linear.modes(net)
    a = linear.linearise(net).first_order().toarray()
    ref = scipy.linalg.eigvals(a)
    ref = np.sort_complex(ref[ref.imag > 0])
    np.testing.assert_allclose(np.sort_complex(found.eigenvalues), ref, rtol=1e-10)
    np.testing.assert_allclose(np.sort(found.q_factors), np.sort(abs(ref) / (-2 * ref.real)),
                               rtol=1e-9)


def test_mass_proportional_damping_modes() -> None:
    """b = alpha m (the paper's damping): every mode decays at alpha/2 and keeps its
    undamped natural frequency |lambda| = omega_j."""
    alpha, k, m, n = 0.4, 5.0, 1.5, 6
    found = linear.modes(_chain(n, k, m, alpha))
    theory = 2 * np.sqrt(k / m) * np.sin(np.arange(1, n + 1) * np.pi / (2 * (n + 1)))
    np.testing.assert_allclose(2 * np.pi * found.freqs_hz, theory, rtol=1e-10)
    np.testing.assert_allclose(found.damping_rates, alpha / 2, rtol=1e-10)
    np.testing.assert_allclose(found.q_factors, theory / alpha, rtol=1e-10)


def test_sparse_path_agrees_with_the_dense_one(monkeypatch) -> None:
    net = _chain(350, 2.0, 1.0, alpha=30.0)
    sparse = linear.step_limit(linear.modes(net))
    monkeypatch.setattr(linear, "DENSE_MAX", 1000)
    dense_modes = linear.modes(net)
    dense = linear.step_limit(dense_modes)
    assert dense_modes.complete
    assert sparse.dt == pytest.approx(dense.dt, rel=1e-9)
    assert sparse.mode.lam == pytest.approx(dense.mode.lam, rel=1e-9)


@pytest.mark.parametrize("method", list(TABLEAUX))
def test_step_limit_equals_the_brute_force_minimum(method: str) -> None:
    """The candidate pruning and vectorised ray search of `step_limit` give the answer of
    `integrators.max_stable_step` over every eigenvalue (overdamped modes to Q > 50)."""
    found = linear.modes(_mixed_damped())
    assert np.any(found.eigenvalues.imag == 0) and found.q_factors.max() > 50  # both kinds
    dt, arg = max_stable_step(TABLEAUX[method], found.eigenvalues)
    limit = linear.step_limit(found, method)
    assert limit.dt == pytest.approx(dt, rel=1e-12, abs=0)
    assert limit.mode.lam == found.eigenvalues[arg]


def _mixed_damped():
    rng = np.random.default_rng(3)
    b = IRBuilder()
    for i in range(12):
        b.mass(f"M{i}", f"n{i}", rng.uniform(0.5, 2), b=rng.uniform(0, 3) * 10 ** (i % 3))
        b.spring(f"K{i}", f"n{i}", rng.uniform(1, 50) * 10 ** (i % 4))
    for i in range(11):
        b.coupling(f"C{i}", f"n{i}", f"n{i + 1}", rng.uniform(1, 20))
    return b.finish()


def test_zero_modes_of_a_free_body_and_a_free_chain() -> None:
    b = IRBuilder()
    b.mass("M", "free", 1.0, b=2.0)
    found = linear.modes(b.finish())
    assert found.zero_count == 1
    # The damped free body keeps one real mode: velocity decays at b/m.
    assert found.eigenvalues == pytest.approx([-2.0])
    free_chain = _chain(400, 1.0, 1.0)
    free_chain.springs.node = free_chain.springs.node[:0]
    free_chain.springs.k = free_chain.springs.k[:0]
    free_chain.springs.names, free_chain.springs.locs = [], []
    found = linear.modes(free_chain)
    assert found.zero_count == 1 and not found.zero_modes[0].at_least


def test_mode_shape_and_dominant_nodes() -> None:
    """Two equal masses joined by a spring, one held: the fast mode is mostly antisymmetric."""
    b = IRBuilder()
    b.mass("M1", "a", 1.0)
    b.mass("M2", "b", 1.0)
    b.coupling("C", "a", "b", 1.0)
    b.spring("K", "a", 1.0)
    found = linear.modes(b.finish())
    fast = found.mode(len(found) - 1)
    # K = [[2, -1], [-1, 1]]: omega^2 = (3 + sqrt 5)/2, shape (1, (1 - sqrt 5)/2).
    assert fast.omega == pytest.approx(np.sqrt((3 + np.sqrt(5)) / 2), rel=1e-12)
    assert fast.shape["a"] == pytest.approx(1.0)
    assert fast.shape["b"] == pytest.approx((1 - np.sqrt(5)) / 2, rel=1e-10)
    assert [name for name, _ in fast.dominant()] == ["a", "b"]
    assert linear.fastest_mode(b.finish()).omega == pytest.approx(fast.omega)


def _scaled(net, seed: int):
    """`net` with every spring, coupling, dashpot and mass coefficient scaled by its own
    random factor in [0.5, 1.5): the same pattern, other values."""
    from dataclasses import replace

    rng = np.random.default_rng(seed)

    def vary(tab, *keys):
        return replace(tab, **{k: getattr(tab, k) * rng.uniform(0.5, 1.5, len(tab)) for k in keys})

    return replace(net, masses=vary(net.masses, "m", "b"), springs=vary(net.springs, "k"),
                   couplings=vary(net.couplings, "k"), dashpots=vary(net.dashpots, "b"))


def test_a_population_has_each_netlists_modes_alone() -> None:
    """`modes_many` solves netlists of one pattern in one batch: each netlist's modes are
    bitwise those it has alone, and equal to the eigenvalues of its first-order matrix (a
    dense scipy eig of a 10-row matrix, to its round-off: 1e-12 of the largest) whether
    damping couples its modes (`_mixed`) or not (a chain with mass-proportional damping)."""
    for base in (_mixed(), _chain(5, 4.0, 2.0, alpha=0.3)):
        nets = [base] + [_scaled(base, seed) for seed in range(4)]
        together = linear.modes_many(nets)
        for net, found in zip(nets, together):
            alone = linear.modes(net)
            np.testing.assert_array_equal(found.eigenvalues, alone.eigenvalues)
            assert found.omega_max == alone.omega_max
            lin = linear.linearise(net)
            want = scipy.linalg.eigvals(lin.first_order().toarray())
            want = want[want.imag >= -1e-12 * np.abs(want).max()]
            scale = np.abs(want).max()
            assert len(found.eigenvalues) == len(want)
            gap = np.abs(found.eigenvalues[:, None] - want[None, :]).min(axis=1)
            assert gap.max() <= 1e-12 * scale


@pytest.mark.parametrize("method", ["rk4", "ssprk3"])
def test_step_limits_of_many_are_each_one_alone(method: str) -> None:
    """`step_limits` finds the candidates of all its sets of modes at once: each limit (step
    and mode) is the one `step_limit` finds alone, for stable sets, an unstable one
    (negative damping: Re lambda > 0, step 0) and one without modes."""
    b = IRBuilder()
    b.mass("M1", "a", 1.0, b=-1.0)
    b.spring("K1", "a", 4.0)
    unstable = b.finish()
    founds = [linear.modes(net) for net in
              (_mixed_damped(), _chain(6, 3.0, 1.0, alpha=0.2), unstable, _scaled(_mixed(), 1))]
    founds.insert(1, linear.Modes(np.zeros(0, complex), np.zeros(0), np.zeros(0), np.zeros(0),
                                  [], [], 0.0))
    together = linear.step_limits(founds, method)
    assert together[1].dt == np.inf and together[3].dt == 0.0
    for found, limit in zip(founds, together):
        alone = linear.step_limit(found, method)
        assert limit.dt == alone.dt
        assert (limit.mode is None) == (alone.mode is None)
        if limit.mode is not None:
            assert limit.mode.lam == alone.mode.lam


@pytest.mark.parametrize("method", list(TABLEAUX))
def test_grouped_ray_search_finds_the_first_exit_of_every_ray(method: str) -> None:
    """Rays of a population (angles within 1e-7 to 1e-3 of each other, near the imaginary
    axis, at a Q of 2 and on the negative real axis) found from their group's middle ray
    give the first exit that scanning every radius of every ray gives."""
    tab = TABLEAUX[method]
    rng = np.random.default_rng(5)
    radii = np.linspace(0.0, 8.0, 4001)[1:]
    centres = np.array([np.pi / 2, np.pi / 2 + 0.02, 2.0, 2.9, np.pi - 1e-4])
    spreads = np.array([1e-7, 1e-5, 3e-4])
    angles = np.concatenate([np.clip(c + rng.normal(0, s, 40), np.pi / 2, np.pi)
                             for c in centres for s in spreads] + [[np.pi / 2] * 9])
    d = np.exp(1j * angles)
    grouped = linear._first_exits(tab, d, radii)
    assert len(np.unique(grouped)) > 5  # the rays exit at many different radii
    each = linear._scan(tab, d, radii, np.zeros(len(d), dtype=int))
    np.testing.assert_array_equal(grouped, each)
