"""Every point of a `.step`/`.mc` netlist checked like a netlist of its own.

`check_points(points, method)` checks each point's netlist as `springc.check.check` does
(the points of one structure group together, `check_many`: a large component may take a
certified bound from the first point's instead of a Lanczos run of its own) and returns the
point set with the checked netlists; a point that fails is a `CheckError` whose every
diagnostic names the point (step values, sample index, seed) beside the failed check. `worst`
is the point with the smallest stable step, the one that sets the step of a run of them all.
"""

from __future__ import annotations

import math
from dataclasses import replace

from springc.check.checks import CheckedNetlist, check_many
from springc.errors import CheckError
from springc.lang.variation import Point, PointSet


def check_points(points: PointSet, method: str | None = None, **options) -> PointSet:
    """`points` with every point's `CheckedNetlist` (`method` overrides `.options method=`,
    `options` are `check`'s tstep, substeps and judge_step); `CheckError` at the first point
    that fails, naming it. The points of one structure group are checked together
    (`check_many`), each refused where it is refused alone."""
    results: list = [None] * len(points)
    for group in points.groups:
        found = check_many([points.nets[i] for i in group], method, **options)
        for i, result in zip(group, found):
            results[i] = result
    for point, result in zip(points.points, results):
        if isinstance(result, CheckError):
            raise at_point(result, point, len(points))
    return replace(points, checked=tuple(results))


def at_point(err: CheckError, point: Point, count: int) -> CheckError:
    """`err` with the point named in each message (a single netlist's errors unchanged)."""
    if count == 1 and not point.steps and point.sample is None:
        return err
    where = f" at {point.describe(count)}"
    return CheckError([replace(d, message=d.message + where) for d in err.diagnostics])


def worst(points: PointSet) -> int:
    """The index of the checked point with the smallest stable step (then the fastest mode;
    the first of equals)."""
    def key(i: int) -> tuple[float, float, int]:
        result: CheckedNetlist = points.checked[i]
        omega = result.modes.omega_max if result.modes is not None else 0.0
        dt = result.step.dt if result.step is not None else math.inf
        return dt, -omega, i

    return min(range(len(points.checked)), key=key)
