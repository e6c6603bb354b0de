"""Regenerate docs/results-cv.md and docs/results-cv.png: digital against mass-spring by
size, cross-validated over speakers on every clip of the built-in corpus (`springc cv`).

    springc data synth /tmp/corpus14 --clips 1600 --seed 1 \\
        --words yes,no,up,down,left,right,on,off,stop,go,one,two,three,four
    python scripts/results_cv.py --data /tmp/corpus14

Each row equals `springc cv --data DIR --bins n --delays m` (features cached, so a second
run only refits the SVMs). The mass-spring column is the SVM on the simulated network's own
Phi (the "ideal c.Phi" of docs/results-massspring.md); the whole classifier network realises
it within its readout error (0.4-1.1%, measured there on the test split).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from springc.kws.evaluation import crossval
from springc.kws.features.digital import FeatureSettings

SIZES = ((4, 2), (6, 3), (8, 3))
# Measured with this script on the same corpus and folds before the compressor (mass-spring
# network version 4, git 8aac568), for the record of why the network changed.
HISTORY = ("Before: with the paper's compression through the squarer's cubic stiffness on the "
           "resonant filter (network version 4), the same folds gave gaps of +6.0 +- 1.3, "
           "+5.8 +- 1.4 and +6.2 +- 2.3 points at 4x2, 6x3 and 8x3 (mass-spring 42.2, 59.8 "
           "and 62.9%); compressing the low-passed envelope instead (`compressor.spr`, "
           "`springc/kws/features/massspring.py`) moved the mass-spring features to the digital "
           "ones or above. On the corpus synthesised before the synthesis channel change "
           "(867444d), with liblinear's SVM and the features at RK4 x8 (git 77b6450, 13.3 min), "
           "the gaps were -2.1 +- 0.8, -1.0 +- 1.3 and -2.2 +- 1.4 points (digital 48.2, 65.6 and "
           "69.1%, mass-spring 50.2, 66.6 and 71.2%). Before the stiffness prediction "
           "(c2c5bcb, the same corpus command, the 2-core machine of that day, 6.5 min), the "
           "gaps were -3.5 +- 0.9, -2.9 +- 1.1 and -1.8 +- 0.9 points (digital 46.3, 60.0 and "
           "62.5%, mass-spring 49.8, 62.9 and 64.3%): the mass-spring column is within 0.2 "
           "points of it; the digital column, whose code did not change, moved by +0.3 to "
           "+1.0 (the corpus synthesised again, on another machine; C differs in one fold "
           "at 6x3 and at 8x3).")


def run(data: Path, sizes, folds: int, jobs: int) -> list[dict]:
    """One cross-validation report per size, with its wall time."""
    reports = []
    for n, m in sizes:
        start = time.perf_counter()
        opts = crossval.CVOptions(data=data, settings=FeatureSettings(bins=n, delays=m),
                                  folds=folds, jobs=jobs)
        report = crossval.cross_validate(opts, progress=lambda s, n=n, m=m: print(
            f"{n}x{m}: {s}", flush=True))
        report["seconds"] = time.perf_counter() - start
        print("\n".join(crossval.summary_lines(report)), flush=True)
        reports.append(report)
    return reports


def page(reports: list[dict], data: Path, minutes: float, plot_name: str) -> str:
    """The Markdown page: the plot, the tables, then how it was measured."""
    lines = [
        "# Digital against mass-spring, cross-validated on every clip",
        "",
        f"Plot: `{plot_name}` beside this page after a run (not committed).",
        "",
        *_size_table(reports),
        "",
        "## Per class (true-positive rate, %)",
        "",
        *_class_table(reports),
        "",
        "## How it was measured",
        "",
        *_how_measured(reports[0], data, minutes),
        "",
        HISTORY,
    ]
    return "\n".join(lines) + "\n"


def _size_table(reports: list[dict]) -> list[str]:
    """Each size's accuracies, their paired gap and its interval, the clips decided apart,
    the C per fold and the time."""
    lines = [
        ("| size | digital | mass-spring (SVM on the network's Phi) | gap digital - mass-spring "
        "| 95% interval | clips decided differently | C per fold (digital / mass-spring) "
        "| time |"),
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in reports:
        d, s = r["realisations"]["digital"], r["realisations"]["mass-spring"]
        g = s["gap"]
        lines.append(
            f"| {r['bins']}x{r['delays']} | {100 * d['balanced_accuracy']:.1f} +- "
            f"{100 * d['se']:.1f}% | {100 * s['balanced_accuracy']:.1f} +- "
            f"{100 * s['se']:.1f}% | **{g['points']:+.1f} +- {g['se']:.1f}** | "
            f"{g['ci95'][0]:+.1f} .. {g['ci95'][1]:+.1f} | {100 * g['disagree']:.0f}% | "
            f"{_cs(d['c_per_fold'])} / {_cs(s['c_per_fold'])} | {r['seconds'] / 60:.1f} min |")
    return lines


def _class_table(reports: list[dict]) -> list[str]:
    """Each size's and realisation's true-positive rate per class."""
    classes = list(reports[-1]["realisations"]["digital"]["per_class"])
    lines = ["| size | realisation | " + " | ".join(classes) + " |",
             "|---|---|" + "---|" * len(classes)]
    for r in reports:
        for name, v in r["realisations"].items():
            lines.append(f"| {r['bins']}x{r['delays']} | {name} | "
                         + " | ".join(f"{100 * v['per_class'][c]:.0f}" for c in classes) + " |")
    return lines


def _how_measured(r0: dict, data: Path, minutes: float) -> list[str]:
    """The command, the data and folds (from the first report), and why this page exists."""
    return [
        (f"Regenerate with `python scripts/results_cv.py --data DIR` ({minutes:.1f} min on this "
        "2-core machine; corpus command in the script's docstring). Each row equals "
        "`springc cv --data DIR --bins n --delays m`."),
        "",
        (f"Data: `{data.name}`, {r0['clips']} clips (all split lists, `_silence_` windows "
        f"included, none augmented) by {r0['speakers']} speakers, {r0['folds']} "
        f"speaker-disjoint folds of {min(r0['fold_sizes'])}-{max(r0['fold_sizes'])} clips. "
        "Every clip is classified once by an SVM trained on the other speakers' folds (C "
        "chosen on the next fold, speaker-disjoint too). Accuracy: class-balanced (mean "
        "true-positive rate over the 12 classes, as on the paper's balanced test set; chance "
        f"{100 * r0['majority']:.1f}%). Errors: bootstrap over speakers (2000 draws); the gap "
        "is paired (both realisations see the same clips in the same folds)."),
        "",
        ("Why this page: the 136-clip balanced test split of docs/results-massspring.md gives "
        "each gap a standard error near 4 points, too coarse to judge the issue's 2-point "
        "target; every clip tested once brings it to about 1.3."),
    ]


def _cs(cs: list[float]) -> str:
    return ", ".join(f"{c:g}" for c in cs)


def plot(reports: list[dict], path: Path) -> None:
    """Grouped bars: class-balanced accuracy per size and realisation, +-1 SE."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sizes = [f"{r['bins']}x{r['delays']}" for r in reports]
    x = np.arange(len(sizes))
    fig, ax = plt.subplots(figsize=(6, 3.8))
    for k, name in enumerate(crossval.REALISATIONS):
        acc = [100 * r["realisations"][name]["balanced_accuracy"] for r in reports]
        se = [100 * r["realisations"][name]["se"] for r in reports]
        ax.bar(x + (k - 0.5) * 0.38, acc, 0.38, yerr=se, capsize=4, label=name)
    ax.axhline(100 * reports[0]["majority"], color="gray", ls=":", label="chance")
    ax.set_xticks(x, sizes)
    ax.set_xlabel("bins x delays")
    ax.set_ylabel("class-balanced accuracy (%)")
    ax.set_title(f"{reports[0]['folds']}-fold speaker CV, {reports[0]['clips']} clips")
    ax.legend(loc="upper left", fontsize="small")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--out", type=Path, default=Path("docs/results-cv.md"))
    ap.add_argument("--folds", type=int, default=5)
    ap.add_argument("--jobs", type=int, default=0)
    ap.add_argument("--json", type=Path, default=None, help="Also write the reports here.")
    args = ap.parse_args()
    start = time.perf_counter()
    reports = run(args.data, SIZES, args.folds, args.jobs)
    png = args.out.with_suffix(".png")
    plot(reports, png)
    args.out.write_text(page(reports, args.data, (time.perf_counter() - start) / 60, png.name))
    if args.json:
        args.json.write_text(json.dumps(reports, indent=1))
    print(f"wrote {args.out} and {png}")


if __name__ == "__main__":
    main()
