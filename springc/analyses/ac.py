"""Small-signal frequency response of the linearisation at rest (`.ac`, `springc ac`).

H(f) = X_node(f) / U(f) solves (K - w^2 M + i w B) X = F for every frequency, where F holds
the gains of every `F ... in(k)` element of the chosen input channel k. Small networks solve
all frequencies at once with batched dense LU; larger ones factor a sparse matrix per
frequency.
"""

from __future__ import annotations

import math
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from springc.check import linear
from springc.check.checks import CheckedNetlist, require_checked
from springc.errors import UsageError
from springc.lang.ir import FlatNetlist

DENSE_MAX = 400  # networks up to this many dofs are solved with batched dense LU
DEFAULT_POINTS = 200


@dataclass(frozen=True)
class Sweep:
    """Log-spaced frequencies from fmin to fmax (Hz), `points` of them."""

    fmin: float
    fmax: float
    points: int

    def frequencies(self) -> np.ndarray:
        # what `.ac` accepts: a band of points >= 2, or one frequency (fmin = fmax)
        if not (0 < self.fmin <= self.fmax < math.inf) or self.points < 1 or (
                self.fmin < self.fmax and self.points < 2):
            raise UsageError(f"bad sweep: need 0 < fmin < fmax and points >= 2, or one "
                             f"frequency fmin = fmax (got fmin={self.fmin:g}, fmax="
                             f"{self.fmax:g}, points={self.points})")
        return np.geomspace(self.fmin, self.fmax, self.points)


@dataclass
class AcResult:
    """Complex response H at frequencies `f_hz` of node `node` to input channel `channel`."""

    node: str
    channel: int
    f_hz: np.ndarray
    h: np.ndarray

    @property
    def mag(self) -> np.ndarray:
        return np.abs(self.h)

    @property
    def phase(self) -> np.ndarray:
        """Phase in radians, in (-pi, pi]."""
        return np.angle(self.h)

    def plot(self, path: str | Path | None = None, *, ax=None):
        """Magnitude (log-log) over phase (rad) against frequency. `ax`: a matplotlib Axes
        for the magnitude alone, or two (magnitude, phase); else a new figure of both.
        Returns the new figure (written as a PNG too where `path` is given), or `ax` as given
        (its figure written to `path` where given)."""
        from springc.sim.results import plot_into

        return plot_into(lambda *axes: draw(self, *axes), ax, path, panels=2,
                         figsize=(7, 5.5), dpi=120)

    def to_xarray(self):
        """An `xarray.Dataset` over frequency `f` (Hz): the complex response `h`, `mag` and
        `phase` (rad). The input in(k) is a number (each `F ... in(k)` a force of `gain` N per
        unit), so `h` and `mag` are metres of displacement per unit input (`units` m)."""
        return dataset(self, ("f",))


def input_vector(net: FlatNetlist, channel: int) -> np.ndarray:
    """Force per unit input: the gains of the `F ... in(channel)` elements, summed per node."""
    f = net.forces
    driven = np.array([s.kind == "in" and s.channel == channel for s in f.source], bool)
    if not driven.any():
        raise UsageError(f"no F element is driven by in({channel}); the frequency response "
                         f"needs at least one", hint="add e.g. 'F1 <node> in(0)'")
    out = np.zeros(net.n)
    np.add.at(out, f.node[driven], f.gain[driven])
    return out


def response(checked: CheckedNetlist, node: str, f_hz: np.ndarray, channel: int = 0,
             progress: bool = False) -> AcResult:
    """H(f) = X_node / U of the checked netlist's linearisation at rest, at frequencies `f_hz`
    (Hz); with `progress`, large networks (one sparse factorisation per frequency) show a
    progress bar."""
    net = require_checked(checked, "ac.response").net
    if node not in net.nodes:
        raise UsageError(f"unknown node '{node}'", hint=near(net, node))
    target = net.nodes.index(node)
    force = input_vector(net, channel)
    lin = linear.linearise(net)
    w = 2 * np.pi * np.asarray(f_hz, dtype=np.float64)
    if net.n <= DENSE_MAX:
        h = _dense(lin, force, w, target)
    else:
        h = _sparse(lin, force, w, target, progress)
    return AcResult(node, channel, np.asarray(f_hz, dtype=np.float64), h)


def near(net: FlatNetlist, node: str) -> str:
    """A hint naming the nodes closest to a mistyped `node`."""
    import difflib

    close = difflib.get_close_matches(node, net.nodes, n=3, cutoff=0.5)
    return f"did you mean {', '.join(close)}?" if close else "node names are case-sensitive"


