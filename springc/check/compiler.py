"""`build`: the front end, then the checks, then a summary of what was built.

    load_file(path) -> FlatNetlist -> checks.check(net) -> BuildReport

The report is what `springc build` prints (text or one JSON object, docs/language.md,
"Outputs"): degrees of freedom, element counts, instances, the fastest mode of the
linearisation and the largest stable step of the integrator (for a splitting scheme, the
blocks it integrates exactly and the mode of the rest that limits its step). The integrator
is the one `springc sim` takes: the user's where the netlist's `.options` or `--method` pin
it (its step judged), else the cheapest that meets the error tolerance (`accuracy.choose`),
which `sim` confirms on nonlinear terms by step doubling over its first run.
With `.step` or `.mc` every point is checked and the report is the worst point's (the
smallest stable step), with the number of points and of structures.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from typing import TYPE_CHECKING

from springc.check import accuracy, checks, store
from springc import lang
from springc.lang import files
from springc.errors import Diagnostic, UsageError
from springc.kernels import expint
from springc.lang.ir import FlatNetlist

if TYPE_CHECKING:  # the points' modules come with the front end, on a cache miss only
    from springc.lang import variation


@dataclass
class BuildReport:
    """Summary of a netlist that passed every check."""

    file: str
    title: str
    dofs: int
    elements: dict[str, int]
    instances: int
    instances_by_subckt: dict[str, int]
    omega_max: float  # largest undamped eigenfrequency, rad/s
    fastest_nodes: list[tuple[str, float]]  # dominant nodes of the mode that limits the step
    fastest_mode: str  # that mode, described for people ('' if none)
    method: str
    dt_max: float  # largest stable step of `method`, s (inf: nothing limits it)
    tstep: float | None  # configured step (.tran tstep / substeps), s
    substeps: int
    zero_modes: int
    modes_complete: bool
    notes: list[Diagnostic] = field(default_factory=list)
    # nodes of each block a split scheme integrates exactly (no step limit from them)
    exact_blocks: list[list[str]] = field(default_factory=list)
    mode_errors: list[accuracy.ModeError] = field(default_factory=list)  # worst first
    net: FlatNetlist | None = field(default=None, repr=False)  # what was built
    points: int = 1  # with .step/.mc: how many points, and the worst one (this report's)
    structures: int = 1
    worst_point: variation.Point | None = None
    choice: accuracy.Choice | None = None  # the integration springc chose (None: pinned)
    tolerance: float | None = None  # that choice's target

    @property
    def f_max_hz(self) -> float:
        return self.omega_max / (2 * math.pi)

    def to_json(self) -> dict:
        """The documented keys (`dofs`, `elements`, `omega_max`, `dt_max`) and the rest; an
        unlimited `dt_max` is null."""
        return {
            "file": self.file,
            "title": self.title,
            "dofs": self.dofs,
            "elements": dict(self.elements),
            "instances": self.instances,
            "instances_by_subckt": dict(self.instances_by_subckt),
            "omega_max": self.omega_max,
            "f_max_hz": self.f_max_hz,
            "fastest_mode": self.fastest_mode,
            "fastest_nodes": [{"node": n, "amplitude": a} for n, a in self.fastest_nodes],
            "method": self.method,
            "dt_max": self.dt_max if math.isfinite(self.dt_max) else None,
            "tstep": self.tstep,
            "substeps": self.substeps,
            "zero_modes": self.zero_modes,
            "modes_complete": self.modes_complete,
            "exact_blocks": [list(b) for b in self.exact_blocks],
            "mode_errors": [m.to_json() for m in self.mode_errors],
            "points": self.points,
            "structures": self.structures,
            "worst_point": self.worst_point.to_json() if self.worst_point else None,
            "integration": self._integration_json(),
            "diagnostics": [{"severity": d.severity, "message": d.message,
                             "loc": str(d.loc) if d.loc else None} for d in self.notes],
        }

    def _integration_json(self) -> dict:
        chosen = self.choice
        out = {"chosen": chosen is not None, "method": self.method, "substeps": self.substeps,
               "h": self.tstep}
        if chosen is not None:
            out.update(tolerance=self.tolerance, error=chosen.error, cost=chosen.cost,
                       band_hz=None if math.isinf(chosen.band_hz) else chosen.band_hz,
                       text=chosen.describe())
        return out

    def summary(self) -> str:
        """Human-readable text."""
        counts = ", ".join(f"{k}={v}" for k, v in self.elements.items()) or "none"
        # a split scheme's step is set by the fastest mode it does not integrate exactly
        limiting = "limiting   " if self.exact_blocks else "fastest    "
        lines = [f"{self.file}: {self.title or '(untitled)'}",
                 f"  dofs        {self.dofs}",
                 f"  elements    {counts}",
                 f"  instances   {self.instances}" + _by_subckt(self.instances_by_subckt),
                 f"  omega_max   {self.omega_max:.6g} rad/s ({self.f_max_hz:.6g} Hz)",
                 f"  {limiting} {self.fastest_mode or '-'}",
                 f"  dt_max      {_seconds(self.dt_max)} ({self.method})",
                 f"  step        {_step(self)}"]
        if self.choice is not None:
            lines.append(f"  integration {_chosen(self)}")
        if self.worst_point is not None:
            lines[1:1] = [f"  points      {self.points} ({self.structures} structure(s)); "
                          f"worst {self.worst_point.describe(self.points)}, reported below"]
        if self.exact_blocks:
            lines.append(f"  exact       {len(self.exact_blocks)} block(s) by matrix "
                         f"exponential: {_blocks(self.exact_blocks)}")
        if self.zero_modes:
            lines.append(f"  zero modes  {self.zero_modes}")
        if self.mode_errors:
            which = "chosen" if self.choice is not None else "configured"
            lines.append(f"  worst modes (error of {self.method} at the {which} step over "
                         ".tran tstop, relative L2 of the impulse response):")
            lines += [f"    {m.describe()}" for m in self.mode_errors]
        return "\n".join(lines + [d.format() for d in self.notes])


def _blocks(blocks: list[list[str]], count: int = 4) -> str:
    """'(xa, xb), (xc, xd), ... 12 more' for people."""
    shown = ", ".join("(" + ", ".join(b) + ")" for b in blocks[:count])
    return shown + (f", ... {len(blocks) - count} more" if len(blocks) > count else "")


def _by_subckt(counts: dict[str, int]) -> str:
    return " (" + ", ".join(f"{k}: {v}" for k, v in counts.items()) + ")" if counts else ""


def _seconds(value: float) -> str:
    return f"{value:.6g} s" if math.isfinite(value) else "unlimited"


def _step(report: BuildReport) -> str:
    if report.tstep is None:
        return "no .tran"
    sub = f" (tstep / {report.substeps})" if report.substeps > 1 else ""
    if report.choice is not None:
        return f"{report.tstep:.6g} s{sub}, chosen for tolerance {report.tolerance:g}"
    return f"{report.tstep:.6g} s{sub}, stable"


def _chosen(report: BuildReport) -> str:
    """The choice in `springc sim`'s words, and what `sim` checks on top of it."""
    c = report.choice
    text = (f"{c.method} with {c.substeps} substep(s), as springc sim chooses it: estimated "
            f"error {c.error:.3g} on {c.modes_judged()}, cost "
            f"{c.cost:.3g} stages per sample")
    if report.net is not None and accuracy.nonlinear(report.net):
        text += ("; springc sim confirms it on the nonlinear terms by step doubling over "
                 "the start of its first run (and takes more substeps where that says so)")
    return text


