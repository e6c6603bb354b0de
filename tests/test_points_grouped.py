"""A population elaborated and checked by structure group (springc.lang.variation.PointSet,
springc.check.points.check_points) gives every point exactly what elaborating and checking
that point's netlist alone gives: the same coefficients bit for bit, the same diagnostics,
modes and step limit (a large component: a certified bound at most 10% looser, from the first
sample's), and the same refusal naming the same point."""

from __future__ import annotations

import numpy as np
import pytest

from springc.check import check
from springc.check.points import check_points
from springc.errors import CheckError
from springc.lang import parse, variation

# local draws on every coefficient kind, in a subcircuit and in a loop, under a .step
DIRECT = """\
.param k0=30
.subckt cell p q kk=4
M1 p m={gauss(1, 0.05)} b={unif(0.2, 0.1)} x0={agauss(0.01, 0.002)}
C1 p q k={gauss(kk, 0.05)} a={gauss(1.5, 0.02)}
.ends
.for i 0 2
M{i} n{i} m={unif(1, 0.05)} b=0.3
K{i} n{i} k={gauss(k0*(i+1), 0.05)}
.endfor
X1 n0 n1 cell kk=6
D1 n2 l={gauss(5, 0.1)}
Q1 n1 n2 g={gauss(1.5, 0.1)} a=1
B1 n0 n2 b={gauss(0.25, 0.1)}
P1 c={gauss(0.01, 0.1)} n0^1 n2^1
F1 n0 in gain={gauss(1, 0.1)}
.step k0 list 30 45
.mc 4 seed=3
.tran 1m 0.1
"""
# a global draw (a .param) reaches several elements: each point is elaborated alone
GLOBAL = """\
.param kc={gauss(20, 0.1)}
M1 a m=1 b=0.1
M2 b m=1 b=0.1
K1 a k={kc}
C1 a b k={2*kc}
.mc 3 seed=5
.tran 1m 0.1
"""


def _variation(text: str) -> variation.Variation:
    return variation.read(parse(text, "pop.spr"))


def _same_netlist(a, b) -> None:
    assert a.text() == b.text()
    for table, key in variation.COEFFICIENTS:
        x, y = getattr(getattr(a, table), key), getattr(getattr(b, table), key)
        assert x.dtype == y.dtype and x.tobytes() == y.tobytes(), (table, key)


@pytest.mark.parametrize("text, direct", [(DIRECT, True), (GLOBAL, False)])
def test_each_point_is_its_own_netlist(text: str, direct: bool) -> None:
    var = _variation(text)
    assert variation.direct_draws(var.statements) is direct
    points = var.point_set()
    assert len(points) == var.count
    for point in points.points:
        _same_netlist(points.nets[point.index], var.netlist(point))
    assert len({p.sample for p in points.points}) == var.samples  # the samples do differ
    springs = np.array([net.springs.k for net in points.nets])
    assert np.unique(springs, axis=0).shape[0] == len(points)


def test_grouped_check_equals_each_point_alone() -> None:
    var = _variation(DIRECT)
    points = check_points(var.point_set(), "rk4")
    for point in points.points:
        alone = check(var.netlist(point), "rk4")
        got = points.checked[point.index]
        assert got.step.dt == alone.step.dt
        assert got.modes.omega_max == alone.modes.omega_max
        assert np.array_equal(got.modes.eigenvalues, alone.modes.eigenvalues)
        assert got.step.mode.describe() == alone.step.mode.describe()
        assert [d.message for d in got.diagnostics] == [d.message for d in alone.diagnostics]


def test_failing_point_is_named_as_alone() -> None:
    # sample 2 of k0=45 draws a negative spring (a spread of 60%): the first point that fails
    text = DIRECT.replace("k={gauss(k0*(i+1), 0.05)}", "k={gauss(k0*(i+1), 0.6)}")
    var = _variation(text)
    first = None
    for point in var.points():
        try:
            check(var.netlist(point), "rk4")
        except CheckError as err:
            first = (point, err)
            break
    assert first is not None, "the spread must break a sign rule at some point"
    with pytest.raises(CheckError) as got:
        check_points(var.point_set(), "rk4")
    message = got.value.diagnostics[0].message
    assert message.startswith(first[1].diagnostics[0].message)
    assert message.endswith(f"at {first[0].describe(var.count)}")


