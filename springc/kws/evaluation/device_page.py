"""docs/results-device.md from `scripts/results_device.py run`'s results: the two designs'
accuracy against fabrication spread and against device mass (plot and tables), the budget at
physical scale against the bound, and the buffered design at eps = 1."""

from __future__ import annotations

from pathlib import Path

from springc.kws.evaluation.studies import falls_below

COMMAND = ("python scripts/results_device.py run --data CORPUS --out DIR; "
           "python scripts/results_device.py page --out DIR")


def spread_rows(results: dict) -> list[str]:
    """Markdown rows: size, design, spread, nominal, mean +- standard error, worst."""
    rows = ["| size | heads | spread | nominal design % | mean device % | worst % |",
            "|---|---|---|---|---|---|"]
    for key, r in results.items():
        for p in r.get("spread", []):
            rows.append(f"| {_size(key)} | {_design(key)} | {p['spread']:g} | "
                        f"{100 * p['nominal']:.1f} | {100 * p['mean']:.1f} +- "
                        f"{100 * p['stderr']:.1f} | {100 * p['worst']:.1f} |")
    return rows


def noise_rows(results: dict) -> list[str]:
    """Markdown rows: size, design, device mass, accuracy with noise, noiseless, error."""
    rows = ["| size | heads | device mass (kg) | accuracy with noise % | noiseless % | "
            "decision error |", "|---|---|---|---|---|---|"]
    for key, r in results.items():
        for p in r.get("noise", []):
            rows.append(f"| {_size(key)} | {_design(key)} | {p['device_mass']:.0e} | "
                        f"{100 * p['accuracy']:.1f} | {100 * p['noiseless']:.1f} | "
                        f"{p['decision_error']:.3g} |")
    return rows


def budget_rows(results: dict) -> list[str]:
    """Markdown rows: per model and stage, k_B T and dB of the sound (median clip)."""
    rows = ["| size | heads | stage | k_B T | of the sound (dB) |", "|---|---|---|---|---|"]
    for key, r in results.items():
        for stage, e in r.get("budget", {}).get("stages", {}).items():
            rows.append(f"| {_size(key)} | {_design(key)} | {stage} | {e['kt']:.3g} | "
                        f"{e['db_of_sound']:.1f} |")
    return rows


def summary_rows(results: dict) -> list[str]:
    """Markdown rows: per model the test accuracy of the whole network and of its ideal
    readout, the test clips, the insertion loss, the training's seconds and the minutes of
    training and every study together."""
    rows = ["| model | network % | ideal readout % | test clips | insertion loss (dB) | "
            "train s | all its studies min |", "|---|---|---|---|---|---|---|"]
    for key, r in results.items():
        ideal = f"{100 * r['ideal']:.1f}" if "ideal" in r else "-"
        train = f"{r['train_s']:.0f}" if "train_s" in r else "-"
        studies = f"{r['seconds'] / 60:.1f}" if "seconds" in r else "-"
        rows.append(f"| {key} | {100 * r['accuracy']:.1f} | {ideal} | {r['n']} | "
                    f"{r['loss_db']:.1f} | {train} | {studies} |")
    return rows


LOSS = 0.02  # the accuracy a threshold gives up: 2 points


def threshold_rows(results: dict) -> list[str]:
    """Markdown rows: per model the spread at which the mean device falls LOSS below the
    nominal design, and the device mass at which thermal noise costs LOSS ('-': not within
    the sweep; 'below' where the first point is already past it)."""
    rows = [f"| model | spread ({100 * LOSS:g} points lost) | device mass, kg "
            f"({100 * LOSS:g} points lost) |", "|---|---|---|"]
    for key, r in results.items():
        spread, noise = r.get("spread", []), r.get("noise", [])
        if not spread and not noise:
            continue
        by_spread = _threshold([p["spread"] for p in spread], [p["mean"] for p in spread],
                               spread[0]["nominal"] if spread else 0.0)
        by_mass = _threshold([p["device_mass"] for p in noise],
                             [p["accuracy"] for p in noise],
                             noise[0]["noiseless"] if noise else 0.0)
        rows.append(f"| {key} | {by_spread} | {by_mass} |")
    return rows


def _threshold(xs: list[float], ys: list[float], reference: float) -> str:
    if not xs:
        return "-"
    if ys[0] <= reference - LOSS:
        return f"below {xs[0]:.0e}"
    found = falls_below(xs, ys, reference - LOSS)
    return "-" if found is None else f"{found:.2g}"


def unheard_rows(unheard: dict) -> list[str]:
    """Markdown rows: the 8x3 network per eps, trained without one engine, on its own test
    split and on that engine's voices."""
    engine = unheard["engine"]
    rows = [f"| 8x3 mass-spring, trained without {engine} | own test % (clips) | "
            f"{engine} alone % (clips) | insertion loss (dB) |", "|---|---|---|---|"]
    for key, r in unheard.items():
        if key != "engine":
            rows.append(f"| {key} | {100 * r['own']:.1f} ({r['own_n']}) | "
                        f"{100 * r['unheard']:.1f} ({r['unheard_n']}) | {r['loss_db']:.1f} |")
    return rows


def _size(key: str) -> str:
    return key.split()[0]


def _design(key: str) -> str:
    return key.split()[1]