@dataclass
class LibraryReport:
    """Summary of a file that defines subcircuits and no top-level network."""

    file: str
    title: str
    subckts: list  # springc.lang.library.SubcktSummary

    def to_json(self) -> dict:
        """`dofs` 0 and no elements at top level, and one object per subcircuit."""
        return {"file": self.file, "title": self.title, "dofs": 0, "elements": {},
                "subckts": [s.to_json() for s in self.subckts]}

    def summary(self) -> str:
        """Human-readable text: one header and one instance per subcircuit."""
        title = f" ({self.title})" if self.title else ""
        head = (f"{self.file}{title}: a library of {len(self.subckts)} subcircuit(s), "
                "no top-level network")
        return "\n".join([head] + [s.describe() for s in self.subckts])


def build(path: str | Path, *, lib_dirs: list[Path] | None = None,
          method: str | None = None,
          tolerance: float | None = None) -> BuildReport | LibraryReport:
    """Load, check and summarise the netlist at `path`; `method` overrides `.options
    method=` (and pins the integrator); `tolerance` chooses it for that error target even
    where `.options` pin it, as `springc sim --tolerance` does. A file of subcircuit
    definitions alone gets a `LibraryReport`. Raises `NetlistError` (syntax, semantics) or
    `CheckError` (all failed checks)."""
    if tolerance is not None and method:
        raise UsageError("--tolerance chooses the integrator itself",
                         hint="drop --method, or drop --tolerance")
    text = lang.read_source(path)
    judge = False if tolerance is not None else None
    # the same entry as `springc.load` with these options: build, then sim, checks once
    entry = store.key(text, str(path), method=method, lib_dirs=lib_dirs, tstep=None,
                      substeps=None, judge_step=judge)
    found = store.lookup(entry)
    if found is not None:
        return remembered_summary(found, tolerance)
    with files.recording() as reads:
        tree = lang.parse(text, str(path))
        from springc.lang import variation

        var = variation.read(tree, lib_dirs)
        net = var.nominal()
        if net.n == 0:
            from springc.lang import library  # the parser's: only for a library file

            found = library.subckts(tree, text, lib_dirs)
            if found:
                return LibraryReport(net.file, net.title, found)
        if var.varies:
            return points_report(var.point_set(net), method, tolerance, judge)
        checked = checks.check(net, method, judge_step=judge)
    store.save(entry, checked, reads)
    return remembered_summary(checked, tolerance)


