"""Explicit Runge-Kutta integrators as data (Butcher tableaux) and their linear stability.

The code generator builds every scheme from its tableau; the time-step check uses the
stability polynomial R(z) = 1 + sum_k z^(k+1) b^T A^k 1 of the same tableau.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Tableau:
    """An explicit Runge-Kutta scheme: stage matrix `a` (strictly lower), weights `b`,
    nodes `c` and classical order."""

    name: str
    a: tuple[tuple[float, ...], ...]
    b: tuple[float, ...]
    c: tuple[float, ...]
    order: int
    description: str

    @property
    def stages(self) -> int:
        return len(self.b)


TABLEAUX: dict[str, Tableau] = {
    t.name: t
    for t in [
        Tableau(
            "rk4",
            ((), (0.5,), (0.0, 0.5), (0.0, 0.0, 1.0)),
            (1 / 6, 1 / 3, 1 / 3, 1 / 6),
            (0.0, 0.5, 0.5, 1.0),
            4,
            "classic fourth-order Runge-Kutta (the paper's integrator)",
        ),
        Tableau(
            "rk38",
            ((), (1 / 3,), (-1 / 3, 1.0), (1.0, -1.0, 1.0)),
            (1 / 8, 3 / 8, 3 / 8, 1 / 8),
            (0.0, 1 / 3, 2 / 3, 1.0),
            4,
            "Kutta's 3/8-rule fourth-order scheme",
        ),
        Tableau(
            "ssprk3",
            ((), (1.0,), (0.25, 0.25)),
            (1 / 6, 1 / 6, 2 / 3),
            (0.0, 1.0, 0.5),
            3,
            "third-order strong-stability-preserving Runge-Kutta (Shu-Osher)",
        ),
        Tableau(
            "heun3",
            ((), (1 / 3,), (0.0, 2 / 3)),
            (0.25, 0.0, 0.75),
            (0.0, 1 / 3, 2 / 3),
            3,
            "Heun's third-order scheme",
        ),
        Tableau(
            "midpoint",
            ((), (0.5,)),
            (0.0, 1.0),
            (0.0, 0.5),
            2,
            "explicit midpoint rule (second order; unstable for undamped oscillators)",
        ),
    ]
}

DEFAULT_METHOD = "rk4"


def get_tableau(name: str) -> Tableau:
    """The tableau called `name` (KeyError lists the known ones)."""
    try:
        return TABLEAUX[name]
    except KeyError:
        raise KeyError(f"unknown integrator {name!r}; known: {', '.join(TABLEAUX)}") from None


def stability_polynomial(tab: Tableau) -> np.ndarray:
    """Coefficients r_0..r_s (increasing powers) of R(z) for the test equation y' = z y."""
    s = tab.stages
    a = np.zeros((s, s))
    for i, row in enumerate(tab.a):
        a[i, : len(row)] = row
    b = np.asarray(tab.b)
    coeffs = [1.0]
    vec = np.ones(s)
    for _ in range(s):
        coeffs.append(float(b @ vec))
        vec = a @ vec
    return np.asarray(coeffs)


def amplification(tab: Tableau, z: np.ndarray) -> np.ndarray:
    """R(z): the factor one step multiplies a mode with eigenvalue lambda by, z = lambda h."""
    return np.polynomial.polynomial.polyval(np.asarray(z, dtype=complex), stability_polynomial(tab))


def max_stable_step(tab: Tableau, eigenvalues: np.ndarray) -> tuple[float, int]:
    """Largest h with |R(h lambda)| <= 1 for every eigenvalue (of the first-order system), and
    the index of the eigenvalue that limits it (-1 if none does: all zero).

    Eigenvalues with positive real part are unstable for any h (returns 0)."""
    lam = np.asarray(eigenvalues, dtype=complex)
    best, arg = np.inf, -1
    for idx, value in enumerate(lam):
        h = _ray_limit(tab, value)
        if h < best:
            best, arg = h, idx
    return best, arg


def _ray_limit(tab: Tableau, lam: complex, tol: float = 1e-12) -> float:
    """Largest h with |R(h lam)| <= 1 + tol along the ray from 0 (first exit)."""
    mag = abs(lam)
    if mag == 0.0:
        return np.inf
    direction = lam / mag
    s = np.linspace(0.0, 8.0, 4001)[1:]
    bad = np.abs(amplification(tab, s * direction)) > 1 + tol
    if not bad.any():
        return np.inf
    first = int(np.argmax(bad))
    if first == 0:
        return 0.0
    lo, hi = s[first - 1], s[first]
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if abs(amplification(tab, mid * direction)) > 1 + tol:
            hi = mid
        else:
            lo = mid
    return lo / mag