def test_stability_of_many_equals_each_alone() -> None:
    """`require_stable_many` (one vectorised pass for a method the check did not compute)
    refuses exactly the points that refuse alone, with the same message, at a step between
    the smallest and largest of their own limits."""
    from springc.check.checks import require_stable_many

    var = _variation(DIRECT)
    points = check_points(var.point_set(), "rk4")
    alone = [check(var.netlist(point), "rk4") for point in points.points]
    limits = [a.step_limit("ssprk3").dt for a in alone]
    h = float(np.median(limits))
    assert min(limits) < h < max(limits)
    got = require_stable_many(list(points.checked), "ssprk3", h, 1)
    for member, err in zip(alone, got):
        try:
            member.require_stable("ssprk3", h, 1)
            expected = None
        except CheckError as own:
            expected = own.diagnostics[0].message
        assert (err.diagnostics[0].message if err else None) == expected
    assert sum(err is not None for err in got) == sum(dt < h for dt in limits) > 0


def test_large_components_take_a_certified_bound_from_the_first() -> None:
    """320 masses (above linear.DENSE_MAX): the first sample is checked as alone; the others
    take its bound by perturbation (`sparse.near`), at or above their own largest eigenvalue
    (Weyl's inequality: no step is judged against an underestimate) and at most
    `sparse.NEAR_MARGIN` above it, so their step limits are at most their own."""
    from springc.bench.population import population_text
    from springc.check.sparse import NEAR_MARGIN

    var = _variation(population_text(masses=320, samples=3))
    points = check_points(var.point_set())
    for point in points.points:
        alone = check(var.netlist(point))
        got = points.checked[point.index]
        assert not got.modes.complete and not alone.modes.near  # the sparse path
        if point.index == 0:
            assert not got.modes.near
            assert (got.modes.omega_max, got.step.dt) == (alone.modes.omega_max, alone.step.dt)
            assert got.modes.eigenvalues.tobytes() == alone.modes.eigenvalues.tobytes()
            continue
        assert got.modes.near
        # alone: ritz <= lambda_max <= bound, ritz = bound / (1 + margin), margin <= 1e-8
        own_low = alone.modes.omega_max ** 2 / (1 + alone.modes.omega_margin)
        assert own_low <= got.modes.omega_max ** 2 <= alone.modes.omega_max ** 2 * (1 + NEAR_MARGIN)
        assert got.modes.omega_margin <= NEAR_MARGIN
        assert got.step.dt <= alone.step.dt


def test_a_step_refused_by_the_bound_is_judged_against_the_points_own() -> None:
    """A pinned step between a sample's limit by perturbation and its own: accepted, with the
    sample's own modes (a population is refused exactly where its points are alone)."""
    from springc.bench.population import population_text

    var = _variation(population_text(masses=320, samples=3))
    near = check_points(var.point_set(), judge_step=False)
    own = [check(var.netlist(p), judge_step=False).step.dt for p in near.points]
    loose = near.checked[1].step.dt
    assert loose < min(own)
    h = (loose + min(own)) / 2
    points = check_points(var.point_set(), tstep=h, substeps=1, judge_step=True)
    assert all(c.step.dt >= h for c in points.checked)
    assert not points.checked[1].modes.near and points.checked[1].step.dt == own[1]
    with pytest.raises(CheckError, match="unstable"):
        check_points(var.point_set(), tstep=1.01 * min(own), substeps=1, judge_step=True)


def test_lockstep_lanczos_runs_equal_lone_runs() -> None:
    # runs of different lengths in one lockstep batch: rank-one matrices end after a step or
    # two (fewer Ritz vectors than asked for), tridiagonal ones run on
    import scipy.sparse as sp

    from springc.check import sparse

    rng = np.random.default_rng(3)
    n = 400
    mats = []
    for k in range(4):
        if k % 2:
            diagonal = sp.diags(3 * rng.uniform(1, 2, n))
            mats.append((sp.diags(np.ones(n - 1), 1) + sp.diags(np.ones(n - 1), -1)
                         + diagonal).tocsr())
        else:
            v = np.zeros(n)
            v[:3] = rng.uniform(1, 3, 3)
            mats.append(sp.csr_matrix(np.outer(v, v)))
    together = sparse.top_many(mats, 6)
    for a, got in zip(mats, together):
        alone = sparse.top_many([a], 6)[0]
        assert (got.bound, got.ritz) == (alone.bound, alone.ritz)
        assert got.vectors.shape == alone.vectors.shape
        assert got.vectors.tobytes() == alone.vectors.tobytes()
    assert {t.vectors.shape[1] for t in together} == {2, 6}
