"""Running ngspice in batch mode on an exported circuit and reading back its probe traces.

Used to cross-check springc against the most trusted circuit simulator (see `export_spice`).
ngspice is a separate program (Debian package `ngspice`); a missing or failing ngspice is a
`SimulationError` that says so, with the tail of ngspice's own log.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from springc.sim.audio import resample
from springc.errors import SimulationError, UsageError
from springc.export.spice import (
    SpiceOptions,
    control_block,
    export_spice,
    probe_vectors,
    transient,
)
from springc.check.checks import CheckedNetlist

_DATA_FILE = "probes.txt"
# Lines that end the circuit or run it; run_ngspice supplies its own.
_CONTROL = re.compile(
    r"^\s*\.control\b.*?^\s*\.endc\b[^\n]*\n?", re.IGNORECASE | re.MULTILINE | re.DOTALL
)
_TRAN_OR_END = re.compile(r"^\s*\.(tran|end)\b[^\n]*\n?", re.IGNORECASE | re.MULTILINE)


def ngspice_path() -> str:
    """Path of the ngspice executable; SimulationError if it is not installed."""
    path = shutil.which("ngspice")
    if path is None:
        raise SimulationError(
            "ngspice is not installed (not found on PATH)",
            hint="install the Debian package: apt-get install ngspice",
        )
    return path


def run_ngspice(
    netlist_text: str,
    tstop: float,
    tstep: float,
    probes: dict[str, str],
    tmax: float | None = None,
    timeout: float = 600.0,
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Run a transient of `netlist_text` from its initial conditions (`uic`) to `tstop` and
    return ngspice's own time points and one trace per probe (label -> ngspice vector, e.g.
    {"x(a)": "v(x0)"}). Any `.tran`, `.control` or `.end` in the text is replaced. The time
    points are those ngspice chose (at most `tmax`, default `tstep`, apart), not interpolated,
    so that the comparison is not blurred by output interpolation."""
    exe = ngspice_path()
    if not probes:
        raise SimulationError("nothing to record: the netlist has no .probe")
    text = _with_control(netlist_text, tstop, tstep, tmax or tstep, list(probes.values()))
    with tempfile.TemporaryDirectory(prefix="springc-ngspice-") as tmp:
        (Path(tmp) / "circuit.cir").write_text(text)
        log = _run(exe, Path(tmp), timeout)
        data = _read_data(Path(tmp) / _DATA_FILE, len(probes), log)
    return data[:, 0], {label: data[:, k + 1] for k, label in enumerate(probes)}


