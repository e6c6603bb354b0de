"""springc from Python: what the command line does, for scripts and notebooks.

    import springc
    net = springc.load("netlists/examples/duffing.spr")   # parsed, elaborated, checked
    res = net.simulate()                                   # a Result
    res["x(x)"]                                            # (runs, T) array, by written name

`load` raises the same located errors the CLI prints (`springc.errors.NetlistError`,
`CheckError`, `UsageError`). A `Netlist` simulates, analyses and exports itself; the CLI
commands `build`, `sim`, `ac`, `modes`, `grad` and `export` call these methods.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from typing import TYPE_CHECKING

from springc.check import CheckedNetlist, check, store
from springc.errors import NetlistError, UsageError
from springc.lang import files, read_source
from springc.lang.ir import FlatNetlist
from springc.sim.gpu import default_device  # noqa: F401  (springc.default_device)

# the parser, the elaborator and the analyses are imported where they are used: a netlist
# loaded from the check cache (`springc.check.store`) needs none of them
if TYPE_CHECKING:
    from springc.check.compiler import BuildReport
    from springc.grad.params import ParamNetlist
    from springc.lang import variation


def load(source: str | Path, *, params: Mapping[str, float] | None = None,
         method: str | None = None, tstep: float | None = None, substeps: int | None = None,
         judge_step: bool | None = None, lib_dirs: Sequence[Path] | None = None) -> Netlist:
    """Parse, elaborate and check a netlist: `source` is a file path, or netlist text when
    it has a line break. `params` replaces top-level `.param` values (a sweep point);
    `method`, `tstep` and `substeps` override `.options` and `.tran` for the step check.
    The step is judged here only where it is pinned (by these arguments or `.options
    method=`/`substeps=`, `springc.check.checks.pinned`); otherwise `simulate` chooses the
    integration and judges the step it takes (`judge_step` True or False: always, never)."""
    text, filename = _source(source)
    dirs = list(lib_dirs) if lib_dirs else None
    options = dict(tstep=tstep, substeps=substeps, judge_step=judge_step)
    entry = store.key(text, filename, method=method, lib_dirs=dirs, **options)
    found = None if params else store.lookup(entry)
    if found is not None:  # unchanged since it was last checked: no `.step`/`.mc` in it
        return Netlist(found, text, dirs, {}, options, varies=False)
    with files.recording() as reads:
        if params:
            from springc.grad.params import ParamNetlist

            flat, varies = ParamNetlist.from_text(text, filename, dirs).netlist(params), None
        else:
            var = _variation(text, filename, dirs)
            flat, varies = var.nominal(), var.varies
        if flat.n == 0:
            raise NetlistError(f"{filename}: no top-level network (a library of "
                               "subcircuits?)", hint="instantiate a subcircuit in a netlist "
                                                     "and load that")
        checked = check(flat, method, **options)
    if varies is False:
        store.save(entry, checked, reads)
    return Netlist(checked, text, dirs, dict(params or {}), options, varies=varies)


def _variation(text: str, filename: str, lib_dirs: list[Path] | None) -> variation.Variation:
    """The netlist's `.step` and `.mc` lines and its nominal design."""
    from springc.lang import variation
    from springc.lang.parser import parse

    return variation.read(parse(text, filename), lib_dirs)


def _source(source: str | Path) -> tuple[str, str]:
    """(text, filename) of a path or of netlist text."""
    if isinstance(source, str) and "\n" in source:
        return source, "<text>"
    return read_source(source), str(source)


