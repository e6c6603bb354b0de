"""The netlist a kernel is generated for: a `FlatNetlist` in, an equivalent one out whose force
code is cheaper.

A monomial of one variable squared, `P c x^2`, is a linear spring of stiffness 2c: it moves from
the monomial table (a general product loop with powers, per term and lane) into the springs,
whose stiffness the kernel's linear rows already hold (`marshal.linear_rows`). The
zero-mode multipliers take back their excess diagonal stiffness this way (`springc.design.mvm`),
48 monomials per head, and in the keyword spotter's classifier they cost more than everything
else in its force code together (docs/performance.md#classifier-kernel). Element names and
locations travel with the moved terms; the potential is unchanged.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from springc.lang.ir import FlatNetlist, Monomials, Springs


def kernel_netlist(net: FlatNetlist) -> FlatNetlist:
    """`net` with its one-variable quadratic monomials as springs (k = 2c), the rest as is."""
    p = net.monomials
    moved = squares(p)
    if not moved.any():
        return net
    first = p.ptr[:-1]
    s = net.springs
    springs = Springs(names=s.names + [n for n, m in zip(p.names, moved) if m],
                      locs=s.locs + [loc for loc, m in zip(p.locs, moved) if m],
                      node=np.concatenate([s.node, p.var[first[moved]]]).astype(s.node.dtype),
                      k=np.concatenate([s.k, 2.0 * p.c[moved]]))
    return replace(net, springs=springs, monomials=_keep(p, ~moved))


def squares(p: Monomials) -> np.ndarray:
    """Per monomial: whether it is c x^2 of one variable (one factor, exponent 2)."""
    factors = np.diff(p.ptr)
    single = factors == 1
    exps = np.zeros(len(p.c), np.int64)
    exps[single] = p.exp[p.ptr[:-1][single]]
    return single & (exps == 2)


def _keep(p: Monomials, keep: np.ndarray) -> Monomials:
    """The monomials where `keep` is true, their factor ranges renumbered."""
    rows = np.flatnonzero(keep)
    spans = [np.arange(p.ptr[e], p.ptr[e + 1]) for e in rows]
    idx = np.concatenate(spans) if spans else np.zeros(0, np.int64)
    ptr = np.concatenate([[0], np.cumsum([len(s) for s in spans])]).astype(p.ptr.dtype)
    return Monomials(names=[p.names[e] for e in rows], locs=[p.locs[e] for e in rows],
                     c=p.c[rows], ptr=ptr, var=p.var[idx], exp=p.exp[idx])