def _dense(lin: linear.Linearisation, force: np.ndarray, w: np.ndarray, target: int):
    k, m, b = lin.K.toarray(), lin.M.toarray(), lin.B.toarray()
    n = len(force)
    chunk = max(1, 4_000_000 // max(n * n, 1))  # bound memory of the stacked systems
    out = np.empty(len(w), complex)
    for lo in range(0, len(w), chunk):
        ww = w[lo:lo + chunk, None, None]
        system = k[None] - ww**2 * m[None] + 1j * ww * b[None]
        rhs = np.broadcast_to(force.astype(complex), (len(ww), n))[..., None]
        out[lo:lo + chunk] = np.linalg.solve(system, rhs)[:, target, 0]
    return out


def _sparse(lin: linear.Linearisation, force: np.ndarray, w: np.ndarray, target: int,
            progress: bool):
    from tqdm import tqdm

    k, m, b = (x.astype(complex).tocsc() for x in (lin.K, lin.M, lin.B))
    out = np.empty(len(w), complex)
    bar = tqdm(w, desc="ac", unit="freq", disable=not progress, leave=False)
    for idx, ww in enumerate(bar):
        out[idx] = sla.spsolve(sp.csc_matrix(k - ww**2 * m + 1j * ww * b), force)[target]
    return out


def target(net: FlatNetlist, node: str | None, channel: int | None) -> tuple[str, int]:
    """(output node, input channel): as given, else the `.ac` directive's (channel 0 without
    one); no node at all is a `UsageError`."""
    spec = net.acs[0] if net.acs else None
    if node is None:
        if spec is None:
            raise UsageError("no output node: give --node or an .ac directive")
        node = net.nodes[spec.node]
    if channel is None:
        channel = spec.input if spec else 0
    return node, channel


def sweep(net: FlatNetlist, fmin: float | None = None, fmax: float | None = None,
          points: int | None = None) -> Sweep:
    """`default_sweep` with any of its bounds or its count replaced."""
    return override(default_sweep(net), fmin, fmax, points)


def override(base: Sweep, fmin: float | None, fmax: float | None,
             points: int | None) -> Sweep:
    """`base` with the bounds and count that are given (0 is given, and refused)."""
    return Sweep(base.fmin if fmin is None else fmin, base.fmax if fmax is None else fmax,
                 base.points if points is None else points)


def default_sweep(net: FlatNetlist) -> Sweep:
    """From `.ac` if present, else a decade below the slowest to a decade above the fastest
    mode (1 Hz to 10 kHz if there are none)."""
    if net.acs:
        ac = net.acs[0]
        return Sweep(ac.fstart, ac.fstop, ac.points)
    found = linear.modes(net)
    f = found.freqs_hz[found.freqs_hz > 0]
    if len(f) == 0:
        return Sweep(1.0, 1e4, DEFAULT_POINTS)
    return Sweep(float(f.min()) / 10, float(f.max()) * 10, DEFAULT_POINTS)


def write_csv(result: AcResult, path: str | Path) -> None:
    """Columns exactly `f_hz,mag,phase_rad`, written atomically (temp file, then rename)."""
    table = np.column_stack([result.f_hz, result.mag, result.phase])
    _atomic(path, lambda f: np.savetxt(f, table, delimiter=",", header="f_hz,mag,phase_rad",
                                       comments="", fmt="%.17g"))


def plot(result: AcResult, path: str | Path) -> None:
    """PNG: magnitude (log-log) over phase (rad), written atomically (`AcResult.plot`)."""
    result.plot(path)


def draw(result: AcResult, top, bottom=None) -> None:
    """The magnitude on Axes `top` (log-log) and, where given, the phase (rad) on
    `bottom`."""
    top.loglog(result.f_hz, result.mag)
    top.set_ylabel("|H| (displacement / input)")
    top.set_title(f"frequency response of x({result.node}) to in({result.channel})")
    if bottom is not None:
        bottom.semilogx(result.f_hz, result.phase)
        bottom.set_ylabel("phase (rad)")
    for ax in (top, bottom):
        if ax is not None:
            ax.grid(True, which="both", alpha=0.3)
    (top if bottom is None else bottom).set_xlabel("frequency (Hz)")


def dataset(result: AcResult, dims: tuple[str, ...], coords: dict | None = None):
    """`AcResult.to_xarray` for a response `h` over `dims` (the last one `f`), with more
    `coords` (a family's points)."""
    import xarray as xr

    per = f"displacement of {result.node} per unit in({result.channel})"
    data = {"h": (dims, result.h, {"units": "m", "long_name": f"H, {per}"}),
            "mag": (dims, result.mag, {"units": "m", "long_name": f"|H|, {per}"}),
            "phase": (dims, result.phase, {"units": "rad", "long_name": "phase of H"})}
    f = ("f", result.f_hz, {"units": "Hz", "long_name": "frequency"})
    return xr.Dataset(data, coords={"f": f, **(coords or {})},
                      attrs={"node": result.node, "input": result.channel})


def _atomic(path: str | Path, write) -> None:
    """Write through `write(file)` to a temp file in the target folder, then rename."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent or ".", prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
