"""The physics checks: sign rules, nodes without mass, the whole potential and the time step.

Messages are matched whole where they carry numbers that follow from the physics; the golden
cases in `tests/cases/check/*.spr` (header `* expect:` and `* line:`) go through the front end.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np
import pytest
from reference_nets import H16, WS, filter_pair, kicked_pair, net_loc

from springc.check import checks
from springc.lang import physics
from springc.errors import CheckError, SimulationError
from springc.kernels.integrators import get_tableau, max_stable_step, stability_polynomial
from springc.lang.ir import IRBuilder, Tran
from springc.lang import load_file
from springc.sim.simulate import simulate
from springc.check import check

CASES = sorted((Path(__file__).resolve().parent / "cases" / "check").glob("*.spr"))
_HEADER = re.compile(r"^\* (expect|line): (.*)$")


def _errors(net) -> list[str]:
    return [d.message for d in checks.diagnose(net).errors]


def _two(build) -> IRBuilder:
    b = IRBuilder(file="net.spr")
    b.mass("M1", "x1", 1.0, loc=net_loc(1))
    b.mass("M2", "x2", 1.0, loc=net_loc(2))
    build(b)
    return b.finish()


@pytest.mark.parametrize("build,message", [
    (lambda b: b.mass("M3", "x1", 0.0), "M3: mass m=0 must be > 0"),
    (lambda b: b.mass("M3", "x1", -2.0), "M3: mass m=-2 must be > 0"),
    (lambda b: b.mass("M3", "x1", 1.0, b=-1.0), "M3: damping b=-1 must be >= 0"),
    (lambda b: b.spring("K1", "x1", -3.0), "K1: stiffness k=-3 must be >= 0"),
    (lambda b: b.duffing("D1", "x1", -0.5), "D1: Duffing coefficient l=-0.5 must be >= 0"),
    (lambda b: b.coupling("C1", "x1", "x2", 1.0, 0.0), "C1: leverage a=0 must be != 0"),
    (lambda b: b.coupling("C1", "x1", "x2", -1.0, 2.0), "C1: k/a=-0.5 must be >= 0"),
    (lambda b: b.quad("Q1", "x1", "x2", 1.0, 0.0), "Q1: leverage a=0 must be != 0"),
    (lambda b: b.quad("Q1", "x1", "x2", 2.0, -4.0), "Q1: g/a=-0.5 must be >= 0"),
    (lambda b: b.dashpot("B1", "x1", "0", -1.0), "B1: dashpot b=-1 must be >= 0"),
    (lambda b: b.monomial("P1", 1.0, [("x1", -2)]),
     "P1: exponent -2 of x1 must be a non-negative integer"),
])
def test_sign_rules(build, message) -> None:
    result = checks.diagnose(_two(build))
    assert [d.message for d in result.errors] == [message]
    assert result.errors[0].hint


@pytest.mark.parametrize("build,message", [
    (lambda b: b.mass("M3", "x1", 1e-300), "M3: m=1e-300 is outside the range"),
    (lambda b: b.spring("K1", "x1", 1e151), "K1: k=1e+151 is outside the range"),
    (lambda b: b.quad("Q1", "x1", "x2", -1.0, -1e-200), "Q1: a=-1e-200 is outside the range"),
])
def test_coefficients_whose_products_leave_the_doubles(build, message) -> None:
    # k/m of such values overflows: refused, and no numpy warning is printed on the way
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        errors = _errors(_two(build))
    assert len(errors) == 1 and errors[0].startswith(message), errors


@pytest.mark.parametrize("build,good,bad", [
    (lambda b, v: b.spring("K1", "x1", v), 3.0, -3.0),
    (lambda b, v: b.coupling("C1", "x1", "x2", v, 2.0), 1.0, -1.0),
    (lambda b, v: b.quad("Q1", "x1", "x2", 1.0, v), 1.0, 0.0),
    (lambda b, v: b.dashpot("B1", "x1", "0", v), 1.0, -1.0),
    (lambda b, v: b.spring("K1", "x1", v), 3.0, 1e151),
    (lambda b, v: b.mass("M3", "x1", v), 1.0, 1e-300),
])
def test_a_population_is_checked_as_each_netlist_alone(build, good, bad) -> None:
    """check_many applies the sign and range rules to a population's coefficients at once:
    the netlist that breaks one gets the errors it gets alone, the others pass."""
    nets = [_two(lambda b, v=v: build(b, v)) for v in (good, bad, good)]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        results = checks.check_many(nets)
    assert isinstance(results[0], checks.CheckedNetlist)
    assert isinstance(results[2], checks.CheckedNetlist)
    assert isinstance(results[1], CheckError)
    assert [d.message for d in results[1].diagnostics] == _errors(nets[1])


def test_negative_leverage_with_negative_k_is_legal() -> None:
    """k/a >= 0 is the rule, not k >= 0: C with k=-1, a=-1 is V = 1/2 (x1 + x2)^2."""
    assert _errors(_two(lambda b: b.coupling("C1", "x1", "x2", -1.0, -1.0))) == []


def test_every_bad_element_is_reported_with_its_location() -> None:
    def build(b):
        b.spring("K1", "x1", -1.0, loc=net_loc(3))
        b.spring("K2", "x2", -2.0, loc=net_loc(4))
    result = checks.diagnose(_two(build))
    assert [d.loc.line for d in result.errors] == [3, 4]
    assert result.errors[0].format().startswith("net.spr:3:1: error: K1: stiffness k=-1")


def test_massless_node_points_at_first_element_naming_it() -> None:
    def build(b):
        b.coupling("C1", "x1", "x3", 1.0, loc=net_loc(7))
        b.probe("x", "x3", loc=net_loc(9))
        b.spring("K3", "x3", 1.0, loc=net_loc(5))
    diag, = checks.diagnose(_two(build)).errors
    assert diag.message == "node 'x3' has no mass (named by K3, but no M element declares it)"
    assert diag.loc.line == 5
    assert "M_x3 x3 m=1" in diag.hint


def _poly(terms: list[tuple[float, list[tuple[str, int]]]], build=None):
    def add(b):
        for idx, (c, factors) in enumerate(terms):
            b.monomial(f"P{idx + 1}", c, factors, loc=net_loc(10 + idx))
        if build:
            build(b)
    return _two(add)


def _direction(message: str) -> dict[str, float]:
    inside = message[message.rindex("(") + 1:message.rindex(")")]
    parts = [part.split("=") for part in inside.split(", ") if part != "..."]
    return {k: float(v) for k, v in parts}


def test_cubic_escape_direction() -> None:
    """V = x1^2 - x1^2 x2 + x2^2: along the reported direction V(t u) -> -inf like t^3."""
    net = _poly([(1, [("x1", 2)]), (-1, [("x1", 2), ("x2", 1)]), (1, [("x2", 2)])])
    msg, = _errors(net)
    assert msg.startswith("P1: the potential is not bounded below")
    u = _direction(msg)
    top = -u["x1"] ** 2 * u["x2"]  # the cubic part at u: must be negative
    assert top < -0.38  # the minimum over the unit sphere is -2/(3 sqrt 3) = -0.3849
    from springc.lang.physics import potential
    x = np.array([u["x1"], u["x2"]])
    assert potential(net, 1e3 * x) < -1e8 and potential(net, 1e4 * x) < -1e11


def test_negative_stiffness_is_not_psd() -> None:
    msg, = _errors(_poly([(-1, [("x1", 2)])]))
    assert msg == ("P1: the stiffness matrix at rest is not positive semidefinite: curvature -2 "
                   "along (x1=1)")


def test_negative_quartic_is_unbounded() -> None:
    msg, = _errors(_poly([(-1, [("x1", 4)])], lambda b: b.spring("K1", "x1", 1.0)))
    assert msg == "P1: the potential is not bounded below: V decreases without bound along (x1=1)"


def test_linear_term_escapes_along_its_descent() -> None:
    """V = x1^2 + x2: PSD Hessian, but V -> -inf as x2 -> -inf (the sign is kept)."""
    msg, = _errors(_poly([(1, [("x1", 2)]), (1, [("x2", 1)])]))
    assert msg.endswith("along (x2=-1)")


def test_bounded_polynomial_is_accepted() -> None:
    """x1^4 + x2^4 - x1^2 x2: the quartic part is positive definite."""
    net = _poly([(1, [("x1", 4)]), (1, [("x2", 4)]), (-1, [("x1", 2), ("x2", 1)])])
    assert _errors(net) == []


def test_vanishing_top_form_needs_the_sphere_search() -> None:
    """Q's quartic (x1^4/2) vanishes along x2: with -x2 the potential falls along the valley
    x2 = x1^2; with +x2^2 instead it is bounded."""

    def quad(b):
        b.quad("Q1", "x1", "x2", 1.0)

    msg, = _errors(_poly([(-1, [("x2", 1)])], quad))
    u = _direction(msg)
    assert u["x2"] > 0.99
    assert _errors(_poly([(1, [("x2", 2)])], quad)) == []


def _squarer_with_negative_spring(c: float):
    """x1 squared onto x2 by Q (g=2, a=1: V_Q = (x1^2 - x2)^2, stiffness 2 on x2 at rest), a
    soft local spring 0.01 on x2 and a quadratic P term c x2^2."""
    def build(b):
        b.spring("K1", "x1", 1.0)
        b.spring("K2", "x2", 0.01)
        b.quad("Q1", "x1", "x2", 2.0, 1.0)
        b.monomial("P1", c, [("x2", 2)])
    return _two(build)


def test_sum_of_nonnegative_parts_is_bounded_without_a_search() -> None:
    # K without the Q's share is diag(1, 0.01 + 2c): PSD for c = -0.004, so V >= 0 visibly
    net = _squarer_with_negative_spring(-0.004)
    lin = _hessian_at_rest(net)
    labels = np.zeros(net.n, np.int64)
    assert checks._visibly_bounded(net, lin, labels, 0, np.arange(net.n))
    assert _errors(net) == []


def test_a_negative_spring_hidden_by_a_squarer_is_found_by_the_search() -> None:
    # V = x1^2/2 - 0.495 x2^2 + (x1^2 - x2)^2 is PSD at rest (x2: 0.01 - 0.99 + 2) but falls
    # along x2 = x1^2: the shortcut must not accept it, the search must find the descent
    net = _squarer_with_negative_spring(-0.5)
    lin = _hessian_at_rest(net)
    labels = np.zeros(net.n, np.int64)
    assert not checks._visibly_bounded(net, lin, labels, 0, np.arange(net.n))
    assert [e.split(":")[0] for e in _errors(net)] == ["P1"]
    assert "not bounded below" in _errors(net)[0]


@pytest.mark.parametrize("c, factors, visible", [
    (0.3, [("x1", 2), ("x2", 2)], True),  # a square: >= 0 wherever it is
    (0.3, [("x2", 4)], True),
    (-0.3, [("x1", 2), ("x2", 2)], False),  # negative: only the search can tell
    (0.3, [("x1", 2), ("x2", 1)], False),  # an odd exponent changes sign
])
def test_squares_of_higher_degree_are_bounded_without_a_search(c, factors, visible) -> None:
    """With the squarer's PSD quadratic part (c = -0.004 above), a P term that is a square
    keeps V >= 0: the shortcut accepts it, and the search that it saves finds no descent
    either. Signed and odd terms are left to the search."""
    def build(b):
        b.spring("K1", "x1", 1.0)
        b.spring("K2", "x2", 0.01)
        b.quad("Q1", "x1", "x2", 2.0, 1.0)
        b.monomial("P1", -0.004, [("x2", 2)])
        b.monomial("P2", c, factors, loc=net_loc(12))
    net = _two(build)
    lin = _hessian_at_rest(net)
    labels = np.zeros(net.n, np.int64)
    assert checks._visibly_bounded(net, lin, labels, 0, np.arange(net.n)) is visible
    if visible:
        assert checks._escape(net, lin, labels, 0) is None


def _hessian_at_rest(net):
    """The Hessian of V at rest, as the checks build it."""
    from springc.check import linear
    return linear.linearise(net).K.tocsr()


def test_designed_zero_modes_pass_the_psd_check() -> None:
    """K = I - U U^T written as P elements (like a matrix-vector multiplier): PSD with
    exactly rank(U) zero modes, reported as one info."""
    rng = np.random.default_rng(1)
    n, r = 6, 2
    u, _ = np.linalg.qr(rng.normal(size=(n, r)))
    k = np.eye(n) - u @ u.T
    b = IRBuilder(file="net.spr")
    for i in range(n):
        b.mass(f"M{i}", f"n{i}", 1.0)
        b.monomial(f"P{i}_{i}", k[i, i] / 2, [(f"n{i}", 2)])
        for j in range(i + 1, n):
            b.monomial(f"P{i}_{j}", k[i, j], [(f"n{i}", 1), (f"n{j}", 1)])
    result = checks.diagnose(b.finish())
    assert result.errors == []
    info, = result.notes
    assert info.severity == "info" and info.message.startswith("2 zero-stiffness modes")
    assert result.modes.zero_count == 2


def _oscillator(w: float, tstep: float | None = None, method: str | None = None):
    b = IRBuilder(file="net.spr")
    b.mass("M1", "a", 2.0, loc=net_loc(1))
    b.spring("K1", "a", 2.0 * w**2, loc=net_loc(2))
    if tstep:
        b.tran = Tran(tstep, 1.0, net_loc(3))
    if method:
        b.options["method"] = method
    return b.finish()


def test_rk4_limit_of_an_oscillator() -> None:
    """RK4 on the imaginary axis is stable up to |h lambda| = 2 sqrt 2."""
    w = 2 * np.pi * 1000
    result = checks.check(_oscillator(w))
    assert result.step.dt == pytest.approx(2 * np.sqrt(2) / w, rel=1e-6)


def test_unstable_step_names_the_mode_and_the_largest_stable_step() -> None:
    """A pinned step (here the method named) above the limit is refused; unpinned, the
    checks leave it to the integration the simulator chooses."""
    w = 2 * np.pi * 1000
    assert checks.check(_oscillator(w, tstep=1e-3)).tstep == 1e-3
    with pytest.raises(CheckError) as info:
        checks.check(_oscillator(w, tstep=1e-3), "rk4")
    diag, = info.value.diagnostics
    assert diag.loc.line == 3
    assert diag.message == (
        "time step 0.001 s is unstable for rk4: the oscillating mode at 1000 Hz (6283.19 rad/s), "
        "damping rate 0 1/s, Q inf, dominant nodes a (1.00) needs a step <= 0.000450158 s "
        "(largest stable step)")
    assert diag.hint == "use .tran tstep <= 0.000450158, or .options substeps=3"


def test_substeps_make_the_step_stable() -> None:
    net = _oscillator(2 * np.pi * 1000, tstep=1e-3)
    net.options["substeps"] = 3
    assert checks.check(net).tstep == pytest.approx(1e-3 / 3)


def test_midpoint_cannot_integrate_an_undamped_oscillator() -> None:
    result = checks.diagnose(_oscillator(10.0, tstep=1e-3, method="midpoint"))
    assert result.step.dt == 0.0
    assert "midpoint is unstable for this mode at any step" in result.errors[0].hint


def test_overdamped_mode_limits_the_step() -> None:
    """m=1, b=100, k=1 (Q = 0.01): the fast real eigenvalue limits RK4 to 2.785/|lambda|."""
    b = IRBuilder()
    b.mass("M1", "a", 1.0, 100.0)
    b.spring("K1", "a", 1.0)
    result = checks.check(b.finish())
    fast = (100 + np.sqrt(100**2 - 4)) / 2
    # Real-axis limit of RK4: the negative root of R(z) = 1, i.e. of 1 + z/2 + z^2/6 + z^3/24.
    coeffs = stability_polynomial(get_tableau("rk4"))[1:]
    roots = np.roots(coeffs[::-1])
    edge = float(-roots[np.abs(roots.imag) < 1e-12].real.min())
    assert edge == pytest.approx(2.785293563, abs=1e-8)
    assert result.step.dt * fast == pytest.approx(edge, rel=1e-6)
    assert result.step.mode.lam.imag == 0 and result.step.mode.q == 0.5


def test_free_body_is_an_info_not_an_error() -> None:
    b = IRBuilder(file="net.spr")
    b.mass("M1", "free", 1.0, loc=net_loc(4))
    b.tran = Tran(1e-3, 1.0, net_loc(5))
    result = checks.check(b.finish())
    info, = result.notes
    assert (info.severity, info.loc.line) == ("info", 4)
    assert info.message == "1 zero-stiffness mode (free motion), dominant nodes free"
    assert result.step.dt == np.inf


def test_method_override_and_unknown_method() -> None:
    net = _oscillator(10.0)
    assert checks.check(net, method="ssprk3").method == "ssprk3"
    msg, = _errors_with(net, "rk5")
    assert msg == "unknown integrator 'rk5'"


def _errors_with(net, method: str) -> list[str]:
    return [d.message for d in checks.diagnose(net, method).errors]


def test_large_network_checks_through_the_sparse_path() -> None:
    """A 10,000-element netlist: a 5,000-mass chain with fixed ends (sparse Lanczos) plus an
    all-to-all block of 60 masses (dense, one zero mode)."""
    n, k, m = 5000, 3.0, 2.0
    b = IRBuilder()
    for i in range(n):
        b.mass(f"M{i}", f"n{i}", m)
    b.spring("KL", "n0", k)
    b.spring("KR", f"n{n - 1}", k)
    for i in range(n - 1):
        b.coupling(f"C{i}", f"n{i}", f"n{i + 1}", k)
    for i in range(60):
        b.mass(f"A{i}", f"a{i}", 1.0)
        for j in range(i):
            b.coupling(f"CA{i}_{j}", f"a{i}", f"a{j}", 0.01)
    result = checks.check(b.finish())
    chain = 2 * np.sqrt(k / m) * np.sin(n * np.pi / (2 * (n + 1)))
    # the sparse path's omega_max is an upper bound, above the truth by at most its margin
    margin = result.modes.omega_margin
    assert chain * (1 - 1e-12) <= result.modes.omega_max
    assert result.modes.omega_max**2 <= chain**2 * (1 + margin) * (1 + 1e-12)
    assert margin < 1e-5
    assert result.step.dt == pytest.approx(2 * np.sqrt(2) / chain, rel=1e-6)
    assert result.modes.zero_count == 1


def _header(path: Path) -> dict[str, str]:
    out = {}
    for line in path.read_text().splitlines():
        match = _HEADER.match(line)
        if not match:
            break
        out[match.group(1)] = match.group(2).strip()
    return out


def test_enough_cases() -> None:
    assert len(CASES) >= 15


@pytest.mark.parametrize("case", CASES, ids=lambda p: p.stem)
def test_check_case(case: Path) -> None:
    header = _header(case)
    with pytest.raises(CheckError) as info:
        checks.check(load_file(case))
    text = info.value.format()
    assert header["expect"] in text
    assert info.value.loc.line == int(header["line"]), text
    assert "^" in text and "hint:" in text


def _long_chain(extra, fixed: bool = True, n: int = 400):
    """A chain longer than linear.DENSE_MAX, so the whole-potential check goes sparse."""
    b = IRBuilder()
    for i in range(n):
        b.mass(f"M{i}", f"n{i}", 1.0)
        if i:
            b.coupling(f"C{i}", f"n{i - 1}", f"n{i}", 1.0)
    if fixed:
        b.spring("KL", "n0", 1.0)
    extra(b)
    return b.finish()


def test_large_component_negative_curvature() -> None:
    """K = chain Laplacian + grounding with K_200,200 lowered by 6: one negative eigenvalue,
    -4.32456 (scipy's dense eigvalsh of the same matrix, to 6 digits)."""
    net = _long_chain(lambda b: b.monomial("P1", -3.0, [("n200", 2)]))
    msg, = _errors(net)
    from springc.lang.physics import stiffness_matrix
    lowest = np.linalg.eigvalsh(stiffness_matrix(net))[0]
    assert f"curvature {lowest:.6g} along (n200=0.974" in msg


def test_constant_force_on_a_free_chain_is_unbounded() -> None:
    """V = 1/2 x.L x + x_2 / 2 with L a free chain's Laplacian: V -> -inf under a rigid
    translation to -inf (every node -1/sqrt(n)); a grounded chain is bounded."""
    for n in (10, 400):
        msg, = _errors(_long_chain(lambda b: b.monomial("P1", 0.5, [("n2", 1)]), False, n))
        u = _direction(msg)
        np.testing.assert_allclose(list(u.values()), -1 / np.sqrt(n), rtol=2e-3)  # 3 digits
        assert _errors(_long_chain(lambda b: b.monomial("P1", 0.5, [("n2", 1)]), True, n)) == []


def test_large_component_quartics() -> None:
    """Only the variables of non-quadratic terms are searched. (x200^4 + x201^4)/4 - x200^2
    x201^2 is negative along x200 = +-x201, so V falls there; with -0.1 x200^2 x201 instead
    the quartic form is positive definite and V is bounded."""
    def bad(b):
        b.duffing("D1", "n200", 1.0)
        b.duffing("D2", "n201", 1.0)
        b.monomial("P1", -1.0, [("n200", 2), ("n201", 2)])
    def good(b):
        b.duffing("D1", "n200", 1.0)
        b.duffing("D2", "n201", 1.0)
        b.monomial("P1", -0.1, [("n200", 2), ("n201", 1)])
    msg, = _errors(_long_chain(bad))
    u = _direction(msg)
    assert abs(u["n200"]) == pytest.approx(abs(u["n201"]), rel=1e-3)
    assert _errors(_long_chain(good)) == []


# --- split schemes (springc.kernels.expint): blocks exact, the inner RK4 on the rest --------------

G_SQUARE = 1e3  # squarers from the filters into the slow part


def _fast_pairs(stiff: float | None = None):
    """Filter pairs at 7 and 8 kHz (omega h = 3.0 and 3.5 at 16 kHz, past RK4's 2.83)
    squared into a slow coupled pair r, s; `stiff`: a node t with that omega, coupled to s."""
    b = IRBuilder(file="net.spr")
    filter_pair(b, "xa", "xb", 2 * np.pi * 7000, 1)
    filter_pair(b, "xc", "xd", 2 * np.pi * 8000, 5)
    for node in ("r", "s"):
        b.mass(f"M{node}", node, 1.0, 20.0, loc=net_loc(10))
        b.spring(f"K{node}", node, WS**2, loc=net_loc(11))
    b.coupling("Crs", "r", "s", WS**2 / 4, loc=net_loc(12))
    b.quad("Qbr", "xb", "r", G_SQUARE, loc=net_loc(13))
    b.quad("Qds", "xd", "s", G_SQUARE, loc=net_loc(14))
    if stiff:
        b.mass("Mt", "t", 1.0, loc=net_loc(15))
        b.spring("Kt", "t", stiff**2, loc=net_loc(16))
        b.coupling("Cst", "s", "t", 1e3, loc=net_loc(17))
    b.tran = Tran(H16, 0.05, net_loc(20))
    return b.finish()


def _eigenvalues(stiffness: np.ndarray, damping: np.ndarray) -> np.ndarray:
    """First-order eigenvalues of x'' + B x' + K x = 0 (unit masses)."""
    n = len(stiffness)
    a = np.block([[np.zeros((n, n)), np.eye(n)], [-stiffness, -damping]])
    return np.linalg.eigvals(a)


def _rest_limit(stiff: float | None = None, tableau: str = "rk4") -> float:
    """The tableau's largest stable step on the slow part alone (plus t): r, s with their
    springs, the coupling and the squarers' stiffness g a at rest (on r and s, their j
    nodes)."""
    k = WS**2 * np.array([[1.25, -0.25], [-0.25, 1.25]]) + G_SQUARE * np.eye(2)
    damp = np.diag([20.0, 20.0])
    if stiff:
        k = np.pad(k, (0, 1))
        k[1, 1] += 1e3
        k[2, 2] = stiff**2 + 1e3
        k[1, 2] = k[2, 1] = -1e3
        damp = np.pad(damp, (0, 1))
    return max_stable_step(get_tableau(tableau), _eigenvalues(k, damp))[0]


def _unstable_step(error: CheckError, method_and_mode: str, dominant: str, need: float):
    """The one diagnostic of an unstable 16 kHz step on line 20 of `_fast_pairs`: method and
    mode, dominant nodes and the largest stable step `need`."""
    diag, = error.diagnostics
    assert diag.loc.line == 20
    assert diag.message.startswith(f"time step 6.25e-05 s is unstable for {method_and_mode}")
    assert f"dominant nodes {dominant}" in diag.message
    assert diag.message.endswith(f"needs a step <= {need:.6g} s (largest stable step)")
    return diag


def test_rk4_rejects_fast_filter_pairs_with_the_step_they_need() -> None:
    net = _fast_pairs()
    need = max_stable_step(get_tableau("rk4"), _eigenvalues(
        physics.stiffness_matrix(net), physics.damping_matrix(net)))[0]
    # about 2 sqrt 2 / omega of the 8.8 kHz mode (its damping, 200/s, moves it by 0.3%)
    assert 2 * np.sqrt(2) / (1.1 * 2 * np.pi * 8000) == pytest.approx(need, rel=5e-3)
    with pytest.raises(CheckError) as info:
        checks.check(net, "rk4")
    diag = _unstable_step(info.value, "rk4: the oscillating mode at 8800 Hz (55292 rad/s), "
                          "damping rate 200 1/s", "xc (1.00), xd (1.00)", need)
    assert diag.hint.endswith(".options substeps=2")


@pytest.mark.parametrize("method", ["exp-rk4", "strang-rk4", "exp-heun3"])
def test_split_scheme_takes_the_step_the_rest_allows(method: str) -> None:
    """The filter pairs are integrated exactly: only the slow part limits the step, at the
    inner tableau's limit on it."""
    result = checks.check(_fast_pairs(), method=method)
    assert result.errors == [] and result.method == method
    inner = "heun3" if method == "exp-heun3" else "rk4"
    assert result.step.dt == pytest.approx(_rest_limit(tableau=inner), rel=1e-6)
    assert result.step.dt > 50 * H16  # the pairs alone would need < H16 under RK4
    assert {n for n, _ in result.step.mode.dominant(2)} == {"r", "s"}
    assert [list(nodes) for nodes in result.blocks.nodes] == [[0, 1], [2, 3]]


def test_split_scheme_rejects_a_stiff_rest_naming_its_mode() -> None:
    """A 9 kHz node outside the blocks (omega h = 3.5) is integrated by RK4: rejected."""
    w = 2 * np.pi * 9000
    need = _rest_limit(stiff=w)
    assert need == pytest.approx(2 * np.sqrt(2) / w, rel=1e-3)
    with pytest.raises(CheckError) as info:
        checks.check(_fast_pairs(stiff=w), method="exp-rk4")
    _unstable_step(info.value, "exp-rk4: the oscillating mode at 9000", "t (1.00)", need)


def test_split_scheme_without_blocks_has_the_limit_of_rk4() -> None:
    net = _oscillator(2 * np.pi * 1000)  # no input force: nothing to integrate exactly
    rk4 = checks.check(net).step.dt
    assert checks.check(net, method="exp-rk4").step.dt == pytest.approx(rk4, rel=1e-12)
    assert checks.check(net, method="strang-rk4").step.dt == pytest.approx(rk4, rel=1e-12)


def test_unknown_method_lists_every_integrator() -> None:
    net = _oscillator(10.0)
    diag, = checks.diagnose(net, "rk5").errors
    assert diag.message == "unknown integrator 'rk5'"
    assert diag.hint == ("known: rk4, rk38, ssprk3, heun3, midpoint, strang-rk4, exp-rk4, "
                         "exp-heun3")
    net.options["method"] = "exp_rk4"  # the spelling .options takes
    assert checks.check(net).method == "exp-rk4"


def _growth(net) -> float:
    """Largest |x(xb)| over the last quarter of a noise-driven run over that of the first
    quarter (inf if the divergence guard stops it). Above the limit on purpose: the step is
    not judged, the run confirms the limit."""
    rng = np.random.default_rng(0)
    u = 1e-3 * rng.normal(size=(1, 1, int(net.tran.tstop / net.tran.tstep) + 2))
    try:
        x = simulate(check(net, judge_step=False), u, check_step=False).probes["x(xb)"][0]
    except SimulationError:
        return np.inf
    quarter = len(x) // 4
    return float(np.abs(x[-quarter:]).max() / np.abs(x[:quarter]).max())


@pytest.mark.parametrize(("method", "limit"), [("exp-rk4", 6.0475e-5), ("strang-rk4", 5.7907e-5),
                                               ("exp-heun3", 6.0117e-5)])
def test_kicked_block_limit_is_where_the_scheme_starts_to_grow(method: str, limit: float) -> None:
    """A 3 kHz kick on a 7 kHz block: RK4 on the kick alone would allow 2.83 / omega = 1.5e-4
    s, yet the scheme's step map grows from ~6e-5 s, below the 16 kHz step (an island: 1e-4 s
    is stable again). The check finds the limit; simulation confirms it on both sides."""
    result = checks.diagnose(kicked_pair(3000.0, H16, method))
    assert result.step.dt == pytest.approx(limit, rel=1e-4)
    assert 2 * np.sqrt(2) / (2 * np.pi * 3000) > 2 * H16
    assert "dominant nodes xb (1.00)" in result.errors[0].message
    h = result.step.dt
    assert _growth(kicked_pair(3000.0, 0.98 * h, method, tstop=0.2)) < 2
    assert _growth(kicked_pair(3000.0, 1.02 * h, method, tstop=0.2)) > 1e3
