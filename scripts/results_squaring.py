"""docs/results-squaring.md: the paper's Fig. 6c-d squaring unit (`springc.design.squaring`)
and, from `scripts/results_stages.py`'s JSON, where the 8x3 network departs from it.

    python scripts/results_stages.py --data CORPUS --out DIR      (the network, minutes)
    python scripts/results_squaring.py [--stages DIR/stages.json] [--docs docs]

Writes DOCS/results-squaring.png (the figure `springc figures OUT --only squaring` draws) and
DOCS/results-squaring.md: the figure, the table of the unit at the paper's pulse (5 line sites)
and at a 5x longer pulse, the per-stage table; the page's text from "## How it was measured"
on is kept as it is.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import time
from pathlib import Path

import numpy as np

from springc.design import figures
from springc.design import squaring as sq

PAPER = {1e-4: "shown (brown)", 10**-1.5: "high distortion (gray)", 1e4: "shown (pink)"}
LONG = 25  # the longer pulse, in line sites: nearer the features' envelopes
PROSE = "## How it was measured"  # the page's hand-written part from here on is kept


def unit_table(short: sq.Sweep, long: sq.Sweep) -> str:
    """eps rows: energy transfer, distortion and gain at both pulse widths, the paper's word."""
    head = ("| eps | log10 transfer | distortion | gain | log10 transfer, long pulse | "
            "distortion, long pulse | paper (Fig. 6d) |")
    lines = [head, "|---" * 7 + "|"]
    for k, eps in enumerate(short.epsilon):
        paper = next((v for e, v in PAPER.items() if abs(np.log10(eps / e)) < 1e-6), "")
        lines.append(f"| {eps:.3g} | {np.log10(short.transfer[k]):.2f} | "
                     f"{short.distortion[k]:.3g} | {short.gain[k]:.3g} | "
                     f"{np.log10(long.transfer[k]):.2f} | {long.distortion[k]:.3g} | {paper} |")
    return "\n".join(lines)


def stages_section(path: Path) -> str:
    """The per-stage table of `results_stages.py` (its markdown beside the JSON)."""
    data = json.loads(path.read_text())
    table = (path.parent / "stages.md").read_text().strip()
    return (f"## The 8x3 network, stage by stage\n\n{table}\n\n"
            f"Feature amplitude A = {data['amplitude']:.4g} m, {data['clips']} test clips, "
            f"heads: {data['model'] or 'stand-in (random weights, built as trained ones)'}.\n")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--stages", type=Path)
    ap.add_argument("--docs", type=Path, default=Path("docs"))
    args = ap.parse_args()
    start = time.time()
    short = sq.sweep()
    long = sq.sweep(dataclasses.replace(sq.Unit(), sigma=LONG * sq.TS))
    figures.plot_squaring(short, args.docs / "results-squaring.png")
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                            text=True).stdout.strip()
    parts = ["# Results: the squaring unit (paper Fig. 6c-d)", "",
             "![Fig. 6c-d](results-squaring.png)", "",
             "(The plot is written beside this page by the commands below; not committed.)",
             "", unit_table(short, long), ""]
    if args.stages:
        parts.append(stages_section(args.stages))
    parts.append(f"<!-- tables generated at {commit} in {time.time() - start:.0f} s -->")
    page = args.docs / "results-squaring.md"
    kept = page.read_text().partition(PROSE)[2] if page.exists() else "\n"
    page.write_text("\n".join(parts) + "\n\n" + PROSE + kept)
    print(unit_table(short, long))


if __name__ == "__main__":
    main()
