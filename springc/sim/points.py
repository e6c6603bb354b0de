"""Simulating every point of a `.step`/`.mc` netlist (docs/language.md, "Sweeps and Monte
Carlo"): probes come out as (points, runs, T), reductions as (points, runs), with the points
table (step values, sample index, seed) beside them.

    simulate_points(checked PointSet, inputs, **settings) -> PointsResult -> write(path)

Each point is one `simulate` call on its own checked netlist, all with the same settings
and the same inputs (read once). The kernel takes its coefficients as runtime arrays, so
the points of one structure share one compiled kernel: the first call compiles it (or loads
it from the cache), the others find it loaded. Running all the points in the lanes of one
kernel call is not done here: N points are N calls.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from springc.check.points import at_point
from springc.errors import CheckError, DivergedRuns, UsageError
from springc.lang.variation import Point, PointSet
from springc.sim import results
from springc.sim.simulate import SimResult, require_memory, resolve_probes, settings, simulate
from springc.sim.simulate import _gather_inputs


@dataclass
class PointsResult:
    """The simulation of every point: `t` (T,), `probes[label]` (points, runs, T),
    `reductions[spec]` (points, runs), `runs` (names), `points` (each point's step values,
    sample and seed), `info` (the settings, and per point its kernel and compile time)."""

    t: np.ndarray
    probes: dict[str, np.ndarray]
    reductions: dict[str, np.ndarray]
    runs: list[str]
    points: tuple[Point, ...]
    info: dict = field(default_factory=dict)

    def table(self) -> dict[str, np.ndarray]:
        """The points table as arrays: `points_<param>` per stepped parameter and, with
        `.mc`, `points_sample` and `points_seed` (one entry per point)."""
        return points_table(self.points)


def points_table(points: tuple[Point, ...]) -> dict[str, np.ndarray]:
    """`points_<param>` (float64) per stepped parameter, `points_sample` and `points_seed`
    (int64) where the points are samples."""
    out = {f"points_{name}": np.array([dict(p.steps)[name] for p in points])
           for name, _ in points[0].steps}
    if points[0].sample is not None:
        out["points_sample"] = np.array([p.sample for p in points], np.int64)
        out["points_seed"] = np.array([p.seed for p in points], np.int64)
    return out


def simulate_points(points: PointSet, inputs=None, input_rate: float | None = None, *,
                    tstep=None, tstop=None, substeps=None, method=None, precision=None,
                    outrate=None, probes=None, reductions=(), channel: int | None = None,
                    progress: bool = False, **options) -> PointsResult:
    """Simulate every point of the checked point set (`springc.check.points.check_points`)
    for every input, one `simulate` call per point with these settings (`options`: its
    other keywords: batch, write_out, temp, seed, device, ...). The records of all the points
    are checked to fit in memory before anything runs. A point whose step is unstable, or
    whose runs diverge, is an error naming the point."""
    if not points.checked:
        raise TypeError("simulate_points takes a checked PointSet: call check_points first")
    first = points.checked[0].net
    tstep0 = tstep or (first.tran.tstep if first.tran else None)
    signals, names, seconds = _gather_inputs(first, inputs, input_rate, tstep0, channel)
    st = settings(first, tstep, tstop, substeps, method, precision, outrate, seconds)
    plist = resolve_probes(first, probes)
    records = st.nsteps // st.rec_every + 1
    try:  # the stacked output and one point's record buffer
        require_memory(len(plist), records, len(names) * (len(points) + 1), st.precision,
                       None)
    except UsageError as err:
        raise UsageError(f"{err.message}; the runs counted are {len(points)} point(s) x "
                         f"{len(names)} run(s), and one point's buffer",
                         hint=err.diagnostic.hint) from None
    if signals is not None:
        input_rate = 1.0 / tstep0  # read once at the input grid rate, not again per point
    out = _Stack(len(points))
    bar = _progress(len(points), progress)
    for i, (point, checked) in enumerate(zip(points.points, points.checked)):
        _same_grid(checked.net, first, point, len(points))
        res = _one_point(point, len(points), checked, signals, input_rate, out.records,
                         dict(tstep=tstep, tstop=tstop, substeps=substeps,
                              method=method, precision=precision, outrate=outrate,
                              probes=probes, reductions=list(reductions), channel=channel,
                              **options))
        out.add(i, res)
        if bar is not None:
            bar.update(1)
    if bar is not None:
        bar.close()
    return PointsResult(out.t, out.probes, out.reductions, names, points.points, out.info)


class _Stack:
    """The points' results gathered into (points, runs, ...) arrays as they come."""

    def __init__(self, count: int) -> None:
        self.count = count
        self.t = np.zeros(0)
        self.probes: dict[str, np.ndarray] = {}
        self.reductions: dict[str, np.ndarray] = {}
        self.records = None  # the record buffer each point records into after the first
        self.info: dict = {"kernels": [], "compile_s": []}

    def add(self, i: int, res: SimResult) -> None:
        if i == 0:
            self.t = res.t
            self.probes = {k: np.empty((self.count, *v.shape), v.dtype)
                           for k, v in res.probes.items()}
            self.reductions = {k: np.empty((self.count, *v.shape), v.dtype)
                               for k, v in res.reductions.items()}
            self.info["settings"] = res.info["settings"]
        for k, v in res.probes.items():
            self.probes[k][i] = v  # copied out: the next point records into the same buffer
        for k, v in res.reductions.items():
            self.reductions[k][i] = v
        self.records = res.info["records"]
        self.info["kernels"].append(res.info["kernel"])
        self.info["compile_s"].append(res.info["compile_s"])


