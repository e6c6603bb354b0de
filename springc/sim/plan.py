"""How a simulation integrates: the integrator and substeps the caller or the netlist names,
or else the cheapest that meets an error tolerance (`DEFAULT_TOLERANCE` when none is given).

RK4 at one step per input sample, the old default, is off by 0.86 on the feature extractor
(docs/bench.md), so nobody gets an unchecked step by default: `springc sim` and
`springc.Netlist.simulate` choose it, print or return why, and take `--method`/`--substeps`
(or `.options method=`/`substeps=`) as the user's own choice.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from springc.check import CheckedNetlist, store
from springc.check.accuracy import DEFAULT_TOLERANCE, choose
from springc.check.checks import pinned
from springc.errors import UsageError
from springc.sim.sources import expand_inputs
from springc.sim.stepcheck import verify

KERNEL_FORMS = {"auto": None, "written-out": True, "shared": False}  # simulate's write_out


@dataclass(frozen=True)
class Steps:
    """The integrator to run (None: the netlist's or the simulator's default) and, where it
    was chosen for a tolerance, the reason in words."""

    method: str | None
    substeps: int | None
    choice: str | None = None


def integration(checked: CheckedNetlist, tolerance: float | None, method: str | None,
                substeps: int | None, tstep: float | None, tstop: float | None, inputs=None,
                channel: int | None = None, input_rate: float | None = None) -> Steps:
    """The method and substeps to simulate with: as given, as the netlist's `.options` set
    them, or chosen for `tolerance` (`DEFAULT_TOLERANCE` when the caller and the netlist name
    neither), by the per-mode estimate and, on nonlinear terms, step doubling over the start
    of the first run (`springc.sim.stepcheck`)."""
    net = checked.net
    if tolerance is not None and (method or substeps):
        raise UsageError("--tolerance chooses the method and substeps itself",
                         hint="drop --method/--substeps, or drop --tolerance")
    default = tolerance is None
    if default and pinned(net, method, substeps):
        return Steps(method, substeps)
    tstep = tstep or (net.tran.tstep if net.tran else None)
    if tstep is None:  # the simulator says what is missing
        return Steps(method, substeps)
    duration = tstop or (net.tran.tstop if net.tran else 1.0)
    tol = DEFAULT_TOLERANCE if default else tolerance
    pilot = first_run(inputs)
    try:
        # both depend on the netlist, these settings and the first run's input alone: kept
        # beside the netlist's entry in the check cache
        what = f"{tstep!r} {duration!r} {tol!r}"
        linear = store.remembered(checked, f"choice {what}",
                                  lambda: choose(net, tstep, duration, tol, found=checked.modes))
        chosen = store.remembered(
            checked, f"verified {what} {channel!r} {input_rate!r} {input_digest(pilot)}",
            lambda: verify(checked, linear, tstep, duration, tol, pilot, channel, input_rate))
    except UsageError as err:
        if not default:
            raise
        raise UsageError(f"{err.message} (springc's default accuracy target)",
                         hint="loosen it with --tolerance, or choose the integrator "
                              "with --method/--substeps") from None
    return Steps(chosen.method, chosen.substeps, chosen.describe())


def input_digest(pilot) -> str:
    """What the first run's input is, for `store.remembered`: a digest of its samples or of
    its file's bytes ('none' for a run without input)."""
    if pilot is None:
        return "none"
    if isinstance(pilot, np.ndarray):
        data = np.ascontiguousarray(pilot).tobytes() + repr(pilot.shape).encode()
    else:
        data = b"".join(Path(p).read_bytes() for p in pilot)
    return hashlib.sha256(data).hexdigest()


def first_run(inputs):
    """The first run's input, as `simulate` takes it (None: a run without input)."""
    if isinstance(inputs, np.ndarray):
        return inputs[:1]
    return expand_inputs(list(inputs))[:1] if inputs else None