def simulate_ngspice(
    checked: CheckedNetlist, options: SpiceOptions | None = None
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Export the checked netlist and run it in ngspice: time points and one trace per probe
    label."""
    options = options or SpiceOptions()
    net = checked.net
    tstep, tstop, tmax = transient(net, options)
    return run_ngspice(export_spice(checked, options), tstop, tstep, probe_vectors(net), tmax)


@dataclass
class CrossCheck:
    """springc's simulator against ngspice on one exported network (one run).

    `t` and `springc[label]` are springc's output grid; `ngspice[label]` is ngspice's trace
    interpolated onto it (its own steps are finer than the grid); `errors[label]` is the
    relative L2 difference; `*_seconds` are wall times (springc's includes compilation unless
    its kernel cache is warm) and `tstop` the simulated time."""

    t: np.ndarray
    springc: dict[str, np.ndarray]
    ngspice: dict[str, np.ndarray]
    errors: dict[str, float]
    springc_seconds: float
    ngspice_seconds: float
    tstop: float


def cross_check(checked: CheckedNetlist, options: SpiceOptions,
                substeps: int | None = None) -> CrossCheck:
    """Simulate the checked netlist with springc (RK4 unless its options say otherwise, `substeps`
    per output step) and with ngspice, from the same inputs, and compare every probe."""
    from springc.sim.simulate import simulate  # the simulator is heavy: import on use

    net = checked.net
    if not net.probes:
        raise UsageError("nothing to compare: the netlist has no .probe")
    tstep, tstop, _ = transient(net, options)
    start = time.perf_counter()
    t_ng, traces = simulate_ngspice(checked, options)
    ngspice_seconds = time.perf_counter() - start
    start = time.perf_counter()
    res = simulate(
        checked,
        _input_array(options, 1 / tstep),
        1 / tstep,
        tstep=tstep,
        tstop=tstop,
        substeps=substeps,
    )
    springc_seconds = time.perf_counter() - start
    ours = {label: res.probes[label][0] for label in traces}
    theirs = {label: np.interp(res.t, t_ng, trace) for label, trace in traces.items()}
    errors = {label: _rel_l2(ours[label], theirs[label]) for label in traces}
    return CrossCheck(res.t, ours, theirs, errors, springc_seconds, ngspice_seconds, tstop)


def plot_cross_check(check: CrossCheck, path: str | Path) -> None:
    """PNG: every probe from both simulators, and their difference, against time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from springc.sim.results import atomic_path

    labels = list(check.errors)
    fig, axes = plt.subplots(
        len(labels), 2, sharex=True, squeeze=False, figsize=(11, 1.8 + 1.8 * len(labels))
    )
    for row, label in zip(axes, labels):
        row[0].plot(check.t, check.ngspice[label], lw=1.6, color="0.7", label="ngspice")
        row[0].plot(check.t, check.springc[label], lw=0.7, color="C0", label="springc")
        row[0].set_ylabel(label)
        row[1].plot(check.t, check.springc[label] - check.ngspice[label], lw=0.7, color="C3")
        row[1].set_title(
            f"springc - ngspice (relative L2 {check.errors[label]:.1e})", fontsize="small"
        )
    axes[0, 0].legend(fontsize="small", loc="upper right")
    for ax in axes[-1]:
        ax.set_xlabel("t (s)")
    fig.tight_layout()
    with atomic_path(path, ".png") as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def _input_array(options: SpiceOptions, rate: float) -> np.ndarray | None:
    """The bound in(k) signals as springc's (1, channels, samples) input array at `rate`."""
    if not options.inputs:
        return None
    channels = max(options.inputs) + 1
    rows = [np.zeros(1)] * channels
    for k, (samples, rate_in) in options.inputs.items():
        rows[k] = resample(np.asarray(samples, dtype=np.float64), rate_in, rate)
    out = np.zeros((1, channels, max(len(r) for r in rows)))
    for k, row in enumerate(rows):
        out[0, k, : len(row)] = row
    return out


def _rel_l2(got: np.ndarray, want: np.ndarray) -> float:
    norm = float(np.linalg.norm(want))
    return float(np.linalg.norm(got - want)) / norm if norm > 0 else float(np.linalg.norm(got))


def _with_control(text: str, tstop: float, tstep: float, tmax: float, vectors: list[str]) -> str:
    body = _TRAN_OR_END.sub("", _CONTROL.sub("", text)).rstrip("\n")
    tran = f".tran {tstep!r} {tstop!r} 0 {tmax!r} uic"
    return "\n".join([body, tran, *control_block(vectors, _DATA_FILE), ".end"]) + "\n"


def _run(exe: str, folder: Path, timeout: float) -> str:
    try:
        proc = subprocess.run(
            [exe, "-b", "circuit.cir"],
            check=False,
            cwd=folder,
            capture_output=True,
            text=True,
            timeout=timeout,
        )
    except subprocess.TimeoutExpired:
        raise SimulationError(f"ngspice did not finish within {timeout:g} s") from None
    log = proc.stdout + proc.stderr
    if proc.returncode != 0:
        raise SimulationError(f"ngspice failed (exit status {proc.returncode}):\n{_tail(log)}")
    return log


def _read_data(path: Path, n_probes: int, log: str) -> np.ndarray:
    if not path.is_file():
        raise SimulationError(f"ngspice wrote no results:\n{_tail(log)}")
    data = np.loadtxt(path, skiprows=1, ndmin=2)
    if data.shape[0] == 0 or data.shape[1] != n_probes + 1:
        raise SimulationError(
            f"ngspice results have shape {data.shape}, expected (T, {n_probes + 1}):\n{_tail(log)}"
        )
    return data


def _tail(log: str, lines: int = 20) -> str:
    return "\n".join(log.strip().splitlines()[-lines:])
