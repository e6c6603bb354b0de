"""The integrator of the keyword-spotting networks, chosen by measurement at a stated tolerance.

    choose(checked, signals, outputs, tol) -> Integration

Candidates come from the per-mode error estimates (`springc.check.accuracy`: the fewest
substeps per method whose linear modes meet `tol`), cheapest first. Each is then run on a
sample of clips and compared with a tight reference (RK4, 16 substeps, float64) on exactly
what the classifier consumes (`outputs`: the Phi reduction, or the heads' readouts); the first
whose error is at most `tol` on every clip, and that does not diverge, is taken. Per method the
candidates run from an eighth to four times the estimated substeps: the estimates weigh every
mode at full weight, which the outputs may not feel (the multipliers' stiff modes), and cannot
see the nonlinear terms (squaring, compression). RK4 at 8 substeps, the paper's setting, is `PAPER`.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import TypeVar

import numpy as np

from springc.check import CheckedNetlist
from springc.check.accuracy import choose as estimate
from springc.errors import DataError, DivergedRuns, SimulationError, UsageError

TOLERANCE = 1e-3  # on Phi and the readouts, relative to each clip's largest value
# a candidate may leave up to this share of the sample to finer steps (clips too loud for
# it: `run_with_retries`); more, and it would cost finer steps for much of a data set
LOUD_SHARE = 0.25
REFERENCE = ("rk4", 16, "float64")
METHODS = ("exp-heun3", "exp-rk4", "rk4")
MAX_SUBSTEPS = 32
# w h (a mode's angular frequency times the step, as predicted) up to which a run is
# integrated at a step: RK4's stability limit on the imaginary axis is 2.83, where the
# error jumps (a compressor at a predicted 2.9 left Phi 1e-5 off, at 3.1 2e-3); the margin
# covers predictions up to 4% low
MAX_WH = 2.7


@dataclass(frozen=True)
class Integration:
    """How a network is integrated, and what that was measured to cost in error."""

    method: str = "rk4"
    substeps: int = 8
    precision: str = "float32"
    tolerance: float | None = None  # None: set by hand (the paper's setting), not chosen
    error: float | None = None  # measured: max over the sample of the relative error
    clips: int = 0  # clips of the sample the error was measured on
    reference: str = "rk4 x16 float64"
    seconds: float | None = None  # the chosen candidate's wall time on the sample

    def to_dict(self) -> dict:
        """Plain dict (settings.json, reports)."""
        return asdict(self)

    def retries(self) -> list[tuple[str, int]]:
        """(method, substeps) tried in turn on a batch: this one, then finer steps (a clip
        louder than the sample stiffens the compressors), then RK4 down to 1/32 sample."""
        finer = [(self.method, self.substeps * k) for k in (1, 2, 4)
                 if self.substeps * k <= MAX_SUBSTEPS]
        return finer + [("rk4", s) for s in (16, 32) if ("rk4", s) not in finer]

    def describe(self) -> str:
        """One line for people."""
        name = f"{self.method} x{self.substeps} {self.precision}"
        if self.error is None:
            return f"{name} (set, not measured)"
        return (f"{name}: error {self.error:.2g} against "
                f"{self.reference} on {self.clips} clip(s) (tolerance {self.tolerance:g})")


PAPER = Integration()


def from_dict(data: dict | None, where: str = "settings.json") -> Integration:
    """The integration recorded in a model's settings (the paper's setting if none is); a
    DataError naming `where` if the entry is not one."""
    if not data:
        return PAPER
    try:
        return Integration(**data)
    except TypeError as exc:
        raise DataError(where, f"holds an unreadable integration entry ({exc})") from None


Outputs = Callable[[np.ndarray, str, int, str], np.ndarray]


def choose(checked: CheckedNetlist, signals: np.ndarray, outputs: Outputs, duration: float,
           tol: float = TOLERANCE, precision: str = "float32",
           methods: tuple[str, ...] = METHODS,
           reference: Callable[[], np.ndarray] | None = None) -> Integration:
    """The cheapest integration of `checked` by one of `methods` in `precision` whose
    `outputs(signals, method, substeps, precision)` (clips, values; a row of NaN for a clip
    that diverges at that step) are within `tol` of the reference on every clip of `signals`
    that it integrates, and that leaves at most `LOUD_SHARE` of them to finer steps. The
    error is relative to each clip's largest reference value. `reference()`: the outputs at
    `REFERENCE`, for a caller whose reference run records more (default: `outputs` at it);
    it runs while the workers compile the candidates' kernels."""
    if not tol > 0:
        raise UsageError(f"tolerance must be positive, got {tol}")
    todo = candidates(checked, 1.0 / 16000.0, duration, tol, methods)
    _compile_ahead(outputs, signals, todo, precision)
    method, substeps, prec = REFERENCE
    _say(f"integration: reference {method} x{substeps} {prec} on {len(signals)} clip(s)")
    start = time.perf_counter()
    reference = reference() if reference else outputs(signals, method, substeps, prec)
    # a candidate may be the reference itself
    known = {REFERENCE: (reference, time.perf_counter() - start)}
    for method, substeps in todo:
        config = (method, substeps, precision)
        try:
            got, seconds = known.get(config) or _timed(outputs, signals, *config)
        except SimulationError:
            _say(f"integration: {method} x{substeps} {precision} diverged")
            continue
        ok = np.isfinite(got).all(axis=1) & np.isfinite(reference).all(axis=1)
        loud = len(ok) - int(ok.sum())
        if loud > LOUD_SHARE * len(ok):
            _say(f"integration: {method} x{substeps} {precision} diverged on {loud} of "
                 f"{len(ok)} clips")
            continue
        error = relative_error(got[ok], reference[ok])
        _say(f"integration: {method} x{substeps} {precision} error {error:.2g} "
             f"({'within' if error <= tol else 'above'} {tol:g}), {seconds:.2f} s"
             + (f"; {loud} loud clip(s) left to finer steps" if loud else ""))
        if error <= tol:
            return Integration(method, substeps, precision, tol, error, len(signals),
                               f"{REFERENCE[0]} x{REFERENCE[1]} {REFERENCE[2]}", seconds)
    raise UsageError(f"no integrator up to {MAX_SUBSTEPS} substeps meets tolerance {tol:g} "
                     "on the sample clips", hint="raise the tolerance")


