"""docs/results-stiffness.md from `scripts/results_device.py stiffness`'s rows: the device
design's accuracy and each later stage's energy against the stage stiffness, the squarer
range, the heads' eps and the compression threshold (plot and tables), and the noise and
population studies of the models measured with them."""

from __future__ import annotations

import math
from pathlib import Path

from springc.kws.evaluation.device_page import cv_rows, reading

COMMAND = ("python scripts/results_device.py stiffness --data CORPUS --out DIR [options]; "
           "python scripts/results_device.py stiffness-page")
TABLES = "## Against the stage stiffness"


STIFFNESS_STAGES = ("low-pass masses", "compressors", "terminals", "mvm heads", "readouts")


def stiffness_rows(st: dict) -> list[str]:
    """The stage-stiffness table (`results_device.py stiffness`'s rows): per size, factor,
    squarer range, heads' eps and compression threshold, the whole network's accuracy and
    each later stage's energy in dB of the sound, with the readouts' k_B T."""
    head = ["| size | stage stiffness | squarer range R (m) | heads' eps | threshold A_c (m) "
            "| network % (clips) | "
            + " | ".join(f"{stage} dB" for stage in STIFFNESS_STAGES) + " | readouts k_B T |",
            "|---" * (len(STIFFNESS_STAGES) + 7) + "|"]
    rows = []
    for r in st.values():
        stages = r["budget"]["stages"]
        rows.append(f"| {r['size']} | {r['factor']:g} | {r['squarer_range']:g} | "
                    f"{r['epsilon']:g} | {r['threshold']:g} | "
                    f"{100 * r['accuracy']:.1f} ({r['n']}) | "
                    + " | ".join(f"{stages[name]['db_of_sound']:.1f}"
                                 for name in STIFFNESS_STAGES)
                    + f" | {stages['readouts']['kt']:.2g} |")
    return head + rows


def stiffness_study_rows(st: dict) -> list[str]:
    """The stiffness study's models that were also measured with thermal noise (300 K, 60
    dB SPL, 1 mm^2) and as fabricated populations: per model and device mass the accuracy
    beside its noiseless one and the decision error (`device.decision_error`: the median
    change of a decision value over the median decision value), per spread the mean device
    beside the nominal design."""
    rows = ["| design | study | accuracy % | without it % | decision error |",
            "|---|---|---|---|---|"]
    for r in st.values():
        name = (f"{r['size']}, S {r['factor']:g}, R {r['squarer_range']:g}, "
                f"eps {r['epsilon']:g}")
        rows += [f"| {name} | noise at {p['device_mass']:g} kg | {100 * p['accuracy']:.1f} | "
                 f"{100 * p['noiseless']:.1f} | {p.get('decision_error', math.nan):.3g} |"
                 for p in r.get("noise", [])]
        rows += [f"| {name} | spread {p['spread']:g}, mean device | "
                 f"{100 * p['mean']:.1f} +- {100 * p['stderr']:.1f} | "
                 f"{100 * p['nominal']:.1f} | - |" for p in r.get("spread", [])]
    return rows if len(rows) > 2 else []


def _order(r: dict) -> tuple:
    """Rows by size, then squarer range (largest first), heads' eps, threshold, stiffness."""
    return r["size"], -r["squarer_range"], r["epsilon"], r["threshold"], r["factor"]


def _line(r: dict) -> tuple:
    """What a line of the stiffness plot holds fixed."""
    return r["size"], r["squarer_range"], r["epsilon"], r["threshold"]


def plot_stiffness(st: dict, path: Path) -> None:
    """Per size, squarer range, heads' eps and threshold against the stage stiffness: the
    readouts' energy (dB of the sound, with the bound a decision may lose) and the whole
    network's accuracy."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (energy, acc) = plt.subplots(1, 2, figsize=(11, 4))
    for key in dict.fromkeys(_line(r) for r in st.values()):
        rows = [r for r in st.values() if _line(r) == key]
        factors = [r["factor"] for r in rows]
        name = f"{key[0]} R {key[1]:g} eps {key[2]:g} A_c {key[3]:g}"
        energy.plot(factors, [r["budget"]["stages"]["readouts"]["db_of_sound"] for r in rows],
                    marker="o", label=f"{name}: readouts")
        acc.plot(factors, [100 * r["accuracy"] for r in rows], marker="o", label=name)
    bound = next(iter(st.values()))["budget"]["bound_db"]
    energy.axhline(-bound, color="black", lw=0.8)
    energy.text(1, -bound, f" -{bound:.1f} dB: what a decision may lose", fontsize="small",
                va="bottom")
    energy.set_ylabel("energy (dB of the sound, median clip)")
    acc.set_ylabel("test accuracy (%)")
    acc.axhline(100 / 12, color="grey", lw=0.8, ls=":")
    for ax in (energy, acc):
        ax.set_xscale("log")
        ax.set_xlabel("stage stiffness (springc train --stage-stiffness)")
        ax.legend(fontsize="x-small")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_page(st: dict, md: Path, intro: str | None = None, cv: dict | None = None) -> Path:
    """The page and its plot beside it; `intro` (by default the page's present reading
    section) goes between the plot and the tables; `cv`, the designs cross-validated over
    speakers (`device_page.cv_rows`), after the first table."""
    intro = reading(md, TABLES) if intro is None else intro
    st = dict(sorted(st.items(), key=lambda item: _order(item[1])))
    png = md.with_suffix(".png")
    plot_stiffness(st, png)
    studies = stiffness_study_rows(st)
    lines = ["# The device design against its stage stiffness", "",
             f"![stage stiffness]({png.name})", "", intro,
             f"{TABLES}, at 2e-9 kg, 60 dB SPL, 1 mm^2, 300 K", "", *stiffness_rows(st), "",
             *(["## Cross-validated over speakers", "", *cv_rows(cv), ""] if cv else []),
             *(["## Against thermal noise and fabrication spread", "", *studies, ""]
               if studies else []),
             f"Regenerated by `{COMMAND}`."]
    md.write_text("\n".join(lines) + "\n")
    return md