@dataclass
class Netlist:
    """A checked netlist: simulate it, analyse its linearisation, differentiate or export it.

    `flat` is the elaborated network (`springc.lang.ir.FlatNetlist`), `params` the top-level
    `.param` values it was elaborated with."""

    checked: CheckedNetlist
    text: str = field(repr=False)
    lib_dirs: list[Path] | None = field(default=None, repr=False)
    overrides: dict[str, float] = field(default_factory=dict)
    check_options: dict = field(default_factory=dict, repr=False)  # load's tstep, substeps...
    varies: bool | None = field(default=None, repr=False)  # .step/.mc lines (None: unknown)

    @property
    def flat(self) -> FlatNetlist:
        return self.checked.net

    @property
    def nodes(self) -> list[str]:
        return list(self.flat.nodes)

    @functools.cached_property
    def source(self) -> ParamNetlist:
        """The parsed netlist as a function of its top-level `.param` values."""
        from springc.grad.params import ParamNetlist

        return ParamNetlist.from_text(self.text, self.flat.file, self.lib_dirs)

    @functools.cached_property
    def variation(self) -> variation.Variation:
        """The file's `.step` and `.mc` lines (`Variation.varies`: whether it has any)."""
        return _variation(self.text, self.flat.file, self.lib_dirs)

    @functools.cached_property
    def points(self) -> variation.PointSet:
        """The points of the file's `.step` and `.mc` lines (one, the nominal netlist,
        without them), each elaborated and checked (`PointSet.checked`) as this netlist was
        (its method, step options); the file's `.param` values, not `params=` overrides."""
        from springc.check.points import check_points

        return check_points(self.variation.point_set(), self.checked.method,
                            **self.check_options)

    @property
    def params(self) -> dict[str, float]:
        """Top-level `.param` values (as the file sets them, with this netlist's
        overrides)."""
        return {**self.source.values, **self.overrides}

    def with_params(self, **values: float) -> Netlist:
        """The same netlist at other top-level `.param` values (checked again)."""
        values = {**self.overrides, **values}
        flat = self.source.netlist(values)
        return Netlist(check(flat), self.text, self.lib_dirs, values)

    def report(self) -> BuildReport:
        """What `springc build` reports: dofs, elements, fastest mode, step limit, mode
        errors."""
        from springc.check.compiler import summarise

        return summarise(self.checked)

    def summary(self, as_dict: bool = False) -> str | dict:
        """`springc build`'s text, or (`as_dict`) its JSON object."""
        report = self.report()
        return report.to_json() if as_dict else report.summary()

    def simulate(self, inputs=None, *, tstop: float | None = None, tstep: float | None = None,
                 method: str | None = None, substeps: int | None = None,
                 tolerance: float | None = None, precision: str | None = None,
                 reduce: Sequence[str] = (), probes: Sequence[str] | None = None,
                 outrate: float | None = None, channel: int | None = None,
                 input_rate: float | None = None, batch: int | None = None,
                 kernel: str = "auto", device: str | None = None,
                 progress: bool = False, temp: float | None = None,
                 seed: int | None = None, fma: bool = True) -> Result:
        """Simulate every input (None: one run without input; an array (runs, channels,
        samples) at `input_rate`; or sound files and folders, one run per file).

        The integrator: `method`/`substeps` as given or as the netlist's `.options` set them;
        where neither names them, the cheapest whose estimated error is at most `tolerance`
        (default `springc.sim.plan.DEFAULT_TOLERANCE`), reported in `Result.choice`.
        `reduce`: streaming reductions (`springc sim --reduce` specs). `kernel`: auto,
        written-out or shared (`springc sim --kernel`). `device`:
        cpu, cuda or auto (`springc sim --device`), or None: that of the innermost
        `springc.default_device` (the CPU outside one). `temp` (kelvin) and `seed`: the
        dampers' thermal noise, overriding `.options temp=`/`seed=` (`springc sim --temp`).
        `fma` False: every product and sum rounded on its own, none fused into a fused
        multiply-add, so that the CPU and a GPU give the same bits (`springc sim --no-fma`).

        With `.step`/`.mc` every point is simulated (`springc.sim.points`: the points of
        one structure in the lanes of one kernel call, or where that form cannot take them
        one call each, sharing the compiled kernel; the integrator chosen on the worst
        point): probes (points, runs, T), reductions (points, runs), `Result.points` the
        points' step values, samples and seeds."""
        from springc.sim import plan, thermal
        from springc.sim.simulate import simulate

        thermal.with_overrides(self.flat, temp, seed)  # a bad value fails before any work

        if isinstance(inputs, (str, Path)):
            inputs = [inputs]
        pointset = self._points_to_run()
        checked = self.checked
        if pointset is not None:
            from springc.check.points import worst
            from springc.sim.points import simulate_points

            checked = pointset.checked[worst(pointset)]
        steps = plan.integration(checked, tolerance, method, substeps, tstep, tstop,
                                 inputs, channel, input_rate)
        options = dict(tstep=tstep, tstop=tstop, substeps=steps.substeps, method=steps.method,
                       precision=precision, outrate=outrate,
                       probes=list(probes) if probes else None, reductions=list(reduce),
                       batch=batch, channel=channel, progress=progress, device=device,
                       write_out=plan.KERNEL_FORMS[kernel], temp=temp, seed=seed, fma=fma)
        if pointset is None:
            res = simulate(self.checked, inputs, input_rate, **options)
        else:
            res = simulate_points(pointset, inputs, input_rate, **options)
        return Result(res.t, res.probes, res.reductions, list(res.runs),
                      res.info["settings"], steps.choice, res.info,
                      getattr(res, "points", None), self,
                      dict(inputs=inputs, input_rate=input_rate, channel=channel))

    def _points_to_run(self) -> variation.PointSet | None:
        """The checked points where the file has `.step`/`.mc` (None: the nominal netlist
        alone); `params=` overrides cannot be combined with them."""
        if self.varies is False or not self.variation.varies:
            return None
        if self.overrides:
            raise UsageError(f"{self.flat.file}: params= overrides and .step/.mc together",
                             hint="step the parameter with .step instead, or load without "
                                  "params=")
        return self.points

    def ac(self, node: str | None = None, *, input: int | None = None,
           fmin: float | None = None, fmax: float | None = None, points: int | None = None,
           progress: bool = False):
        """Frequency response X(f)/U(f) of the linearisation at rest at `node` (default: the
        `.ac` directive's) to input channel `input`: a `springc.analyses.ac.AcResult`
        (`f_hz`, complex `h`, `mag`, `phase`). With `.step`/`.mc`, every point's on one
        grid: a `springc.analyses.family.AcFamily` (`h`, `mag`, `phase` (points, F),
        `points`; `family[i]` point i's `AcResult`)."""
        from springc.analyses import ac, family

        pointset = self._points_to_run()
        if pointset is not None:
            return family.ac_family(pointset, node, input, fmin, fmax, points, progress)
        node, channel = ac.target(self.flat, node, input)
        f_hz = ac.sweep(self.flat, fmin, fmax, points).frequencies()
        return ac.response(self.checked, node, f_hz, channel, progress=progress)

    def noise(self, node: str | None = None, *, input: int | None = None,
              temp: float | None = None, fmin: float | None = None, fmax: float | None = None,
              points: int | None = None):
        """Thermal noise at rest at `node` (default: the `.noise` directive's): a
        `springc.analyses.noise.NoiseResult` (`f_hz`, `psd` in m^2/Hz, `sources`, `rms`,
        `input_referred`). `temp` in kelvin (default `.options temp=`, else 300 K). A
        netlist with `.step`/`.mc` has every point checked, then is refused (`UsageError`):
        the noise analysis takes one netlist."""
        from springc.analyses import noise

        if self._points_to_run() is not None:
            from springc.lang import ast

            first = next(s for s in self.variation.statements if isinstance(s, ast.Directive)
                         and s.name in ("step", "mc"))
            raise UsageError("springc noise analyses one netlist, not the points of "
                             ".step/.mc", first.loc,
                             "remove the .step/.mc lines, or write the point's values in")
        node, channel = noise.target(self.flat, node, input)
        f_hz = noise.sweep(self.flat, fmin, fmax, points).frequencies()
        return noise.noise(self.checked, node, f_hz, temp, channel)

    def modes(self, count: int | None = None) -> dict:
        """Eigenfrequencies, damping rates, Q factors, dominant nodes and zero modes of the
        linearisation (`springc modes --json`), the `count` slowest (all if None). With
        `.step`/`.mc`, `{"file", "points": [{"point": {index, steps, sample, seed}, ...}]}`:
        each point's report under its point."""
        from springc.analyses.family import modes_family
        from springc.analyses.modes import mode_report

        pointset = self._points_to_run()
        if pointset is not None:
            return modes_family(pointset, count)
        return mode_report(self.checked, count)

    def grad(self, of: str | Sequence[str], wrt: str | Sequence[str], inputs=None, **settings):
        """d(reduction `of`)/d(top-level `.param` `wrt`) per run, exact for the simulated
        float64 computation (the discrete adjoint): a `springc.grad.GradResult` (`values`,
        `grad[run, k]`). `settings`: tstep, tstop, substeps, method, channel. With `.step`/`.mc`,
        at every point: `values[spec]` (points, runs), `grad[point, run, k]`, `points`
        (at a `.mc` sample each draw's unit deviate held fixed:
        `springc.grad.gradient.at_points`)."""
        from springc.grad import gradient
        from springc.grad.gradient import at_points

        names = [wrt] if isinstance(wrt, str) else list(wrt)
        pointset = self._points_to_run()
        if pointset is not None:
            return at_points(self.source, pointset, of, names, inputs, **settings)
        return gradient(self.source, of, names, inputs, values=self.overrides, **settings)

    def export_spice(self, **options) -> str | list[str]:
        """The netlist as an ngspice circuit (`springc export --spice`); `options` are
        `springc.export.spice.SpiceOptions` fields (tstop, tstep, tmax, reltol, inputs).
        With `.step`/`.mc`, a list: one circuit per point, its values written in (ngspice's
        `.step`-free form), headed by a comment naming the point."""
        from springc.export.spice import SpiceOptions, export_spice

        pointset = self._points_to_run()
        if pointset is None:
            return export_spice(self.checked, SpiceOptions(**options))
        return [f"* {point.describe(len(pointset))}\n"
                + export_spice(checked, SpiceOptions(**options))
                for point, checked in zip(pointset.points, pointset.checked)]


