"""Force sources: the `in(k)` input signals of each run and the signals shared by all runs.

Conventions (the kernel relies on them):
- The *input grid* has step `tstep` (the `.tran` step); the integration step is
  `h = tstep / substeps`. Input signals (`in(k)` and `wav(...)`) are resampled to the input grid
  and interpolated linearly at every stage time of the integrator. After its end a signal is 0.
- Analytic sources (`sin gauss step pwl`) and `wav` are the same for every run; they are
  tabulated at every stage time, `g[step, stage, force]` (exact values, no interpolation error
  for analytic sources).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from springc.sim.audio import list_audio, load_audio
from springc.errors import DataError, UsageError
from springc.kernels.integrators import Tableau
from springc.lang.ir import FlatNetlist, Source


def analytic(src: Source, t: np.ndarray) -> np.ndarray:
    """Value of an analytic source at times `t` (seconds)."""
    a = src.args
    match src.kind:
        case "sin":
            phase = a[2] if len(a) > 2 else 0.0
            return a[0] * np.sin(2 * np.pi * a[1] * t + phase)
        case "gauss":
            return a[0] * np.exp(-((t - a[1]) ** 2) / (2 * a[2] ** 2))
        case "step":
            return np.where(t >= a[1], a[0], 0.0)
        case "pwl":
            return np.interp(t, np.asarray(a[0::2]), np.asarray(a[1::2]))
        case _:
            raise TypeError(f"not an analytic source: {src.kind!r}")


def stage_times(nsteps: int, h: float, tab: Tableau) -> np.ndarray:
    """Times of every stage of every step, shape (nsteps, stages)."""
    return (np.arange(nsteps)[:, None] + np.asarray(tab.c)[None, :]) * h


def interpolate(samples: np.ndarray, rate: float, t: np.ndarray) -> np.ndarray:
    """Linear interpolation of a signal sampled at `rate` (first sample at t=0) at times `t`;
    0 after the last sample (the signal has ended)."""
    grid = np.arange(len(samples) + 1) / rate
    return np.interp(t, grid, np.append(samples, 0.0), right=0.0)


def common_forces(net: FlatNetlist) -> list[int]:
    """Indices of the force elements whose signal is shared by all runs (not `in`)."""
    return [e for e, s in enumerate(net.forces.source) if s.kind != "in"]


def input_forces(net: FlatNetlist) -> list[int]:
    """Indices of the force elements fed from the runs' input channels (`in(k)`), in node
    order (the kernel adds each node's inputs in its own pass, `codegen.emit_linear`)."""
    found = [e for e, s in enumerate(net.forces.source) if s.kind == "in"]
    return sorted(found, key=lambda e: int(net.forces.node[e]))


def channels_used(net: FlatNetlist) -> int:
    """Number of input channels the netlist reads (highest `in(k)` plus one; 0 if none)."""
    chans = [net.forces.source[e].channel for e in input_forces(net)]
    return max(chans) + 1 if chans else 0


def common_table(net: FlatNetlist, nsteps: int, h: float, tstep: float,
                 tab: Tableau) -> np.ndarray:
    """Shared force signals at every stage time, shape (nsteps, stages, n_common)."""
    idx = common_forces(net)
    if not idx:
        return np.zeros((1, 1, 0))
    out = np.empty((nsteps, tab.stages, len(idx)))
    for col, e in enumerate(idx):
        src = net.forces.source[e]
        if src.kind == "wav":
            samples = load_audio(src.path, 1.0 / tstep, src.channel)
            out[..., col] = at_stage_times(
                lambda t: interpolate(samples, 1.0 / tstep, t), nsteps, h, tab)
        elif src.kind == "sin":
            out[..., col] = sine_at_stage_times(src, nsteps, h, tab)
        else:
            out[..., col] = at_stage_times(lambda t: analytic(src, t), nsteps, h, tab)
    return out


def at_stage_times(f: Callable[[np.ndarray], np.ndarray], nsteps: int, h: float,
                   tab: Tableau) -> np.ndarray:
    """f at every stage time, shape (nsteps, stages) (`stage_times`), evaluated once per
    distinct time: stages at equal fractions share it, and a step's end (c = 1) is the next
    step's start (c = 0). Half the evaluations for RK4, whose sines were half the call's time
    on a one-dof resonator."""
    cs = sorted(set(tab.c) - ({1.0} if 0.0 in tab.c else set()))
    vals = f((np.arange(nsteps + 1)[:, None] + np.asarray(cs)[None, :]) * h)
    cols = [vals[1:, cs.index(0.0)] if c == 1.0 and 0.0 in tab.c else vals[:-1, cs.index(c)]
            for c in tab.c]
    return np.stack(cols, axis=1)


SINE_BLOCK = 256  # steps whose stage times share one block angle in `sine_at_stage_times`


def sine_at_stage_times(src: Source, nsteps: int, h: float, tab: Tableau) -> np.ndarray:
    """A `sin` source at every stage time, shape (nsteps, stages), by angle addition: with
    the step k = q B + r, the angle w (k + c) h + phase is the block's w q B h plus the
    offset's w (r + c) h + phase, so the sines and cosines of a few hundred angles and one
    product per entry make the table. Within a few round-offs of `analytic` (the angle's own
    rounding, about eps x angle, is the same order); the sines took a third of a one-mass
    simulation call."""
    amp, freq = src.args[0], src.args[1]
    phase = src.args[2] if len(src.args) > 2 else 0.0
    w = 2 * np.pi * freq
    blocks = -(-nsteps // SINE_BLOCK)
    a = w * (np.arange(blocks) * (SINE_BLOCK * h))
    b = w * ((np.arange(SINE_BLOCK)[:, None] + np.asarray(tab.c)[None, :]) * h) + phase
    sa, ca = (amp * f(a)[:, None, None] for f in (np.sin, np.cos))
    table = sa * np.cos(b) + ca * np.sin(b)  # (blocks, SINE_BLOCK, stages)
    return table.reshape(blocks * SINE_BLOCK, tab.stages)[:nsteps]


def expand_inputs(items: list[str | Path]) -> list[Path]:
    """Files named on the command line; a folder adds its sound files in sorted order."""
    paths: list[Path] = []
    for item in items:
        p = Path(item)
        if p.is_dir():
            found = list_audio(p)
            if not found:
                raise DataError(str(p), "folder holds no sound files (.wav .flac .ogg)")
            paths += found
        elif p.exists():
            paths.append(p)
        else:
            raise DataError(str(p), "no such file or folder")
    return paths


def read_inputs(paths: list[Path], rate: float, nch: int,
                channel: int | None = None) -> np.ndarray:
    """Sound files as input signals at `rate`, shape (runs, max(nch, 1), samples), zero-padded
    to the longest. With `channel`, that file channel feeds `in(0)`; otherwise file channel k
    feeds `in(k)` (a mono file for a netlist that reads only `in(0)`)."""
    if channel is not None and nch > 1:
        raise UsageError(f"--channel picks one file channel, but the netlist reads {nch} "
                         f"input channels (in(0)..in({nch - 1}))")
    rows = []
    for path in paths:
        if channel is not None or nch <= 1:
            rows.append([load_audio(path, rate, channel)])
        else:
            rows.append([load_audio(path, rate, k) for k in range(nch)])
    return stack_signals(rows)


def stack_signals(rows: list[list[np.ndarray]]) -> np.ndarray:
    """Zero-pad per-run, per-channel signals into one (runs, channels, samples) array."""
    length = max(len(s) for row in rows for s in row)
    out = np.zeros((len(rows), max(len(r) for r in rows), length))
    for r, row in enumerate(rows):
        for ch, sig in enumerate(row):
            out[r, ch, : len(sig)] = sig
    return out


def kernel_inputs(inputs: np.ndarray | None, runs: int, nch: int, nsamples: int,
                  dtype) -> np.ndarray:
    """Inputs laid out for the kernel: (runs, nch, nsamples + 2), zero after the signal so the
    interpolation at the last stage never reads past the end."""
    out = np.zeros((runs, nch, nsamples + 2), dtype=dtype)
    if inputs is not None and nch:
        take = min(inputs.shape[2], nsamples + 2)
        have = min(inputs.shape[1], nch)
        out[:, :have, :take] = inputs[:, :have, :take]
    return out
