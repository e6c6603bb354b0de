"""Writing simulation results: `.npz`, `.csv` and PNG plots, each through a temporary file
renamed into place, so a failed or interrupted write never leaves a partial output.

`.npz` keys: `t` (T,), one (runs, T) array per probe named exactly as written (`x(X1.out)`),
one (runs,) array per reduction named by its spec (`work:in`), and `runs` (the run names).
`.csv` is long format, one value per row: `run,quantity,t,value` (a reduction has t = stop time).
"""

from __future__ import annotations

import contextlib
import csv
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from springc.errors import UsageError
from springc.sim.simulate import SimResult

FORMATS = (".npz", ".csv")


@contextlib.contextmanager
def atomic_path(path: str | Path, suffix: str = "") -> Iterator[Path]:
    """A temporary path beside `path`, renamed onto it on success and removed on failure."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=suffix)
    os.close(fd)
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def check_output_path(path: str | Path) -> None:
    """Fail early (before simulating) on an output name we cannot write."""
    if Path(path).suffix.lower() not in FORMATS:
        raise UsageError(f"output {path}: unknown format", hint="use a .npz or .csv file name")


def write(result: SimResult, path: str | Path) -> None:
    """Write `result` to `path` in the format its suffix names."""
    check_output_path(path)
    if Path(path).suffix.lower() == ".npz":
        write_npz(result, path)
    else:
        write_csv(result, path)


def write_npz(result: SimResult, path: str | Path) -> None:
    """All arrays in one `.npz` (keys as in the module docstring)."""
    arrays = {"t": result.t, **result.probes, **result.reductions,
              "runs": np.asarray(result.runs)}
    with atomic_path(path, ".npz") as tmp, open(tmp, "wb") as fh:
        np.savez(fh, **arrays)


def write_csv(result: SimResult, path: str | Path) -> None:
    """Long-format CSV: `run,quantity,t,value`."""
    tstop = float(result.t[-1]) if len(result.t) else 0.0
    with atomic_path(path) as tmp, open(tmp, "w", newline="") as fh:
        out = csv.writer(fh)
        out.writerow(["run", "quantity", "t", "value"])
        for r, run in enumerate(result.runs):
            for label, data in result.probes.items():
                out.writerows((run, label, repr(float(t)), repr(float(v)))
                              for t, v in zip(result.t, data[r]))
            for spec, data in result.reductions.items():
                out.writerow((run, spec, repr(tstop), repr(float(data[r]))))


def plot(result: SimResult, path: str | Path, max_runs: int = 4) -> None:
    """PNG of every probe against time for the first `max_runs` runs."""
    save_figure(figure(result, max_runs), path)


def figure(result: SimResult, max_runs: int = 4):
    """A matplotlib figure of every probe against time for the first `max_runs` runs."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = list(result.probes)
    if not labels:
        raise UsageError("--plot needs at least one probe (.probe in the netlist)")
    fig, axes = plt.subplots(len(labels), 1, sharex=True, squeeze=False,
                             figsize=(8, 1.8 + 1.6 * len(labels)))
    for ax, label in zip(axes[:, 0], labels):
        for r in range(min(max_runs, len(result.runs))):
            ax.plot(result.t, result.probes[label][r], lw=0.8, label=Path(result.runs[r]).name)
        ax.set_ylabel(label)
    axes[-1, 0].set_xlabel("t (s)")
    if len(result.runs) > 1:
        axes[0, 0].legend(fontsize="small", loc="upper right")
    fig.tight_layout()
    return fig


def save_figure(fig, path: str | Path) -> None:
    """Write a figure as a PNG atomically, and free it."""
    import matplotlib.pyplot as plt

    with atomic_path(path, ".png") as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
