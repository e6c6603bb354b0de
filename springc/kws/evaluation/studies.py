"""What the result pages read off a sweep: where an accuracy falls below a target.

`falls_below(xs, ys, target)` is the threshold of a spread sweep (the spread at which the mean
device falls a given loss below its nominal design) and of a device-mass sweep (the mass at
which thermal noise costs that loss): the sweeps are on logarithmic grids, so the crossing is
interpolated linearly in log10 x between the two measured points around it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence


def falls_below(xs: Sequence[float], ys: Sequence[float], target: float) -> float | None:
    """The x (> 0, increasing) at which ys first falls to or below `target`, interpolated
    linearly in log10 x between the last point above it and the first at or below it; None
    where the first point is already at or below it, or no point falls to it."""
    if len(xs) != len(ys):
        raise ValueError(f"{len(xs)} x values against {len(ys)} y values")
    if not len(ys) or ys[0] <= target:
        return None
    logs = [math.log10(x) for x in xs]
    for (x0, y0), (x1, y1) in zip(zip(logs, ys), zip(logs[1:], ys[1:])):
        if y1 <= target < y0:
            return 10 ** (x0 + (target - y0) * (x1 - x0) / (y1 - y0))
    return None
