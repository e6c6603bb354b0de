"""The linear analyses at every point of a `.step`/`.mc` netlist (docs/language.md, "Sweeps
and Monte Carlo"): `springc ac` and `springc modes` on a population.

    checked PointSet -> ac_family / modes_family -> one curve or mode table per point

Every point is analysed on its own checked netlist, exactly as `springc.analyses.ac` and
`springc.analyses.modes` analyse one netlist; the frequency responses share one grid (the
union of the points' bands), so the family is one (points, frequencies) array. Outputs carry
the points table: each point's index, step values and, with `.mc`, sample index and seed.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from springc.analyses import ac
from springc.analyses.modes import mode_report, mode_text
from springc.errors import UsageError
from springc.lang.variation import Point, PointSet
from springc.sim.results import atomic_path


@dataclass
class AcFamily(ac.AcResult):
    """The response H of `node` to input channel `channel` at every point: `h[point, f]`
    at frequencies `f_hz` (`mag` and `phase` likewise), `points` the points in order."""

    points: tuple[Point, ...]

    def __len__(self) -> int:
        return len(self.points)

    def __getitem__(self, index: int) -> ac.AcResult:
        """Point `index`'s response as `springc ac` gives it for one netlist."""
        return ac.AcResult(self.node, self.channel, self.f_hz, self.h[index])

    def to_json(self) -> dict:
        """`{"node", "input", "f", "points": [{"index", "steps", "sample", "seed", "mag",
        "phase"}]}`."""
        rows = [p.to_json() | {"mag": self.mag[i].tolist(), "phase": self.phase[i].tolist()}
                for i, p in enumerate(self.points)]
        return {"node": self.node, "input": self.channel, "f": self.f_hz.tolist(),
                "points": rows}

    def plot(self, path: str | Path | None = None, *, ax=None):
        """Every point's magnitude (log-log) over its phase (rad), one colour per point. `ax`:
        a matplotlib Axes for the magnitudes alone, or two (magnitude, phase); else a new
        figure of both. Returns the new figure (written as a PNG too where `path` is given),
        or `ax` as given (its figure written to `path` where given)."""
        from springc.sim.results import plot_into

        return plot_into(lambda *axes: draw_ac(self, *axes), ax, path, panels=2,
                         figsize=(7, 5.5), dpi=100)

    def to_xarray(self):
        """`AcResult.to_xarray` over (point, f), with the points table (`point_columns`:
        each stepped parameter, `sample` and `seed` with `.mc`) as coordinates along
        `point`."""
        cols = point_columns(self.points)
        coords = {"point": cols.pop("point")} | {k: ("point", v) for k, v in cols.items()}
        return ac.dataset(self, ("point", "f"), coords)


def family_sweep(points: PointSet, fmin: float | None, fmax: float | None,
                 count: int | None) -> ac.Sweep:
    """One grid for every point: the union of the points' bands (each its `.ac`, else a
    decade around its modes), with the bounds and count that are given."""
    bands = [_band(checked) for checked in points.checked]
    base = ac.Sweep(min(b.fmin for b in bands), max(b.fmax for b in bands),
                    max(b.points for b in bands))
    return ac.override(base, fmin, fmax, count)


def _band(checked) -> ac.Sweep:
    """`ac.default_sweep` of one point, from the modes its check already computed."""
    net = checked.net
    if net.acs or checked.modes is None:
        return ac.default_sweep(net)
    f = checked.modes.freqs_hz[checked.modes.freqs_hz > 0]
    if len(f) == 0:
        return ac.Sweep(1.0, 1e4, ac.DEFAULT_POINTS)
    return ac.Sweep(float(f.min()) / 10, float(f.max()) * 10, ac.DEFAULT_POINTS)


def ac_family(points: PointSet, node: str | None = None, channel: int | None = None,
              fmin: float | None = None, fmax: float | None = None, count: int | None = None,
              progress: bool = False) -> AcFamily:
    """H(f) of every checked point (`springc.check.points.check_points`) at `node` (default:
    the `.ac` directive's) to input `channel`, on `family_sweep`'s grid; an error at one
    point names it."""
    node, channel = ac.target(points.checked[0].net, node, channel)
    f_hz = family_sweep(points, fmin, fmax, count).frequencies()
    h = np.empty((len(points), len(f_hz)), complex)
    for i, (point, checked) in enumerate(zip(points.points, points.checked)):
        try:
            h[i] = ac.response(checked, node, f_hz, channel, progress=progress).h
        except UsageError as err:
            raise UsageError(f"{err.message} at {point.describe(len(points))}", err.loc,
                             err.diagnostic.hint) from None
    return AcFamily(node, channel, f_hz, h, points.points)


