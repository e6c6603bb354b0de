"""The physics checks: sign rules, nodes without mass, the whole potential and the time step.

Messages are matched whole where they carry numbers that follow from the physics; the golden
cases in `tests/cases/check/*.spr` (header `* expect:` and `* line:`) go through the front end.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from springc import checks
from springc.errors import CheckError, SourceLoc
from springc.integrators import get_tableau, stability_polynomial
from springc.ir import IRBuilder, Tran
from springc.lang import load_file

CASES = sorted((Path(__file__).resolve().parent / "cases" / "check").glob("*.spr"))
_HEADER = re.compile(r"^\* (expect|line): (.*)$")


def _loc(line: int) -> SourceLoc:
    return SourceLoc("net.spr", line, 1)


def _errors(net) -> list[str]:
    return [d.message for d in checks.diagnose(net).errors]


def _two(build) -> IRBuilder:
    b = IRBuilder(file="net.spr")
    b.mass("M1", "x1", 1.0, loc=_loc(1))
    b.mass("M2", "x2", 1.0, loc=_loc(2))
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


def test_negative_leverage_with_negative_k_is_legal() -> None:
    """k/a >= 0 is the rule, not k >= 0: C with k=-1, a=-1 is V = 1/2 (x1 + x2)^2."""
    assert _errors(_two(lambda b: b.coupling("C1", "x1", "x2", -1.0, -1.0))) == []


def test_every_bad_element_is_reported_with_its_location() -> None:
    def build(b):
        b.spring("K1", "x1", -1.0, loc=_loc(3))
        b.spring("K2", "x2", -2.0, loc=_loc(4))
    result = checks.diagnose(_two(build))
    assert [d.loc.line for d in result.errors] == [3, 4]
    assert result.errors[0].format().startswith("net.spr:3:1: error: K1: stiffness k=-1")


def test_massless_node_points_at_first_element_naming_it() -> None:
    def build(b):
        b.coupling("C1", "x1", "x3", 1.0, loc=_loc(7))
        b.probe("x", "x3", loc=_loc(9))
        b.spring("K3", "x3", 1.0, loc=_loc(5))
    diag, = checks.diagnose(_two(build)).errors
    assert diag.message == "node 'x3' has no mass (named by K3, but no M element declares it)"
    assert diag.loc.line == 5
    assert "M_x3 x3 m=1" in diag.hint


def _poly(terms: list[tuple[float, list[tuple[str, int]]]], build=None):
    def add(b):
        for idx, (c, factors) in enumerate(terms):
            b.monomial(f"P{idx + 1}", c, factors, loc=_loc(10 + idx))
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
    from springc.physics import potential
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
    quad = lambda b: b.quad("Q1", "x1", "x2", 1.0)
    msg, = _errors(_poly([(-1, [("x2", 1)])], quad))
    u = _direction(msg)
    assert u["x2"] > 0.99
    assert _errors(_poly([(1, [("x2", 2)])], quad)) == []


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
    b.mass("M1", "a", 2.0, loc=_loc(1))
    b.spring("K1", "a", 2.0 * w**2, loc=_loc(2))
    if tstep:
        b.tran = Tran(tstep, 1.0, _loc(3))
    if method:
        b.options["method"] = method
    return b.finish()


def test_rk4_limit_of_an_oscillator() -> None:
    """RK4 on the imaginary axis is stable up to |h lambda| = 2 sqrt 2."""
    w = 2 * np.pi * 1000
    result = checks.check(_oscillator(w))
    assert result.step.dt == pytest.approx(2 * np.sqrt(2) / w, rel=1e-6)


def test_unstable_step_names_the_mode_and_the_largest_stable_step() -> None:
    w = 2 * np.pi * 1000
    with pytest.raises(CheckError) as info:
        checks.check(_oscillator(w, tstep=1e-3))
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
    b.mass("M1", "free", 1.0, loc=_loc(4))
    b.tran = Tran(1e-3, 1.0, _loc(5))
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
    assert result.modes.omega_max == pytest.approx(chain, rel=1e-10)
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
    from springc.physics import stiffness_matrix
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
