"""Chains and square and cubic lattices of masses, as a user writes them (`lattice_text`: `.for`
loops) and built directly as arrays (`lattice_net`: the same flat netlist, for sizes where
elaboration is not what is measured).

Every mass (1 kg) is grounded by a spring k0 and coupled to its neighbour along each axis by
kc; a sine force drives the first mass; the first and the centre mass are probed. The fastest
mode, sqrt(k0 + 4 d kc) = 656 rad/s in 3-D, leaves RK4 at the 1 ms step (`.tran`) a factor 4
inside its stability limit, so a simulated second is 1000 steps at every size.
"""

from __future__ import annotations

import itertools

import numpy as np

from springc.errors import SourceLoc
from springc.lang.ir import (Couplings, Dashpots, Duffings, FlatNetlist, Forces, Masses,
                             Monomials, Probe, QuadCouplings, Source, Springs, Tran)

K0 = (2 * np.pi * 10.0) ** 2  # N/m: each mass to ground
KC = (2 * np.pi * 30.0) ** 2  # N/m: each pair of neighbours
TSTEP = 1e-3  # s
AXES = "xyz"


def side_for(masses: int, dims: int) -> int:
    """The side of a `dims`-dimensional lattice of about `masses` masses."""
    return max(2, round(masses ** (1.0 / dims)))


def _index(dims: int) -> str:
    """The name suffix of a site: `{i}`, `{i}_{j}` or `{i}_{j}_{k}`."""
    return "_".join("{" + v + "}" for v in "ijk"[:dims])


def _shifted(dims: int, axis: int) -> str:
    """The name suffix of the next site along `axis`."""
    return "_".join("{" + v + ("+1}" if a == axis else "}") for a, v in enumerate("ijk"[:dims]))


def _loops(dims: int, body: list[str], short: int | None = None) -> list[str]:
    """`body` inside one `.for` per axis over the sites (axis `short` one site shorter)."""
    heads = [f".for {v} 0 {{n-{2 if a == short else 1}}}" for a, v in enumerate("ijk"[:dims])]
    return heads + body + [".endfor"] * dims


def lattice_text(dims: int, side: int) -> str:
    """The `.spr` text of a chain (`dims` 1), square (2) or cubic (3) lattice of `side` masses
    a side, written with `.for` loops."""
    idx = _index(dims)
    lines = [f".title {dims}-D lattice of {side}^{dims} masses",
             f".param n={side} k0={{(2*pi*10)**2}} kc={{(2*pi*30)**2}}"]
    lines += _loops(dims, [f"M{idx} n{idx} m=1", f"K{idx} n{idx} k={{k0}}"])
    for axis in range(dims):
        lines += _loops(dims, [f"C{AXES[axis]}{idx} n{idx} n{_shifted(dims, axis)} k={{kc}}"],
                        short=axis)
    first, centre = (_site_name([0] * dims), _site_name([side // 2] * dims))
    lines += [f"F1 {first} sin(1 10)", f".probe x({first}) x({centre})",
              f".tran {TSTEP!r} 1"]
    return "\n".join(lines) + "\n"


def _site_name(coords) -> str:
    return "n" + "_".join(str(c) for c in coords)


def lattice_net(dims: int, side: int) -> FlatNetlist:
    """The flat netlist `lattice_text(dims, side)` elaborates to (names, order and values
    alike; every location the file's start), built from arrays."""
    file = f"<lattice {dims}-D {side}>"
    loc = SourceLoc(file, 0, 0)
    shape = (side,) * dims
    n = side**dims
    suffix = ["_".join(map(str, c)) for c in itertools.product(range(side), repeat=dims)]
    grid = np.arange(n, dtype=np.int64).reshape(shape)
    ci, cj, names = [], [], []
    for axis in range(dims):
        lo = grid[tuple(slice(0, side - 1) if a == axis else slice(None) for a in range(dims))]
        ci.append(lo.ravel())
        cj.append(lo.ravel() + grid.strides[axis] // grid.itemsize)
        names += [f"C{AXES[axis]}{suffix[p]}" for p in lo.ravel().tolist()]
    i, j = np.concatenate(ci), np.concatenate(cj)
    nodes = np.arange(n, dtype=np.int64)
    ones, zeros = np.ones(n), np.zeros(n)
    first, centre = 0, int(grid[(side // 2,) * dims])
    return FlatNetlist(
        title=f"{dims}-D lattice of {side}^{dims} masses", file=file,
        nodes=[f"n{s}" for s in suffix], node_locs=[loc] * n,
        masses=Masses([f"M{s}" for s in suffix], [loc] * n, node=nodes, m=ones, b=zeros,
                      x0=zeros.copy(), v0=zeros.copy()),
        springs=Springs([f"K{s}" for s in suffix], [loc] * n, node=nodes.copy(),
                        k=np.full(n, K0)),
        duffings=Duffings(), quads=QuadCouplings(), dashpots=Dashpots(), monomials=Monomials(),
        couplings=Couplings(names, [loc] * len(i), i=i, j=j, k=np.full(len(i), KC),
                            a=np.ones(len(i))),
        forces=Forces(["F1"], [loc], node=np.array([first]), gain=np.ones(1),
                      source=[Source("sin", (1.0, 10.0, 0.0))]),
        probes=[Probe("x", p, f"x(n{suffix[p]})", loc) for p in (first, centre)],
        tran=Tran(TSTEP, 1.0, loc), acs=[], options={}, option_locs={}, instances=[])