def point_columns(points: tuple[Point, ...]) -> dict[str, list]:
    """The points table as columns: `point`, one per stepped parameter and, with `.mc`,
    `sample` and `seed`."""
    cols: dict[str, list] = {"point": [p.index for p in points]}
    for name, _ in points[0].steps:
        cols[name] = [dict(p.steps)[name] for p in points]
    if points[0].sample is not None:
        cols["sample"] = [p.sample for p in points]
        cols["seed"] = [p.seed for p in points]
    return cols


def write_ac_csv(family: AcFamily, path: str | Path) -> None:
    """Long format, written atomically: the points table's columns (`point`, the stepped
    parameters, `sample` and `seed` with `.mc`), then `f_hz,mag,phase_rad`, one row per
    point and frequency."""
    cols = point_columns(family.points)
    lines = [",".join([*cols, "f_hz", "mag", "phase_rad"])]
    mag, phase = family.mag, family.phase
    for i in range(len(family)):
        head = ",".join(_cell(v[i]) for v in cols.values())
        lines += [f"{head},{f!r},{m!r},{p!r}" for f, m, p in
                  zip(family.f_hz.tolist(), mag[i].tolist(), phase[i].tolist())]
    with atomic_path(path, ".csv") as tmp:
        tmp.write_text("\n".join(lines) + "\n")


def _cell(value) -> str:
    return repr(float(value)) if isinstance(value, float) else str(value)


LEGEND_MAX = 10  # more points than this: a colour scale instead of a legend


def plot_ac(family: AcFamily, path: str | Path) -> None:
    """PNG: every point's magnitude (log-log) over its phase, on one pair of axes
    (`AcFamily.plot`)."""
    family.plot(path)


def draw_ac(family: AcFamily, top, bottom=None) -> None:
    """Every point's magnitude on Axes `top` (log-log) and, where given, its phase (rad)
    on `bottom`; a legend naming the points up to `LEGEND_MAX` of them."""
    import matplotlib

    colours = matplotlib.colormaps["viridis"](np.linspace(0, 0.9, len(family)))
    for i, point in enumerate(family.points):
        label = point.describe() if len(family) <= LEGEND_MAX else None
        top.loglog(family.f_hz, family.mag[i], color=colours[i], lw=1, label=label)
        if bottom is not None:
            bottom.semilogx(family.f_hz, family.phase[i], color=colours[i], lw=1)
    top.set_ylabel("|H| (displacement / input)")
    top.set_title(f"x({family.node}) / in({family.channel}) at {len(family)} points")
    if len(family) <= LEGEND_MAX:
        top.legend(fontsize="x-small")
    if bottom is not None:
        bottom.set(ylabel="phase (rad)")
    for ax in (top, bottom):
        if ax is not None:
            ax.grid(True, which="both", alpha=0.3)
    (top if bottom is None else bottom).set_xlabel("frequency (Hz)")


def modes_family(points: PointSet, count: int | None = None) -> dict:
    """`springc modes --json` at every checked point: `{"file", "points": [{"point": {index,
    steps, sample, seed}, ...mode_report}]}`."""
    rows = []
    for point, checked in zip(points.points, points.checked):
        report = mode_report(checked, count)
        rows.append({"point": point.to_json(), **report})
    return {"file": points.checked[0].net.file, "points": rows}


def modes_family_text(report: dict) -> str:
    """Each point's mode table under a line naming the point."""
    count = len(report["points"])
    blocks = []
    for row in report["points"]:
        p = row["point"]
        point = Point(p["index"], tuple(p["steps"].items()), p["sample"], p["seed"])
        blocks.append(f"== {point.describe(count)}\n{mode_text(row)}")
    return "\n".join(blocks)


def plot_modes(report: dict, path: str | Path) -> None:
    """PNG: each mode's frequency against the point (the stepped parameter's value where
    one parameter is stepped and there are no samples, else the point index)."""
    plt = _pyplot()
    rows = report["points"] if "points" in report else [{"point": None, **report}]
    x, xlabel = _axis(rows)
    fig, ax = plt.subplots(figsize=(7, 4))
    width = max(len(r["modes"]) for r in rows)
    for k in range(width):
        fx = [(xi, r["modes"][k]["freq_hz"]) for xi, r in zip(x, rows) if k < len(r["modes"])
              and r["modes"][k]["freq_hz"] > 0]
        if fx:
            ax.plot(*zip(*fx), "o-", ms=3, lw=0.8)
    ax.set(xlabel=xlabel, ylabel="mode frequency (Hz)", yscale="log",
           title=f"modes of {Path(report['file']).name} at {len(rows)} point(s)")
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    _save(fig, path)


def _axis(rows: list[dict]) -> tuple[list[float], str]:
    points = [r["point"] for r in rows]
    if points[0] is not None and len(points[0]["steps"]) == 1 and points[0]["sample"] is None:
        name = next(iter(points[0]["steps"]))
        return [p["steps"][name] for p in points], name
    return list(range(len(rows))), "point"


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: str | Path) -> None:
    import matplotlib.pyplot as plt

    with atomic_path(path, ".png") as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    plt.close(fig)

