"""A weighted sum by springs: one output node pulled towards each input by a spring whose
stiffness is the weight's size and whose leverage is its sign.

    y = sum_p w_p x_p / sum_p |w_p|        (quasi-statically)

A `C` element V = k/(2a) (x_p - a y)^2 with k = kappa |w_p| and a = sign(w_p) (k/a >= 0 for
either sign) pulls y with the force k (x_p - a y): the output settles where the forces
balance, at the weighted mean above, with the stiffness kappa sum |w| to hold it. Unlike the
zero-mode multiplier (`springc.design.mvm`), whose outputs are zero modes of a stiffness built
to cancel exactly (a relative spread of 1e-6 on its couplings moves them by their own size,
docs/results-spread.md), every coefficient here enters the output at first order: a relative
spread s on the springs moves y by at most about s times the largest input.

Each input feels the stiffness kappa |w_p| towards y (and through y towards the other
inputs): `kappa` sets how hard the sum loads what it reads. The output's mass and damping set
its own resonance and damping ratio (well above the inputs' band: the sum is quasi-static
there).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from springc.design.emit import SprWriter, num, write_atomic
from springc.errors import UsageError


@dataclass(frozen=True)
class Summer:
    """A weighted sum of `len(weights)` inputs: coupling stiffness kappa |w_p|, leverage
    sign(w_p); the output's mass `m` and damping `b`."""

    weights: np.ndarray
    kappa: float
    m: float
    b: float

    @property
    def stiffness(self) -> float:
        """N/m: what holds the output, kappa sum |w|."""
        return self.kappa * float(np.abs(self.weights).sum())

    @property
    def gains(self) -> np.ndarray:
        """dy/dx_p at rest: w_p / sum |w|."""
        return self.weights / float(np.abs(self.weights).sum())

    def elements(self, inputs: list[str], output: str, tag: str = "") -> list[list[str]]:
        """The element lines' fields: the output's mass Ms{tag}, one coupling Cs{tag}_{p} per
        nonzero weight."""
        lines = [[f"Ms{tag}", output, f"m={num(self.m)}", f"b={num(self.b)}"]]
        for p, (node, w) in enumerate(zip(inputs, self.weights)):
            if w != 0:
                lines.append([f"Cs{tag}_{p}", node, output, f"k={num(self.kappa * w)}",
                              f"a={num(math.copysign(1.0, w))}"])
        return lines


def design_summer(weights, kappa: float, resonance_hz: float,
                  zeta: float = 0.7) -> Summer:
    """The sum of `weights` (not all zero) with coupling stiffness `kappa` per unit weight,
    the output's mass placing its resonance at `resonance_hz` and its damping ratio `zeta`."""
    w = np.asarray(weights, dtype=np.float64)
    if w.ndim != 1 or not np.all(np.isfinite(w)) or not np.any(w != 0):
        raise UsageError("a weighted sum needs finite weights, not all zero")
    if not (kappa > 0 and resonance_hz > 0 and zeta > 0):
        raise UsageError(f"need kappa, resonance and damping ratio > 0, got {kappa:g}, "
                         f"{resonance_hz:g}, {zeta:g}")
    k = kappa * float(np.abs(w).sum())
    m = k / (2 * math.pi * resonance_hz) ** 2
    return Summer(w, kappa, m, 2 * zeta * math.sqrt(k * m))


def summer_text(summer: Summer, name: str = "summer") -> str:
    """`.subckt name in0 .. in{N-1} out`: the sum as a readable block."""
    n = len(summer.weights)
    w = SprWriter()
    w.comment(f"{name}: out = sum_p w_p in_p / sum |w| quasi-statically (springc design "
              f"summer); the output held by {summer.stiffness:.6g} N/m, each input pulled by "
              f"kappa |w_p| = {summer.kappa:.6g} |w_p|.")
    w.comment("weights: " + " ".join(num(v) for v in summer.weights))
    w.blank()
    w.subckt(name, [f"in{p}" for p in range(n)] + ["out"])
    for fields in summer.elements([f"in{p}" for p in range(n)], "out"):
        w.statement(*fields)
    w.ends(name)
    return w.text()


def write_summer(summer: Summer, path: str | Path, name: str = "summer") -> Path:
    """Write `summer_text` to `path` atomically."""
    return write_atomic(path, summer_text(summer, name))
