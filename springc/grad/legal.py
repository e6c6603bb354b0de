"""Optimiser variables that cannot leave the legal set: unconstrained z in, `.param` values
out, every one inside a box whose netlists pass every check.

Each parameter gets a `Range` [lo, hi] and the map p = lo (hi / lo)^sigmoid(z) (log scale,
for a range of one sign: a stiffness or a damping never changes sign, and decades are as
easy to cross as units) or p = lo + (hi - lo) sigmoid(z) (linear, for a range through 0).
Every finite z lands strictly inside the box, so an optimiser needs no rejection step.

`legal_map` builds the box around legal starting values (default: each parameter within a
factor `spread` of its value) and checks the netlist at every corner (all `2^P` for up to
`MAX_CORNERS` of them, else that many random corners and the two extreme ones), shrinking
the box until all pass. The checks are monotone in each coefficient where the netlist's
coefficients are monotone in each parameter over the box (the sign rules are sign
conditions; stiffness added to a positive semidefinite potential keeps it so and only
raises the fastest mode; mass only lowers it), so the corners passing means the whole box
passes; a parameter whose coefficients are not monotone over the box is outside that
guarantee (docs/gradients.md).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from springc.check import check
from springc.errors import NetlistError, UsageError
from springc.grad.params import ParamNetlist

MAX_CORNERS = 1024
SHRINKS = 8  # halvings of the box's log-width before giving up


@dataclass(frozen=True)
class Range:
    """A parameter's interval; `log`: the sigmoid moves along log |p| (lo and hi share a
    sign)."""

    lo: float
    hi: float
    log: bool

    def value(self, z: float) -> float:
        """The parameter value for the unconstrained variable z."""
        s = _sigmoid(z)
        if self.log:
            return self.lo * (self.hi / self.lo) ** s
        return self.lo + (self.hi - self.lo) * s

    def slope(self, z: float) -> float:
        """d value / d z (for chaining a gradient in the parameter to one in z)."""
        s = _sigmoid(z)
        ds = s * (1.0 - s)
        if self.log:
            return self.value(z) * math.log(self.hi / self.lo) * ds
        return (self.hi - self.lo) * ds

    def variable(self, value: float) -> float:
        """The z that gives `value` (strictly inside the range)."""
        if self.log:
            s = math.log(value / self.lo) / math.log(self.hi / self.lo)
        else:
            s = (value - self.lo) / (self.hi - self.lo)
        if not 0.0 < s < 1.0:
            raise UsageError(f"{value:g} is not strictly inside [{self.lo:g}, {self.hi:g}]")
        return math.log(s / (1.0 - s))


def _sigmoid(z: float) -> float:
    # both branches stay finite for any finite z
    if z >= 0:
        return 1.0 / (1.0 + math.exp(-z))
    e = math.exp(z)
    return e / (1.0 + e)


@dataclass(frozen=True)
class LegalMap:
    """z (one entry per name) <-> parameter values inside the checked box."""

    names: tuple[str, ...]
    ranges: tuple[Range, ...]

    def values(self, z: Sequence[float]) -> dict[str, float]:
        """Parameter values for the unconstrained vector z."""
        return {n: r.value(float(zk)) for n, r, zk in zip(self.names, self.ranges, z)}

    def variables(self, values: Mapping[str, float]) -> np.ndarray:
        """The z that gives these parameter values."""
        return np.array([r.variable(values[n]) for n, r in zip(self.names, self.ranges)])

    def chain(self, grad: Sequence[float], z: Sequence[float]) -> np.ndarray:
        """A gradient in the parameters (in `names` order) as a gradient in z."""
        return np.asarray(grad) * np.array([r.slope(float(zk))
                                            for r, zk in zip(self.ranges, z)])


def legal_map(pn: ParamNetlist, wrt: Sequence[str], values: Mapping[str, float] | None = None,
              *, spread: float = 4.0, bounds: Mapping[str, tuple[float, float]] | None = None,
              method: str | None = None, tstep: float | None = None,
              substeps: int | None = None, seed: int = 0) -> LegalMap:
    """A `LegalMap` for the parameters `wrt` around `values` (others as the file sets them):
    each within a factor `spread` of its value (a parameter at 0: +-1), or within `bounds`
    where given, shrunk until the netlist passes the checks (for `method`, `tstep`,
    `substeps`) at every corner. A `UsageError` if the start fails or no box passes."""
    pn.require(list(wrt))
    start = {**pn.values, **dict(values or {})}
    fixed = {k: v for k, v in dict(values or {}).items() if k not in wrt}
    judge = lambda vals: _passes(pn, {**fixed, **vals}, method, tstep, substeps)  # noqa: E731
    if not judge({n: start[n] for n in wrt}):
        raise UsageError("the starting parameter values fail the checks",
                         hint="start from a netlist that springc build accepts")
    ranges = [_initial(n, start[n], spread, bounds) for n in wrt]
    rng = np.random.default_rng(seed)
    for _ in range(SHRINKS):
        if all(judge(dict(zip(wrt, corner))) for corner in _corners(ranges, rng)):
            return LegalMap(tuple(wrt), tuple(ranges))
        ranges = [_shrink(r, start[n]) for r, n in zip(ranges, wrt)]
    raise UsageError(f"no box around the starting values of {', '.join(wrt)} passes the "
                     "checks at every corner", hint="give narrower bounds")


def _initial(name: str, value: float, spread: float,
             bounds: Mapping[str, tuple[float, float]] | None) -> Range:
    if bounds and name in bounds:
        lo, hi = (float(b) for b in bounds[name])
        if not lo < value < hi:
            raise UsageError(f"bounds of {name}: [{lo:g}, {hi:g}] must hold its value "
                             f"{value:g} strictly inside")
        return Range(lo, hi, lo * hi > 0)
    if value == 0.0:
        return Range(-1.0, 1.0, False)
    lo, hi = sorted((value / spread, value * spread))
    return Range(lo, hi, True)


def _shrink(r: Range, value: float) -> Range:
    """Halve the range's (log-)distance from the starting value on each side."""
    if r.log:
        return Range(math.copysign(math.sqrt(r.lo * value), value),
                     math.copysign(math.sqrt(r.hi * value), value), True)
    return Range((r.lo + value) / 2, (r.hi + value) / 2, False)


def _corners(ranges: list[Range], rng: np.random.Generator) -> list[tuple[float, ...]]:
    ends = [(r.lo, r.hi) for r in ranges]
    if 2 ** len(ranges) <= MAX_CORNERS:
        return list(itertools.product(*ends))
    picks = rng.integers(0, 2, size=(MAX_CORNERS, len(ranges)))
    extreme = [np.zeros(len(ranges), int), np.ones(len(ranges), int)]
    return [tuple(ends[k][b] for k, b in enumerate(p)) for p in [*extreme, *picks]]


def _passes(pn: ParamNetlist, values: dict, method, tstep, substeps) -> bool:
    try:
        # the gradient integrates at the configured step, chosen by no one: judge it
        check(pn.netlist(values), method, tstep=tstep, substeps=substeps, judge_step=True)
    except NetlistError:  # a failed check, or an expression outside its domain
        return False
    return True
