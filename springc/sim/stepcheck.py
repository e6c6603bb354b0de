"""Step doubling: the error a tolerance-driven choice makes on a netlist's nonlinear terms.

`springc.check.accuracy.choose` estimates each mode's error from the linearisation. That is the
whole error of a linear network, but not of a nonlinear one: a quadratic coupling squares a
filter's output (frequencies the linear modes do not have), and a splitting scheme's blocks
are exact only up to their coupling through such terms (on the feature extractor the linear
estimate is orders of magnitude too small: docs/performance.md#how---tolerance-chooses).

So for a netlist with nonlinear terms, `verify` simulates the start of the first run
(`PILOT_S` seconds or `PILOT_SAMPLES` input samples, the longer, within the run) at the
chosen substeps and at twice as many and takes the difference as the error: for a method of
order p, y(s) - y(2s) is (1 - 2^-p) of y(s)'s error. While that exceeds the tolerance it
moves to the substeps the order predicts (of `accuracy.SUBSTEPS`) and checks again. The
pilot stretch is short, so errors that only build up later (a slow mode's drift over a long
run) are the linear estimate's to catch.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from springc.check import CheckedNetlist, accuracy
from springc.check.accuracy import nonlinear
from springc.sim import simulate
from springc.errors import UsageError

PILOT_S = 0.05  # seconds of the first run that step doubling integrates, at least,
PILOT_SAMPLES = 1000  # and input samples (slow netlists: periods rather than milliseconds)
MAX_TRIES = 4  # substeps tried before giving up


def doubling_error(checked: CheckedNetlist, method: str, substeps: int, tstep: float, inputs,
                   duration: float, channel: int | None = None,
                   runs: dict[int, dict] | None = None,
                   input_rate: float | None = None) -> float:
    """Worst probe's relative L2 error of `method` at `substeps` over the first `duration`
    seconds of `inputs` (one run), estimated by step doubling (module docstring). `runs`:
    probes already simulated, by substeps (filled in; a retry at twice the substeps reuses
    the finer run)."""
    runs = {} if runs is None else runs
    net = checked.net
    probes = None if net.probes else [f"x({n})" for n in net.nodes]
    # noiseless: step doubling judges the deterministic dynamics (the noise of two steps
    # differs by design)
    kw = dict(tstep=tstep, tstop=duration, method=method, probes=probes, channel=channel,
              temp=0.0)
    for sub in (substeps, 2 * substeps):
        if sub not in runs:
            runs[sub] = simulate.simulate(checked, inputs, input_rate, substeps=sub,
                                          **kw).probes
    coarse, fine = runs[substeps], runs[2 * substeps]
    shrink = 1.0 - 2.0 ** -simulate.method_order(method)
    worst = 0.0
    for label, y in fine.items():
        norm = float(np.linalg.norm(y[0]))
        if norm > 0:
            diff = float(np.linalg.norm(coarse[label][0] - y[0]))
            worst = max(worst, diff / norm / shrink)
    return worst


def verify(checked: CheckedNetlist, choice: accuracy.Choice, tstep: float, duration: float,
           tol: float, inputs=None, channel: int | None = None,
           input_rate: float | None = None) -> accuracy.Choice:
    """`choice` checked by step doubling when `net` is nonlinear (module docstring): the same
    method at the fewest substeps whose doubling error meets `tol` over the start of a run of
    `duration` seconds, with that error in `choice.pilot_error`. `inputs`, `channel`: the
    first run's input as `simulate` takes it (None: a run without input; an array at
    `input_rate`, default 1/tstep)."""
    net = checked.net
    if not nonlinear(net):
        return choice
    pilot = min(duration, max(PILOT_S, PILOT_SAMPLES * tstep))
    order = simulate.method_order(choice.method)
    sub = choice.substeps
    runs: dict[int, dict] = {}
    for _ in range(MAX_TRIES):
        err = doubling_error(checked, choice.method, sub, tstep, inputs, pilot, channel, runs,
                             input_rate)
        if err <= tol:
            return replace(choice, substeps=sub, h=tstep / sub,
                           cost=accuracy.cost(net, choice.method, sub), pilot_error=err,
                           pilot_s=pilot, linear_substeps=choice.substeps)
        want = sub * (err / tol) ** (1.0 / order) if math.isfinite(err) else 2 * sub
        sub = next((s for s in accuracy.SUBSTEPS if s >= max(want, 2 * sub)), 0)
        if not sub:
            break
    raise UsageError(f"{choice.method} does not meet tolerance {tol:g} on the netlist's "
                     f"nonlinear terms with up to {max(accuracy.SUBSTEPS)} substeps (step "
                     f"doubling over the first {pilot:g} s of the first run)",
                     hint="raise the tolerance or lower .tran tstep")
