"""springc/design/squaring.py: the squaring unit of the paper's Fig. 6c-d (one quadratic
coupling from a matched delay line into a leaky-integrator readout), against the physics."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from springc.design import figures
from springc.design import squaring as sq

EPS = np.array([1e-4, 1e-3, 1e-2, 1e-1, 1.0])


@pytest.fixture(scope="module")
def sweep():
    """One batch through one kernel: the eps -> 0 reference and five decades of eps."""
    return sq.sweep(epsilons=EPS)


def test_eps_definition_round_trips():
    """alpha for (A, gamma, eps) gives back eps; the amplitude for eps too."""
    alpha = sq.leverage_for(0.3, 2.0, 1e-2, 0.25)
    assert sq.squaring_error(0.3, 2.0, alpha, 0.25) == pytest.approx(1e-2, rel=1e-14)
    assert sq.amplitude_for(1e-2, 2.0, alpha, 0.25) == pytest.approx(0.3, rel=1e-14)


def test_small_eps_limit_is_the_analytic_leaky_integrated_square(sweep):
    """At eps -> 0 the readout is gamma A^2 / D times exponentially modified Gaussians of the
    pulse's square (the readout's two poles): within 1% at the peak and 1e-3 of the peak in
    shape (the line's dispersion; measured 0.36% and 2e-4)."""
    amp = sq.amplitude_for(sq.EPS_REFERENCE, sweep.unit.gamma, sweep.unit.alpha, sq.KC)
    exact = sq.small_eps_readout(sweep.unit, sweep.t, float(amp))
    ideal_peak = sweep.x_r[0].max() / sweep.gain[0] / (sweep.amplitude[0] / amp) ** 2
    assert ideal_peak == pytest.approx(exact.max(), rel=1e-2)
    assert np.max(np.abs(sweep.ideal - exact / exact.max())) < 1e-3


def test_distortion_vanishes_linearly_as_eps_goes_to_zero(sweep):
    """Back-action and the cubic stiffness are first order in eps: the distortion falls ten
    times per decade towards eps -> 0 (measured 9.7) and the gain goes to 1."""
    d = sweep.distortion
    assert d[0] < 2e-4
    assert d[1] / d[0] == pytest.approx(10, rel=0.1)
    assert sweep.gain[0] == pytest.approx(1, abs=2e-3)
    assert d[3] > 100 * d[0]  # the high-distortion region of the paper's Fig. 6c-d


def test_energy_transfer_rises_with_eps(sweep):
    """E_out / E_in = (eps kc / (gamma alpha)) b_r int v'^2 / (input work / A^2): proportional
    to eps at small eps (log slope 1), rising up to eps = 1."""
    logt = np.log10(sweep.transfer)
    assert np.all(np.diff(logt) > 0)
    assert logt[1] - logt[0] == pytest.approx(1, abs=0.03)


def test_eps_alone_sets_the_response(sweep):
    """The paper's nondimensionalisation: at fixed gamma alpha, eps reached through gamma and
    alpha instead of the amplitude gives the same distortion and energy transfer."""
    other = dataclasses.replace(sweep.unit, gamma=30 * sweep.unit.gamma)
    again = sq.sweep(other, epsilons=EPS[3:4])
    assert again.distortion[0] == pytest.approx(sweep.distortion[3], rel=1e-6)
    assert again.transfer[0] == pytest.approx(sweep.transfer[3], rel=1e-6)


def _reference_ode(unit: sq.Unit, amplitude: float):
    """The unit's equations of motion written out for scipy: line sites x_1..x_n (mass
    ts^2 kc, local kl, couplings kc, matched dampers at both ends) driven at x_1 by the
    sampled force, the coupling
    V = g/(2a) (x_n^2 - a x_r)^2 and the readout (m = 1, b_r, no spring of its own)."""
    n, m, kc = unit.sites, unit.ts**2 * unit.kc, unit.kc
    kl, z = 1e-6 * kc, unit.ts * kc
    g, a, br = unit.gamma, unit.alpha, unit.readout.b
    tstep = unit.ts / 10
    samples = np.append(unit.forces(np.array([amplitude]), tstep)[0, 0], 0.0)
    grid = np.arange(len(samples)) * tstep

    def force(t):  # the samples springc is given, linearly interpolated, then 0 one step on
        return float(np.interp(t, grid, samples, right=0.0))

    def rhs(t, y):
        x, v = y[: n + 1], y[n + 1:]
        f = np.zeros(n + 1)
        xs = x[:n]
        f[:n] = -kl * xs
        f[: n - 1] += kc * (xs[1:] - xs[:-1])
        f[1:n] -= kc * (xs[1:] - xs[:-1])
        f[0] += force(t) - z * v[0]
        f[n - 1] += -z * v[n - 1] - 2 * g / a * (xs[-1] ** 2 - a * x[n]) * xs[-1]
        f[n] = g * (xs[-1] ** 2 - a * x[n]) - br * v[n]
        mass = np.r_[np.full(n, m), 1.0]
        return np.r_[v, f / mass]

    return rhs


def test_one_point_against_scipy(sweep):
    """eps = 0.1 (strong back-action): springc's RK4 readout against scipy's DOP853 of the
    same equations, within 1e-8 of the readout's peak.

    The bound is what the reference certifies: the readout (peak 2.7e-5) is the smallest
    state, so DOP853's absolute tolerance is set a million times below it (1e-18 with rtol
    1e-12); the reference then moves by 1.1e-10 of the peak when both tolerances are
    tightened a hundredfold (measured on 2026-11-28), while an absolute tolerance of 1e-14,
    a tenth of a per mille of the readout, let it drift by 1.1e-8. RK4 at h = ts/10 is
    fourth order in h, its own error 1.5e-11 of the peak against the tightest reference:
    the bound leaves a hundredfold margin over the reference's uncertainty."""
    unit, k = sweep.unit, 3
    rhs = _reference_ode(unit, float(sweep.amplitude[k]))
    sol = solve_ivp(rhs, (0, sweep.t[-1]), np.zeros(2 * unit.sites + 2), method="DOP853",
                    t_eval=sweep.t, rtol=1e-12, atol=1e-18, max_step=unit.ts / 10)
    x_r = sol.y[unit.sites]
    assert np.max(np.abs(x_r - sweep.x_r[k])) < 1e-8 * x_r.max()


def test_figure(sweep, tmp_path):
    """`springc figures --only squaring` draws this sweep (Fig. 6c-d)."""
    assert "squaring" in figures.FIGURES
    path = figures.plot_squaring(sweep, tmp_path / "squaring.png")
    assert path.stat().st_size > 10_000
