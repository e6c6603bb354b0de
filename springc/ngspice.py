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
from pathlib import Path

import numpy as np

from springc.errors import SimulationError
from springc.export_spice import (
    SpiceOptions,
    control_block,
    export_spice,
    probe_vectors,
    transient,
)
from springc.ir import FlatNetlist

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
    net: FlatNetlist, options: SpiceOptions | None = None
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Export `net` and run it in ngspice: time points and one trace per probe label."""
    options = options or SpiceOptions()
    tstep, tstop, tmax = transient(net, options)
    return run_ngspice(export_spice(net, options), tstop, tstep, probe_vectors(net), tmax)


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
