"""Reference physics of a flat netlist in plain numpy: potential, internal forces, damping
forces and the linearisation (mass, damping and stiffness matrices).

This is the slow, obviously-correct definition of the equations of motion
    m_i x_i'' + b_i x_i' + sum_B b (x_i' - x_j') + dV/dx_i = f_i(t)
that the checks, the analyses, the numpy/scipy peers and the tests use. Positions `x` may be
shape (n,) or (n, batch); results have the same trailing shape.
"""

from __future__ import annotations

import numpy as np

from springc.lang.ir import GROUND, FlatNetlist


def potential(net: FlatNetlist, x: np.ndarray) -> np.ndarray:
    """Total potential energy V(x)."""
    s, d, c, q, p = net.springs, net.duffings, net.couplings, net.quads, net.monomials
    v = np.zeros(x.shape[1:])
    v += np.sum(0.5 * _col(s.k, x) * x[s.node] ** 2, axis=0)
    v += np.sum(0.25 * _col(d.l, x) * x[d.node] ** 4, axis=0)
    v += np.sum(_col(c.k / (2 * c.a), x) * (x[c.i] - _col(c.a, x) * x[c.j]) ** 2, axis=0)
    v += np.sum(_col(q.g / (2 * q.a), x) * (x[q.i] ** 2 - _col(q.a, x) * x[q.j]) ** 2, axis=0)
    for e in range(len(p)):
        v = v + p.c[e] * _monomial(p, e, x)
    return v


def internal_force(net: FlatNetlist, x: np.ndarray) -> np.ndarray:
    """-dV/dx, the force of all potential elements."""
    f = np.zeros_like(x, dtype=np.float64)
    s, d, c, q = net.springs, net.duffings, net.couplings, net.quads
    np.add.at(f, s.node, -_col(s.k, x) * x[s.node])
    np.add.at(f, d.node, -_col(d.l, x) * x[d.node] ** 3)
    stretch = x[c.i] - _col(c.a, x) * x[c.j]
    np.add.at(f, c.i, -_col(c.k / c.a, x) * stretch)
    np.add.at(f, c.j, _col(c.k, x) * stretch)
    qs = x[q.i] ** 2 - _col(q.a, x) * x[q.j]
    np.add.at(f, q.i, -_col(2 * q.g / q.a, x) * x[q.i] * qs)
    np.add.at(f, q.j, _col(q.g, x) * qs)
    return f + monomial_force(net, x)


def monomial_force(net: FlatNetlist, x: np.ndarray) -> np.ndarray:
    """-dV/dx of the P elements alone."""
    f = np.zeros_like(x, dtype=np.float64)
    p = net.monomials
    for e in range(len(p)):
        for k in range(p.ptr[e], p.ptr[e + 1]):
            f[p.var[k]] -= p.c[e] * _monomial_derivative(p, e, k, x)
    return f


def damping_force(net: FlatNetlist, v: np.ndarray) -> np.ndarray:
    """Force of local dampers and dashpots for velocities v."""
    f = -_col(net.local_damping(), v) * v
    d = net.dashpots
    vj = np.where(_col(d.j, v) == GROUND, 0.0, v[np.maximum(d.j, 0)])
    rel = _col(d.b, v) * (v[d.i] - vj)
    np.add.at(f, d.i, -rel)
    grounded = d.j == GROUND
    np.add.at(f, d.j[~grounded], rel[~grounded])
    return f


def stiffness_matrix(net: FlatNetlist, x: np.ndarray | None = None) -> np.ndarray:
    """Hessian of V at x (default: at rest, x = 0), shape (n, n)."""
    n = net.n
    x = np.zeros(n) if x is None else np.asarray(x, dtype=np.float64)
    h = np.zeros((n, n))
    s, d, c, q, p = net.springs, net.duffings, net.couplings, net.quads, net.monomials
    np.add.at(h, (s.node, s.node), s.k)
    np.add.at(h, (d.node, d.node), 3 * d.l * x[d.node] ** 2)
    for i, j, k, a in zip(c.i, c.j, c.k, c.a):
        h[i, i] += k / a
        h[j, j] += k * a
        h[i, j] -= k
        h[j, i] -= k
    for i, j, g, a in zip(q.i, q.j, q.g, q.a):
        h[i, i] += 2 * g / a * (3 * x[i] ** 2 - a * x[j])
        h[j, j] += g * a
        h[i, j] -= 2 * g * x[i]
        h[j, i] -= 2 * g * x[i]
    for e in range(len(p)):
        _add_monomial_hessian(h, p, e, x)
    return h


def damping_matrix(net: FlatNetlist) -> np.ndarray:
    """Linear damping matrix (local dampers plus dashpots), shape (n, n)."""
    bmat = np.diag(net.local_damping())
    d = net.dashpots
    for i, j, b in zip(d.i, d.j, d.b):
        bmat[i, i] += b
        if j != GROUND:
            bmat[j, j] += b
            bmat[i, j] -= b
            bmat[j, i] -= b
    return bmat


def energy(net: FlatNetlist, x: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Total mechanical energy: kinetic plus potential."""
    return 0.5 * np.sum(_col(net.mass(), v) * v**2, axis=0) + potential(net, x)


def _col(a: np.ndarray, like: np.ndarray) -> np.ndarray:
    """Broadcast per-element coefficients against (n,) or (n, batch) positions."""
    a = np.asarray(a)
    return a.reshape(a.shape + (1,) * (like.ndim - 1))


def _monomial(p, e: int, x: np.ndarray) -> np.ndarray:
    out = np.ones(x.shape[1:])
    for k in range(p.ptr[e], p.ptr[e + 1]):
        out = out * x[p.var[k]] ** p.exp[k]
    return out


def _monomial_derivative(p, e: int, k: int, x: np.ndarray) -> np.ndarray:
    """d/dx_var[k] of the monomial e (factors on one variable are merged by the front end,
    but repeated variables are handled by the product rule anyway)."""
    out = np.zeros(x.shape[1:])
    target = p.var[k]
    if k != _first_factor_of(p, e, target):
        return out
    for kk in range(p.ptr[e], p.ptr[e + 1]):
        if p.var[kk] != target:
            continue
        term = np.ones(x.shape[1:]) * p.exp[kk] * x[target] ** (p.exp[kk] - 1)
        for other in range(p.ptr[e], p.ptr[e + 1]):
            if other != kk:
                term = term * x[p.var[other]] ** p.exp[other]
        out = out + term
    return out


def _first_factor_of(p, e: int, var: int) -> int:
    for k in range(p.ptr[e], p.ptr[e + 1]):
        if p.var[k] == var:
            return k
    raise ValueError(var)


def _add_monomial_hessian(h: np.ndarray, p, e: int, x: np.ndarray) -> None:
    powers: dict[int, int] = {}
    for k in range(p.ptr[e], p.ptr[e + 1]):
        powers[int(p.var[k])] = powers.get(int(p.var[k]), 0) + int(p.exp[k])
    for a in powers:
        for b in powers:
            pw = dict(powers)
            coef = p.c[e] * pw[a]
            pw[a] -= 1
            coef *= pw[b]
            pw[b] -= 1
            if coef == 0 or min(pw.values()) < 0:
                continue
            h[a, b] += coef * np.prod([x[v] ** q for v, q in pw.items()])