def remembered_summary(checked: checks.CheckedNetlist,
                       tolerance: float | None = None) -> BuildReport:
    """`summarise`, kept beside the netlist's entry in the check cache: the mode errors
    and the integrator choice depend on nothing else (and the choice imports scipy)."""
    def compute() -> BuildReport:
        report = summarise(checked, tolerance)
        report.net = None  # stored once, in the entry itself
        return report

    report = store.remembered(checked, f"build summary {tolerance!r}", compute)
    report.net = checked.net
    return report


def points_report(points: variation.PointSet, method: str | None = None,
                  tolerance: float | None = None,
                  judge: bool | None = None) -> BuildReport:
    """Check every point and summarise the worst (smallest stable step)."""
    from springc.check.points import check_points, worst

    points = check_points(points, method, judge_step=judge)
    index = worst(points)
    report = summarise(points.checked[index], tolerance)
    report.points, report.structures = len(points), len(points.groups)
    report.worst_point = points.points[index]
    return report


def report_for(net: FlatNetlist, method: str | None = None) -> BuildReport:
    """Check an already elaborated netlist and summarise it."""
    return summarise(checks.check(net, method))


def summarise(result: checks.CheckedNetlist, tolerance: float | None = None) -> BuildReport:
    """The build report of a netlist that passed the checks (what `springc build` prints):
    for the integrator the user pinned, or else (and with `tolerance`, always) for the one
    `springc sim` chooses at `tolerance` (default `accuracy.DEFAULT_TOLERANCE`)."""
    net = result.net
    choice, notes = _choice(result, tolerance)
    method = choice.method if choice else result.method
    found, step = result.modes, result.step_limit(method)
    mode = step.mode
    blocks = _blocks_of(result, method)
    return BuildReport(
        file=net.file,
        title=net.title,
        dofs=net.n,
        elements=net.element_counts(),
        instances=len(net.instances),
        instances_by_subckt=dict(Counter(i.subckt for i in net.instances)),
        omega_max=found.omega_max,
        fastest_nodes=mode.dominant() if mode else [],
        fastest_mode=mode.describe() if mode else "",
        method=method,
        dt_max=step.dt,
        tstep=choice.h if choice else result.tstep,
        substeps=choice.substeps if choice else int(net.options.get("substeps", 1)),
        zero_modes=found.zero_count,
        modes_complete=found.complete,
        notes=result.notes + notes,
        mode_errors=_mode_errors(net, result, method, choice.h if choice else result.tstep),
        exact_blocks=[[net.nodes[i] for i in nodes] for nodes in blocks.nodes]
        if blocks is not None else [],
        net=net,
        choice=choice,
        tolerance=(tolerance or accuracy.DEFAULT_TOLERANCE) if choice else None,
    )


def _choice(result: checks.CheckedNetlist,
            tolerance: float | None) -> tuple[accuracy.Choice | None, list[Diagnostic]]:
    """The integration `springc sim` chooses where the step is not pinned (or `tolerance` is
    given): (choice, []), or (None, a warning) where no integrator meets the tolerance,
    which `sim` refuses; (None, []) for a pinned step or a netlist without `.tran`."""
    net = result.net
    if net.tran is None or (tolerance is None and result.pinned):
        return None, []
    tol = tolerance or accuracy.DEFAULT_TOLERANCE
    try:
        return accuracy.choose(net, net.tran.tstep, net.tran.tstop, tol,
                               found=result.modes), []
    except UsageError as err:
        return None, [Diagnostic("warning", f"{err.message}: springc sim refuses this "
                                 "netlist at that tolerance", net.tran.loc,
                                 err.diagnostic.hint)]


def _blocks_of(result: checks.CheckedNetlist, method: str):
    """The blocks `method` integrates exactly (None for a Runge-Kutta tableau)."""
    if not expint.is_split(method):
        return None
    return result.blocks if method == result.method else expint.find_blocks(result.net)


WORST_MODES = 5  # modes listed by `springc build`


def _mode_errors(net: FlatNetlist, result: checks.CheckResult, method: str,
                 h: float | None) -> list[accuracy.ModeError]:
    """The worst per-mode error estimates of `method` at step `h` (none without .tran)."""
    if h is None or net.tran is None or result.modes is None:
        return []
    return accuracy.mode_errors(net, h, method, net.tran.tstop, result.modes, WORST_MODES)


def kernel_source(report: BuildReport) -> str:
    """The generated simulation kernel of a built netlist, for its configured method and
    precision (`springc build --emit-kernel`)."""
    from springc.kernels import expint  # code generation only when asked
    from springc.kernels.codegen import KernelOptions, generate

    from springc.kernels.lower import kernel_netlist

    precision = str(report.net.options.get("precision", "float64"))
    opts = KernelOptions(method=report.method, precision=precision)
    net = kernel_netlist(report.net)
    if expint.is_split(report.method):
        return expint.kernel_source(net, opts)
    return generate(net, opts)