def _one_point(point: Point, count: int, checked, signals, input_rate, records,
               settings_: dict) -> SimResult:
    """One point's simulation; its errors name the point."""
    where = f" at {point.describe(count)}"
    try:
        return simulate(checked, signals, input_rate, record_into=records, **settings_)
    except CheckError as err:
        raise at_point(err, point, count) from None
    except DivergedRuns as err:
        raise DivergedRuns(err.message + where, err.diverged, err.reductions,
                           err.diagnostic.hint) from None
    except UsageError as err:
        raise UsageError(err.message + where, err.loc, err.diagnostic.hint) from None


def _same_grid(net, first, point: Point, count: int) -> None:
    """Every point on the first point's time grid (a stepped `.tran` would stack records of
    different lengths)."""
    if net.tran != first.tran:
        raise UsageError(f"the .tran of {point.describe(count)} differs from point 0's (a "
                         "stepped parameter in .tran)", net.tran.loc if net.tran else None,
                         "write the .tran times as numbers, or pass --tstep/--tstop")


def _progress(count: int, enabled: bool):
    if not enabled or count <= 1:
        return None
    from tqdm import tqdm

    return tqdm(total=count, unit="point", desc="simulating points")


# --- files ------------------------------------------------------------------------------------


def write(result: PointsResult, path: str | Path) -> None:
    """Write `result` as `.npz` (`t`, each probe (points, runs, T), each reduction
    (points, runs), `runs` and the points table of `points_table`) or as long-format `.csv`
    (`point`, one column per stepped parameter, `sample` and `seed` with `.mc`, then
    `run,quantity,t,value`)."""
    results.check_output_path(path)
    if Path(path).suffix.lower() == ".npz":
        arrays = {"t": result.t, **result.probes, **result.reductions,
                  "runs": np.asarray(result.runs), **result.table()}
        with results.atomic_path(path, ".npz") as tmp, open(tmp, "wb") as fh:
            np.savez(fh, **arrays)
        return
    _write_csv(result, path)


def _write_csv(result: PointsResult, path: str | Path) -> None:
    table = result.table()
    columns = [k.removeprefix("points_") for k in table]
    tstop = repr(float(result.t[-1])) if len(result.t) else "0.0"
    times = [repr(float(t)) for t in result.t]
    with results.atomic_path(path) as tmp, open(tmp, "w", newline="") as fh:
        out = csv.writer(fh)
        out.writerow(["point", *columns, "run", "quantity", "t", "value"])
        for p in range(len(result.points)):
            head = [p, *(_cell(v[p]) for v in table.values())]
            for r, run in enumerate(result.runs):
                for label, data in result.probes.items():
                    out.writerows([*head, run, label, t, repr(float(v))]
                                  for t, v in zip(times, data[p, r]))
                for spec, data in result.reductions.items():
                    out.writerow([*head, run, spec, tstop, repr(float(data[p, r]))])


def _cell(value) -> str:
    return repr(float(value)) if isinstance(value, np.floating) else str(int(value))


def figure_result(result: PointsResult, max_points: int = 8) -> SimResult:
    """The first run of up to `max_points` points as the runs of a `SimResult`, for the
    probe plot of `springc.sim.results.figure` (one curve per point)."""
    shown = result.points[:max_points]
    probes = {k: v[:len(shown), 0] for k, v in result.probes.items()}
    names = [p.describe() for p in shown]
    return SimResult(result.t, probes, {}, names, result.info)
