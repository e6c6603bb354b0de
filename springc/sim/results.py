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
from collections.abc import Callable, Iterator, Sequence
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
    """A matplotlib figure of every probe against time for the first `max_runs` runs, one
    panel per probe."""
    return plot_into(lambda *axes: draw(result, axes, max_runs), None, None,
                     panels=len(_probe_labels(result)),
                     figsize=(8, 1.8 + 1.6 * len(result.probes)))


def _probe_labels(result: SimResult) -> list[str]:
    if not result.probes:
        raise UsageError("--plot needs at least one probe (.probe in the netlist)")
    return list(result.probes)


def draw(result: SimResult, axes: Sequence, max_runs: int = 4) -> None:
    """Every probe against time for the first `max_runs` runs: probe k on `axes[k]`, or
    every probe on `axes[0]` where one Axes is given (each curve then named by its probe)."""
    labels = _probe_labels(result)
    shared = len(axes) == 1 and len(labels) > 1
    if not shared and len(axes) != len(labels):
        raise ValueError(f"ax: one Axes, or one per probe ({len(labels)}), not {len(axes)}")
    runs = range(min(max_runs, len(result.runs)))
    for k, label in enumerate(labels):
        ax = axes[0 if shared else k]
        for r in runs:
            run = Path(result.runs[r]).name
            ax.plot(result.t, result.probes[label][r], lw=0.8,
                    label=f"{label} {run}" if shared else run)
        ax.set_ylabel(", ".join(labels) if shared else label)
    axes[-1].set_xlabel("t (s)")
    if len(result.runs) > 1 or shared:
        axes[0].legend(fontsize="small", loc="upper right")


def plot_into(draw_on: Callable[..., None], ax, path: str | Path | None, *,
              panels: int = 1, figsize: tuple[float, float] = (7, 4), dpi: int = 110):
    """Draw a plot through `draw_on(*axes)`: on `ax` where given (an Axes, or a sequence of
    up to `panels` of them, top to bottom), else on a new figure of `panels` rows sharing
    the x axis. With `path`, also a PNG written atomically (a new figure is then closed, as
    the commands draw many). Returns the new figure, or `ax` as given."""
    if ax is None:
        fig, axes = pyplot().subplots(panels, 1, sharex=True, squeeze=False, figsize=figsize)
        draw_on(*axes[:, 0])
        fig.tight_layout()
        if path is not None:
            save_figure(fig, path, dpi)
        return fig
    from matplotlib.axes import Axes

    axes = [ax] if isinstance(ax, Axes) else list(ax)
    if not 1 <= len(axes) <= panels:
        raise ValueError(f"ax: an Axes or up to {panels} of them, not {len(axes)}")
    draw_on(*axes)
    if path is not None:
        save_figure(axes[0].figure, path, dpi, close=False)  # the caller's figure stays open
    return ax


def pyplot():
    """matplotlib.pyplot on the Agg back end when it makes a figure of its own: the commands
    run without a display (a figure drawn into a caller's Axes keeps the caller's back end)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path: str | Path, dpi: int = 110, close: bool = True) -> None:
    """Write a figure as a PNG atomically and (`close`) free it."""
    with atomic_path(path, ".png") as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    if close:
        import matplotlib.pyplot as plt

        plt.close(fig)


UNITS = {"x(": "m", "v(": "m/s", "final:x": "m", "final:v": "m/s", "msq:x": "m^2",
         "msq:v": "m^2/s^2", "work": "J", "dissipated": "J", "energy": "J", "loss": "dB",
         "gram": "m^2 s"}


def units(name: str) -> str | None:
    """The SI unit of a probe or reduction by its written name (`x(a)`: m, `msq:v(a)`:
    m^2/s^2, `work:in`: J, `loss:B1`: dB, `gram:...`: m^2 s, the integral of x_k x_l dt);
    None for a name that is neither (a `gram_reduction` given a label of its own)."""
    kind, _, rest = name.partition(":")
    if kind[:2] in ("x(", "v(") and not rest:  # a probe
        return UNITS[kind[:2]]
    if kind in ("final", "msq"):
        kind = f"{kind}:{rest[:1]}"
    return UNITS.get(kind) if bool(rest) != (kind == "energy") else None