def _compile_ahead(outputs: Outputs, signals: np.ndarray, todo: list[tuple[str, int]],
                   precision: str) -> None:
    """Each candidate method's kernel compiled on an idle Dask worker (one clip run there)
    while the reference runs here: a kernel compile takes 10-25 s, and the choice would
    otherwise compile one after the other on one core (`distributed.ahead`)."""
    from springc.kws.features.distributed import ahead

    firsts = {}
    for method, substeps in todo:
        firsts.setdefault(method, substeps)
    for method, substeps in firsts.items():
        if (method, precision) != (REFERENCE[0], REFERENCE[2]):  # that one compiles here
            ahead(outputs, signals[:1], method, substeps, precision)


def _timed(outputs: Outputs, *args) -> tuple[np.ndarray, float]:
    start = time.perf_counter()
    got = outputs(*args)
    return got, time.perf_counter() - start


T = TypeVar("T")


def remembered(name: str, parts: list[str | bytes], measure: Callable[[], T]) -> T:
    """`measure()` (a choice and what it measured), or its result kept from an earlier run on
    the same `parts` (the network, the sample, the tolerance) by the same springc
    (`springc.check.store.memo`): a choice runs the tight reference on its sample, a large
    share of a small training's time, and a second training on the same data and front end
    (the device design after the mass-spring one) would run it again."""
    from springc.check import store

    ran = []

    def run() -> T:
        ran.append(True)
        return measure()

    rules = repr((REFERENCE, METHODS, TOLERANCE, LOUD_SHARE, MAX_SUBSTEPS, MAX_WH))
    out = store.memo(name, [*parts, rules], run)
    if not ran:
        _say(f"integration: the {name} of an earlier run on the same network and sample")
    return out


