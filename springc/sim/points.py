"""Simulating every point of a `.step`/`.mc` netlist (docs/language.md, "Sweeps and Monte
Carlo"): probes come out as (points, runs, T), reductions as (points, runs), with the points
table (step values, sample index, seed) beside them.

    simulate_points(checked PointSet, inputs, **settings) -> PointsResult -> write(path)

The points of one structure (`PointSet.groups`) run in the lanes of one kernel call
(`springc.sim.simulate.simulate_lanes`): N points x R inputs are N*R runs, the coefficients
that differ between the points passed with a column per run, in the shared, written-out,
register and Runge-Kutta-part-of-exponential kernels alike. Where a group cannot share a call
(`LanesRefused`: the CUDA form, a Strang split scheme whose exact blocks differ between
the points, noisy dampers that differ; a Lawson scheme's blocks are read per lane) each of
its points is one `simulate` call, the calls sharing the structure's compiled kernel;
`info["per_point"]` says why. Every run has the same settings and the same inputs (read once).
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from springc.check.points import at_point
from springc.errors import CheckError, DivergedRuns, UsageError
from springc.lang.variation import Point, PointSet
from springc.sim import results, thermal
from springc.sim.marshal import LanesRefused
from springc.sim.execute import require_memory
from springc.sim.simulate import SimResult, resolve_probes, settings, simulate, simulate_lanes
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
    for every input with these settings (`options`: `simulate`'s other keywords: batch,
    write_out, temp, seed, device, ...): the points of one structure in the lanes of one
    call (`simulate_lanes`), else one `simulate` call per point (see the module docstring).
    The records of all the points are checked to fit in memory before anything runs. A point
    whose step is unstable, or whose runs diverge, is an error naming the point."""
    if not points.checked:
        raise TypeError("simulate_points takes a checked PointSet: call check_points first")
    first = points.checked[0].net
    tstep0 = tstep or (first.tran.tstep if first.tran else None)
    signals, names, seconds = _gather_inputs(first, inputs, input_rate, tstep0, channel)
    st = settings(first, tstep, tstop, substeps, method, precision, outrate, seconds)
    plist = resolve_probes(first, probes)
    records = st.nsteps // st.rec_every + 1
    largest = max(len(g) for g in points.groups)
    try:  # the stacked output and the largest group's record buffer
        require_memory(len(plist), records, len(names) * (len(points) + largest),
                       st.precision, None)
    except UsageError as err:
        raise UsageError(f"{err.message}; the runs counted are {len(points)} point(s) x "
                         f"{len(names)} run(s), and the buffer of {largest} point(s)",
                         hint=err.diagnostic.hint) from None
    if signals is not None:
        input_rate = 1.0 / tstep0  # read once at the input grid rate, not again per point
    for point, checked in zip(points.points, points.checked):
        _same_grid(checked.net, first, point, len(points))
    call = dict(tstep=tstep, tstop=tstop, substeps=substeps, method=method,
                precision=precision, outrate=outrate, probes=probes,
                reductions=list(reductions), channel=channel, **options)
    out = _Stack(len(points))
    bar = _progress(len(points), progress)
    for group in _call_groups(points, call):
        if len(group) > 1:
            try:
                out.add_group(group, _lanes(points, group, signals, input_rate, call, len(names)))
                _tick(bar, len(group))
                continue
            except LanesRefused as why:
                out.info["per_point"].append(str(why))
        for i in group:
            res = _one_point(points.points[i], len(points), points.checked[i], signals,
                             input_rate, out.records, {**call, "first_run": i * len(names)})
            out.add(i, res)
            _tick(bar, 1)
    if bar is not None:
        bar.close()
    return PointsResult(out.t, out.probes, out.reductions, names, points.points, out.info)


def _tick(bar, count: int) -> None:
    if bar is not None:
        bar.update(count)


def _call_groups(points: PointSet, call: dict) -> list[tuple[int, ...]]:
    """The structure groups (`PointSet.groups`) as calls. A call's runs draw the noise streams
    of consecutive population runs from its first on, so under thermal noise a group of
    scattered points (a structural parameter stepped inside the samples) is split into its
    stretches of consecutive points: point i's input r keeps run i R + r's streams, and no
    two devices share noise."""
    noisy = thermal.temperature(thermal.with_overrides(points.nets[0], call.get("temp"),
                                                       call.get("seed"))) > 0
    if not noisy:
        return list(points.groups)
    out = []
    for group in points.groups:
        start = 0
        for k in range(1, len(group) + 1):
            if k == len(group) or group[k] != group[k - 1] + 1:
                out.append(tuple(group[start:k]))
                start = k
    return out


def _lanes(points: PointSet, group: tuple[int, ...], signals, input_rate, call: dict,
           reps: int) -> SimResult:
    """One group's points in the lanes of one call (`simulate_lanes`), each named by its
    point (a diverged run is '<input> at point ...'); under thermal noise the points are
    consecutive (`_call_groups`) and the call's runs are the population's from its first
    point's on."""
    count = len(points)
    consecutive = list(group) == list(range(group[0], group[-1] + 1))
    first = group[0] * reps if consecutive else 0  # without noise the numbering is unused
    return simulate_lanes([points.checked[i] for i in group],
                          [points.points[i].describe(count) for i in group], signals,
                          input_rate, **call, first_run=first)


class _Stack:
    """The points' results gathered into (points, runs, ...) arrays as they come."""

    def __init__(self, count: int) -> None:
        self.count = count
        self.t = np.zeros(0)
        self.probes: dict[str, np.ndarray] = {}
        self.reductions: dict[str, np.ndarray] = {}
        self.records = None  # the record buffer each point records into after the first
        # per point its kernel and the compile time of its call (0 for the other points
        # of a call); the calls made; why a group ran point by point
        self.info: dict = {"kernels": [""] * count, "compile_s": [0.0] * count, "calls": 0,
                           "per_point": []}

    def _first(self, res: SimResult, runs: int) -> None:
        """The output arrays, shaped from the first result (`runs` of its runs per point)."""
        if self.info.get("settings") is not None:
            return
        self.t = res.t
        self.probes = {k: np.empty((self.count, runs, *v.shape[1:]), v.dtype)
                       for k, v in res.probes.items()}
        self.reductions = {k: np.empty((self.count, runs, *v.shape[1:]), v.dtype)
                           for k, v in res.reductions.items()}
        self.info["settings"] = res.info["settings"]

    def add_group(self, group: tuple[int, ...], res: SimResult) -> None:
        """A lanes call's result: run p*R + r is input r at the group's point p."""
        runs = len(res.runs) // len(group)
        self._first(res, runs)
        idx = list(group)
        for k, v in res.probes.items():
            self.probes[k][idx] = v.reshape(len(group), runs, *v.shape[1:])
        for k, v in res.reductions.items():
            self.reductions[k][idx] = v.reshape(len(group), runs, *v.shape[1:])
        for i in idx:
            self.info["kernels"][i] = res.info["kernel"]
        self.info["compile_s"][idx[0]] = res.info["compile_s"]
        self.info["calls"] += 1

    def add(self, i: int, res: SimResult) -> None:
        self._first(res, len(res.runs))
        for k, v in res.probes.items():
            self.probes[k][i] = v  # copied out: the next point records into the same buffer
        for k, v in res.reductions.items():
            self.reductions[k][i] = v
        self.records = res.info["records"]
        self.info["kernels"][i] = res.info["kernel"]
        self.info["compile_s"][i] = res.info["compile_s"]
        self.info["calls"] += 1


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