@dataclass
class Result:
    """A simulation: `t` (T,) in seconds, `probes[label]` (runs, T), `reductions[spec]`
    (runs,), `runs` (names), the integration `settings` and, where springc chose the
    integrator, `choice` (why). With `.step`/`.mc`, `points` (each point's step values,
    sample and seed), probes (points, runs, T) and reductions (points, runs)."""

    t: np.ndarray
    probes: dict[str, np.ndarray]
    reductions: dict[str, np.ndarray]
    runs: list[str]
    settings: object
    choice: str | None = None
    info: dict = field(default_factory=dict, repr=False)
    points: tuple | None = None
    netlist: Netlist | None = field(default=None, repr=False)  # simulated, for `stats`
    inputs: dict = field(default_factory=dict, repr=False)  # as simulated, for `stats`

    def __getitem__(self, name: str) -> np.ndarray:
        """A probe or reduction by its written name (`x(X1.out)`, `work:in`)."""
        if name in self.probes:
            return self.probes[name]
        if name in self.reductions:
            return self.reductions[name]
        known = ", ".join([*self.probes, *self.reductions]) or "none"
        raise KeyError(f"no probe or reduction {name!r} (have: {known})")

    def to_xarray(self):
        """An `xarray.Dataset`: each probe over (point, run, time), each reduction over
        (point, run); the points' step values, samples and seeds are coordinates along
        `point` (one point, 0, without `.step`/`.mc`). Each variable's `units` attribute
        is its SI unit (`springc.sim.results.units`: x m, v m/s, msq:x m^2, work, dissipated
        and energy J, loss dB), time's is s."""
        import xarray as xr

        from springc.sim.points import points_table
        from springc.sim.results import units

        one = self.points is None
        data = {k: (("point", "run", "time"), v[None] if one else v, _units(units(k)))
                for k, v in self.probes.items()}
        data |= {k: (("point", "run"), v[None] if one else v, _units(units(k)))
                 for k, v in self.reductions.items()}
        coords = {"point": list(range(1 if one else len(self.points))),
                  "run": list(self.runs), "time": ("time", self.t, _units("s"))}
        if not one:
            coords |= {k.removeprefix("points_"): ("point", v)
                       for k, v in points_table(self.points).items()}
        return xr.Dataset(data, coords=coords, attrs={"method": self.settings.method,
                                                      "substeps": self.settings.substeps})

    def plot(self, path: str | Path | None = None, *, ax=None, max_runs: int = 4):
        """Every probe against time for the first `max_runs` runs (with points: the first
        run of the first `2 max_runs` points). `ax`: a matplotlib Axes to draw every probe
        into, or one Axes per probe; else a new figure, one panel per probe. Returns the
        new figure (written as a PNG too where `path` is given), or `ax` as given (its
        figure written to `path` where given)."""
        from springc.sim import points, results

        sim, runs = self._sim(), max_runs
        if self.points is not None:
            sim, runs = points.figure_result(sim, 2 * max_runs), 2 * max_runs
        if ax is None:
            fig = results.figure(sim, runs)
            if path is not None:
                results.save_figure(fig, path)
            return fig
        return results.plot_into(lambda *axes: results.draw(sim, axes, runs), ax, path,
                                 panels=max(1, len(sim.probes)))

    def save(self, path: str | Path) -> None:
        """Write `.npz` or `.csv` as `springc sim -o` does (with points: their table in the
        `.npz`, their columns in the `.csv`, `springc.sim.points.write`)."""
        from springc.sim import points, results

        if self.points is None:
            results.write(self._sim(), path)
        else:
            points.write(self._sim(), path)

    def stats(self, predict: bool = True):
        """Per reduction, over the Monte Carlo samples of each step point and run: mean,
        standard deviation, 5/50/95% quantiles, min and max, and (`predict`) the first-order
        prediction of the deviation from the gradient at the nominal design
        (`springc.sim.stats`, `springc sim --stats`)."""
        from springc.sim import stats

        return stats.population(self, predict)

    def _sim(self):
        from springc.sim.points import PointsResult
        from springc.sim.simulate import SimResult

        if self.points is not None:
            return PointsResult(self.t, self.probes, self.reductions, self.runs, self.points,
                                self.info)
        return SimResult(self.t, self.probes, self.reductions, self.runs, self.info)


def _units(unit: str | None) -> dict[str, str]:
    """An xarray variable's attributes: its `units` where it has one."""
    return {} if unit is None else {"units": unit}