def plot(results: dict, path: Path) -> None:
    """Accuracy against spread, against device mass and against insertion loss (with the
    budget's bound), a line or point per model."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right, loss) = plt.subplots(1, 3, figsize=(15, 4))
    for key, r in results.items():
        if r.get("spread"):
            left.errorbar([p["spread"] for p in r["spread"]],
                          [100 * p["mean"] for p in r["spread"]],
                          [100 * p["stderr"] for p in r["spread"]], marker="o", label=key)
        if r.get("noise"):
            right.plot([p["device_mass"] for p in r["noise"]],
                       [100 * p["accuracy"] for p in r["noise"]], marker="o", label=key)
        loss.plot(r["loss_db"], 100 * r["accuracy"], marker="o", ls="", label=key)
    bounds = {r["budget"]["bound_db"] for r in results.values() if r.get("budget")}
    for bound in bounds:  # what a decision may lose at the budget's sound and area
        loss.axvline(bound, color="black", lw=0.8)
        loss.text(bound, 15, f" bound {bound:.1f} dB", fontsize="small")
    loss.set_xlim(0, None)
    loss.set_xlabel("insertion loss (dB, median clip)")
    for ax, label in ((left, "relative spread of every coefficient"),
                      (right, "device mass (kg), 300 K, 60 dB SPL, 1 mm^2")):
        ax.set_xscale("log")
        ax.set_xlabel(label)
    for ax in (left, right, loss):
        ax.set_ylabel("test accuracy (%)")
        ax.axhline(100 / 12, color="grey", lw=0.8, ls=":")
        ax.legend(fontsize="small")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


READING = "## Reading the results"
TABLES = "## Accuracy of the whole network"


def reading(md: Path, tables: str = TABLES) -> str:
    """The page's own reading of its results (written by a person, kept when the tables are
    regenerated): the text from READING up to the first table's heading `tables`, or ''."""
    if not md.exists():
        return ""
    text = md.read_text()
    start = text.find(READING)
    end = text.find(tables, start)
    return text[start:end].rstrip() + "\n" if start >= 0 and end > start else ""


def cv_rows(cv: dict, designs: tuple[str, ...] | None = None) -> list[str]:
    """The speaker-fold table (`results_device.py cv`'s "fold{k} {design}" rows): per design
    (by default every one measured, zero-mode first) each fold's accuracy and test clips, the
    clip-weighted mean with the standard error of the folds' mean, the paired change against
    the first design over the same clips, and the summing devices at their spread (mean of
    the folds' device means, beside their nominal on the same clips), in %."""
    folds = sorted({key.split()[0] for key in cv})
    if designs is None:  # as measured, zero-mode (the paper's) first
        designs = tuple(sorted({key.split(" ", 1)[1] for key in cv},
                               key=lambda d: (d != "zero-mode", d)))
    head = ["| design | " + " | ".join(f"{f} % (clips)" for f in folds)
            + " | mean % | change vs " + designs[0] + " | devices at 1e-3 % (nominal %) |",
            "|---" * (len(folds) + 4) + "|"]
    base = [cv[f"{f} {designs[0]}"] for f in folds]
    out = []
    for design in designs:
        rows = [cv.get(f"{f} {design}") for f in folds]
        if None in rows:
            continue
        acc = [100 * r["accuracy"] for r in rows]
        mean, se = _fold_mean(acc, [r["n"] for r in rows])
        change, change_se = _fold_mean([a - 100 * b["accuracy"] for a, b in zip(acc, base)],
                                       [r["n"] for r in rows])
        spread = [r["spread"] for r in rows if "spread" in r]
        devices = (f"{_mean([100 * x['mean'] for x in spread]):.1f} "
                   f"({_mean([100 * x['nominal'] for x in spread]):.1f})" if spread else "-")
        out.append(f"| {design} | " + " | ".join(f"{a:.1f} ({r['n']})" for a, r in
                                                 zip(acc, rows))
                   + f" | {mean:.1f} +- {se:.1f} | {change:+.1f} +- {change_se:.1f} | "
                   f"{devices} |")
    return head + out


def _mean(values: list[float]) -> float:
    return sum(values) / len(values)


def _fold_mean(values: list[float], weights: list[int]) -> tuple[float, float]:
    """The weighted mean of per-fold values and the standard error of their plain mean."""
    k = len(values)
    spread = sum((v - _mean(values)) ** 2 for v in values) / (k - 1) if k > 1 else 0.0
    return sum(v * w for v, w in zip(values, weights)) / sum(weights), (spread / k) ** 0.5


def write_page(results: dict, md: Path, intro: str | None = None,
               cv: dict | None = None) -> Path:
    """The page (tables in the order of `results`) and its plot beside it; `intro` (by
    default the page's present reading section) goes between the plot and the tables;
    `cv`, the speaker folds (`cv_rows`), after the first table."""
    intro = reading(md) if intro is None else intro
    unheard = results.get("unheard")
    results = {k: v for k, v in results.items() if k != "unheard"}
    png = md.with_suffix(".png")
    plot(results, png)
    lines = ["# The keyword spotter as a device", "", f"![accuracy]({png.name})", "", intro,
             TABLES, "", *summary_rows(results), "",
             *(["## Cross-validated over speakers", "", *cv_rows(cv), ""] if cv else []),
             "## Against fabrication spread", "", *spread_rows(results), "",
             "## Against device mass, with thermal noise", "", *noise_rows(results), "",
             "## Where the energy goes, at 2e-9 kg, 60 dB SPL, 1 mm^2, 300 K", "",
             *budget_rows(results), "",
             f"## Thresholds: where {100 * LOSS:g} points are lost", "",
             *threshold_rows(results), "",
             *(["## eps 1 against 1e-6 on voices no model heard", "",
                *unheard_rows(unheard), ""] if unheard else []),
             f"Regenerated by `{COMMAND}`."]
    md.write_text("\n".join(lines) + "\n")
    return md
