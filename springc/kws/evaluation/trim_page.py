"""docs/results-trim.md: the device design's fabricated devices trimmed after fabrication
(`springc eval MODEL --mc N --spread S --trim K`), untrimmed beside trimmed, per size and
spread, and what a spread on one stage alone costs (`--stage`), from the rows stored in
docs/results-trim.json (`row` of each `eval --json` report), with a plot beside the page."""

from __future__ import annotations

from pathlib import Path

from springc.kws.evaluation.device_page import reading

COMMAND = "python scripts/results_device.py trim-page"
TABLES = "## Untrimmed and trimmed"
STAGES = ("filters", "compressors", "delays", "couplings", "readouts")  # device.STAGES


def row(size: str, report: dict) -> dict:
    """The stored row of one `eval --mc N --spread S [--stage X] [--trim K] --json` report of
    a model of `size` ("8x3"): the nominal design's and the devices' accuracy, and where
    trimmed the trimmed ones."""
    devices = report["devices"]
    out = {"size": size, "spread": report["spread"], "kind": report["kind"],
           "stage": report["stage"], "n": report["n"], "devices": len(devices),
           "diverged": sum(d["diverged"] for d in devices), "nominal": report["nominal"],
           "untrimmed": report["accuracy"]}
    if "trimmed" in report:
        out.update(trim_clips=report["trim_clips"], nominal_trimmed=report["nominal_trimmed"],
                   trimmed=report["trimmed"],
                   gain=[d["trimmed"] - d["accuracy"] for d in devices])
    return out


def stage_rows(rows: list[dict]) -> list[str]:
    """Per size and spread measured one stage at a time, each stage's mean device and the
    points it loses against the nominal design, beside every stage at once."""
    alone = [r for r in rows if r["stage"] != "all"]
    out = ["| size | spread | stage spread | mean device % | worst device % | points lost |",
           "|---|---|---|---|---|---|"]
    for size, spread in sorted({(r["size"], r["spread"]) for r in alone}):
        mine = [r for r in rows if (r["size"], r["spread"]) == (size, spread)]
        order = {name: k for k, name in enumerate(STAGES + ("all",))}
        for r in sorted(mine, key=lambda r: order[r["stage"]]):
            u = r["untrimmed"]
            out.append(f"| {size} | {spread:g} | {r['stage']} | {100 * u['mean']:.1f} +- "
                       f"{100 * u['stderr']:.1f} | {100 * u['worst']:.1f} | "
                       f"{100 * (r['nominal'] - u['mean']):.1f} |")
    return out


def table_rows(rows: list[dict]) -> list[str]:
    """One line per size and spread, in that order: percentages, mean +- standard error over
    the devices and the worst, and the mean gain of trimming with its standard error."""
    out = ["| size | spread | devices | nominal % | trimmed nominal % | mean device % "
           "| trimmed % | worst device % | worst trimmed % | gain (points) |",
           "|---|---|---|---|---|---|---|---|---|---|"]
    for r in sorted(_trimmed(rows), key=lambda r: (r["size"], r["spread"])):
        u, t = r["untrimmed"], r["trimmed"]
        mean, err = _mean_err([100 * g for g in r["gain"]])
        out.append(f"| {r['size']} | {r['spread']:g} | {r['devices']} | "
                   f"{100 * r['nominal']:.1f} | {100 * r['nominal_trimmed']:.1f} | "
                   f"{100 * u['mean']:.1f} +- {100 * u['stderr']:.1f} | "
                   f"{100 * t['mean']:.1f} +- {100 * t['stderr']:.1f} | "
                   f"{100 * u['worst']:.1f} | {100 * t['worst']:.1f} | "
                   f"{mean:+.1f} +- {err:.1f} |")
    return out


def _trimmed(rows: list[dict]) -> list[dict]:
    return [r for r in rows if "trimmed" in r]


def _mean_err(values: list[float]) -> tuple[float, float]:
    """Mean and its standard error (0 for a single value)."""
    n = len(values)
    mean = sum(values) / n
    var = sum((v - mean) ** 2 for v in values) / (n - 1) if n > 1 else 0.0
    return mean, (var / n) ** 0.5


def plot(rows: list[dict], path: Path) -> None:
    """Mean device accuracy against spread per size, untrimmed (solid) and trimmed (dashed),
    with standard errors, the nominal design and chance as lines."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    rows = _trimmed(rows)
    for size in sorted({r["size"] for r in rows}):
        mine = sorted((r for r in rows if r["size"] == size), key=lambda r: r["spread"])
        xs, color = [r["spread"] for r in mine], None
        for key, style in (("untrimmed", "-"), ("trimmed", "--")):
            line = ax.errorbar(xs, [100 * r[key]["mean"] for r in mine],
                               [100 * r[key]["stderr"] for r in mine], marker="o", ls=style,
                               color=color, label=f"{size} {key}")
            color = line[0].get_color()  # one colour a size
        ax.axhline(100 * mine[0]["nominal"], color=color, lw=0.8, ls=":")
    ax.axhline(100 / 12, color="grey", lw=0.8, ls=":")
    ax.set_xscale("log")
    ax.set_xlabel("local spread of every coefficient (relative)")
    ax.set_ylabel("test accuracy (%), mean device")
    ax.legend(fontsize="small")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_page(rows: list[dict], md: Path, intro: str | None = None) -> Path:
    """The page and its plot beside it; `intro` (by default the page's present reading
    section) goes between the plot and the table."""
    intro = reading(md, TABLES) if intro is None else intro
    png = md.with_suffix(".png")
    plot(rows, png)
    by_stage = any(r["stage"] != "all" for r in rows)
    lines = ["# Trimming fabricated devices", "", f"![accuracy]({png.name})", "", intro,
             TABLES, "", *table_rows(rows), "",
             *(["## One stage at a time", "", *stage_rows(rows), ""] if by_stage else []),
             f"Regenerated by `{COMMAND}`."]
    md.write_text("\n".join(lines) + "\n")
    return md
