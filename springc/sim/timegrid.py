"""A simulation's time grid and numerics: the step, the stop time, the substeps, the
integrator, the precision and the output rate, resolved from the call's arguments, the
netlist's `.options` and its `.tran` (`settings`)."""

from __future__ import annotations

from dataclasses import dataclass

from springc.errors import UsageError
from springc.kernels import expint
from springc.kernels.integrators import DEFAULT_METHOD, TABLEAUX
from springc.lang.ir import FlatNetlist

PRECISIONS = ("float64", "float32")


@dataclass(frozen=True)
class Settings:
    """Resolved simulation settings (netlist defaults with overrides applied)."""

    tstep: float
    tstop: float
    substeps: int
    method: str
    precision: str
    outrate: float

    @property
    def h(self) -> float:
        return self.tstep / self.substeps

    @property
    def nsteps(self) -> int:
        return int(round(self.tstop / self.h))

    @property
    def rec_every(self) -> int:
        return max(1, int(round(1.0 / (self.outrate * self.h))))


def settings(net: FlatNetlist, tstep=None, tstop=None, substeps=None, method=None,
             precision=None, outrate=None, input_seconds: float | None = None) -> Settings:
    """Resolve settings: explicit arguments win over `.options`, which win over `.tran`."""
    opt = net.options
    tstep = tstep or (net.tran.tstep if net.tran else None)
    if tstep is None or tstep <= 0:
        raise UsageError("no time step: the netlist has no .tran and no --tstep was given")
    tstop = tstop or (net.tran.tstop if net.tran else input_seconds)
    if tstop is None or tstop <= 0:
        raise UsageError("no stop time: the netlist has no .tran and no --tstop was given")
    substeps = int(substeps or opt.get("substeps", 1))
    method = str(method or opt.get("method", DEFAULT_METHOD)).lower()
    precision = str(precision or opt.get("precision", "float64")).lower()
    outrate = float(outrate or opt.get("outrate", 1.0 / tstep))
    if substeps < 1:
        raise UsageError(f"substeps must be a positive integer, got {substeps}")
    if method not in TABLEAUX and not expint.is_split(method):
        known = ", ".join([*TABLEAUX, *expint.SCHEMES])
        raise UsageError(f"unknown integrator {method!r}", hint=f"known: {known}")
    if precision not in PRECISIONS:
        raise UsageError(f"unknown precision {precision!r}", hint="float64 or float32")
    if outrate <= 0:
        raise UsageError(f"output rate must be positive, got {outrate}")
    return Settings(float(tstep), float(tstop), substeps, method, precision, outrate)