def signal_key(signals: np.ndarray) -> bytes:
    """The bytes that identify a sample of signals in a `remembered` key."""
    a = np.ascontiguousarray(signals)
    return f"{a.dtype} {a.shape}".encode() + a.tobytes()


def _say(message: str) -> None:
    # the choice takes tens of seconds: say what is being measured
    print(message, file=sys.stderr, flush=True)


def candidates(checked: CheckedNetlist, tstep: float, duration: float, tol: float,
               methods: tuple[str, ...] = METHODS) -> list[tuple[str, int]]:
    """(method, substeps), cheapest first: per method around the fewest substeps the per-mode
    estimates allow, from an eighth (the estimates count every mode at full weight, which
    the outputs may not feel: the classifier's multipliers put stiff modes where RK4 needs 8
    substeps for 1e-3, and its readouts meet 1e-3 with exp-rk4 at 2) to four times as many
    (the nonlinear terms, which they do not see). A step above the method's stability limit
    at rest is not a candidate."""
    from springc.check.accuracy import cost

    net = checked.net
    out = []
    for method in methods:
        try:
            first = estimate(net, tstep, duration, tol, methods=(method,)).substeps
        except UsageError:
            continue
        limit = checked.step_limit(method).dt * (1 + 1e-9)
        subs = [max(1, round(first * k)) for k in (0.125, 0.25, 0.5, 1, 2, 4)
                if first * k <= MAX_SUBSTEPS]
        out += [(method, sub) for sub in subs if tstep / sub <= limit]
    return sorted(set(out), key=lambda c: (cost(net, *c), c))


def relative_error(got: np.ndarray, reference: np.ndarray) -> float:
    """max over clips of max |got - reference| / max |reference| (per clip)."""
    got, reference = np.atleast_2d(got), np.atleast_2d(reference)
    scale = np.abs(reference).max(axis=1)
    scale = np.where(scale > 0, scale, 1.0)
    return float((np.abs(got - reference).max(axis=1) / scale).max())


def run_with_retries(integration: Integration, run: Callable[[str, int, np.ndarray], dict],
                     runs: int, tries: slice = slice(None),
                     stiffness: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """The reductions of `runs` runs: run(method, substeps, idx) simulates the runs `idx` (in
    `integration.precision`) at each of `integration.retries()[tries]` in turn, each time only
    those that diverged before, so one loud clip does not send its whole batch to finer steps.
    `stiffness` (runs,): the largest mode frequency each run will reach times the sample
    period (predicted before simulating); a try leaves the runs whose w h would pass MAX_WH
    at its step to the next, as if they had diverged (short of divergence, such a run can be
    far off). Runs that diverge at the last try raise, unless `tries` stops short of the last
    retry: then their rows are NaN (for a caller that pools them with others' for the next
    tries)."""
    todo = np.arange(runs)
    out: dict[str, np.ndarray] = {}
    plan = integration.retries()
    start, stop, _ = tries.indices(len(plan))
    for k in range(start, stop):
        method, substeps = plan[k]
        last = k == len(plan) - 1
        stiff = np.zeros(len(todo), bool) if stiffness is None or last else \
            stiffness[todo] / substeps > MAX_WH
        go = np.flatnonzero(~stiff)
        if not len(go) and (k < stop - 1 or out):
            continue  # none fits this step: on to the next
        # none fits the last try of the part: it runs them only for the rows' shapes (NaN)
        shapes_only = not len(go)
        go = np.arange(len(todo)) if shapes_only else go
        try:
            got, diverged = run(method, substeps, todo[go]), np.zeros(0, np.int64)
        except DivergedRuns as err:
            if last:
                raise
            got, diverged = err.reductions, go[np.asarray(err.diverged, np.int64)]
        bad = np.arange(len(todo)) if shapes_only else \
            np.union1d(np.flatnonzero(stiff), diverged)
        keep = np.setdiff1d(go, bad)
        for key, value in got.items():
            out.setdefault(key, np.full((runs,) + value.shape[1:], np.nan))[todo[keep]] = \
                value[np.searchsorted(go, keep)]
        todo = todo[bad]
        if not len(todo):
            break
    return out
