"""Regenerate docs/results-massspring.md: the mass-spring keyword spotter simulated end to end
next to the digital realisation of the same architecture, on the built-in corpus.

    springc data synth /tmp/corpus14 --clips 1600 --seed 1 --words WORDS
    python scripts/results_massspring.py --data /tmp/corpus14 --out docs/results-massspring.md

WORDS (`CORPUS_WORDS` below): the 10 commands and the digits one to four, which are the
`_unknown_` class of the 12-class task and the words of the digit pairs. Held-out splits follow
the paper's balanced protocol (`springc.kws.data.dataset.balanced`).

Every row equals `springc train --data DIR -n N -m M [--realisation mass-spring]
[--task digits-pairs]` and `springc eval MODEL`; the sweeps are `springc.kws.evaluation.sweep`.
Model folders go under --models, the sweep plot (PNG, not committed) beside --out.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

from springc.kws.evaluation import energy
from springc.kws.evaluation.evaluate import budget_signals
from springc.kws.features import massspring as msp
from springc.kws.features.digital import FeatureSettings
from springc.kws.evaluation.evaluate import evaluate
from springc.kws.evaluation.sweep import (compression_sweep, epsilon_sweep, plot_sweeps,
                                          settings_table)
from springc.kws.data.task import DIGITS
from springc.kws.training.train import TrainOptions, train

SIZES = ((4, 2), (6, 3), (8, 3))
SWEEP_SIZE = (4, 2)  # the paper sweeps at 4 x 3; 4 x 2 keeps the run within ~20 minutes here
EPSILONS = (1e-6, 1e-4, 1e-2)
THRESHOLDS = (1e-4, 1e-3, 1e-2)
CORPUS_WORDS = "yes,no,up,down,left,right,on,off,stop,go,one,two,three,four"
# Paper, GSCD 12 classes (Fig. 8a, text): digital 82.0 and mass-spring 80.7 at 8 x 3.
PAPER_SIZES = {(8, 3): ("82.0", "80.7")}
# Paper Fig. 8b states in its text only two-three: 99.7 (Dubcek et al. 2024: linear 59,
# simple nonlinear 81).
PAPER_PAIRS = {"two-three": "99.7 (Dubcek 2024: linear 59, nonlinear 81)"}


READING = [
    "## Reading the results",
    "",
    "- The physical classifier costs little: the simulated network and the ideal readout "
    "c.Phi of the same features agree to within about a clip at every size (readout error "
    "about 1% or less at the default eps = 1e-5).",
    "- The feature compression is where the mass-spring features used to lose. The paper "
    "compresses in the squarer itself, through the cubic stiffness it puts on the resonant "
    "filter mass; that detunes the filter with amplitude (a 500 Hz bin rings near 2.3 kHz at "
    "100x its threshold). In speaker cross-validation on every clip of this corpus "
    "(`springc cv`) that arrangement (network version 4) trailed digital by 6.0 +- 1.3, "
    "5.8 +- 1.4 and 6.2 +- 2.3 points at 4x2, 6x3 and 8x3. Digital proxies located it (4x2): "
    "the network's compression law without the detuning scored 49.9%, compressing the "
    "low-passed envelope, cbrt(LP(y^2)), 49.9-51.0%, digital 48.2%. The network now squares "
    "with a linear filter and compresses the envelope after the low-pass (`compressor.spr`, "
    "a Duffing-stiffened follower); see docs/results-cv.md for the cross-validated gaps.",
    "- The test split is small (one clip is 0.7 points, a standard error of about 4 points "
    "per accuracy), so the sizes' gaps on this page differ within the noise; "
    "docs/results-cv.md tests every clip once.",
    "- The squaring error eps of the heads trades readout error against insertion loss "
    "(about 10 dB per decade of eps, the trend of the paper's Fig. 6c); above 1e-4 the "
    "readouts no longer follow c.Phi and the accuracy falls.",
]

# The features section's heading and text, before its correlation table.
FEATURES = [
    "## Features: mass-spring against digital",
    "",
    "Correlation of the simulated compressed feature c_i(t) with the digital "
    "realisation's feature (`springc.kws.features.digital`: filter, |y|^(2/3), low-pass) of "
    "the same bin, 8 bins, 16 test clips (medians). Where they differ: the mechanical "
    "compression is cube-root only above the threshold A_c (pure squaring below) and acts on "
    "the low-passed envelope (the digital one before the low-pass), the compressor lags by "
    "about 1 ms, and the digital path filters band-limited in the frequency domain.",
    "",
]


def run_size(data: Path, models: Path, bins: int, delays: int, task: str, jobs: int) -> dict:
    """Digital and mass-spring models of one size; the mass-spring network simulated."""
    fs = FeatureSettings(bins=bins, delays=delays)
    tag = f"{task}-n{bins}-m{delays}"
    start = time.perf_counter()
    digital = train(TrainOptions(data=data, out=models / f"digital-{tag}", settings=fs,
                                 task=task, jobs=jobs))
    train(TrainOptions(data=data, out=models / f"mass-spring-{tag}", settings=fs,
                       realisation="mass-spring", task=task, jobs=jobs))
    network = evaluate(models / f"mass-spring-{tag}", jobs=jobs)
    print(f"{tag}: {time.perf_counter() - start:.0f} s", flush=True)
    return {"bins": bins, "delays": delays, "digital": digital, "network": network}


def pct(x: float) -> str:
    return f"{100 * x:.1f}"


def size_table(rows: list[dict]) -> list[str]:
    out = ["| n x m | digital | mass-spring features, ideal c.Phi | mass-spring network | "
           "gap (digital - network) | insertion loss (dB) | readout error | paper digital "
           "(mass-spring) |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        d, net = r["digital"]["accuracy"], r["network"]["accuracy"]
        paper = PAPER_SIZES.get((r["bins"], r["delays"]))
        out.append(f"| {r['bins']} x {r['delays']} | {pct(d)} | "
                   f"{pct(r['network']['digital_same_model']['accuracy'])} | {pct(net)} | "
                   f"{100 * (d - net):+.1f} | {r['network']['insertion_loss_db']['median']:.1f} "
                   f"| {100 * r['network']['readout_error']:.3f}% | "
                   f"{f'{paper[0]} ({paper[1]})' if paper else '-'} |")
    return out


def pairs_table(r: dict) -> list[str]:
    out = ["| pair | digital | mass-spring features, ideal c.Phi | mass-spring network | paper |",
           "|---|---|---|---|---|"]
    ideal = r["network"]["digital_same_model"]["pairs"]
    digital = {frozenset(k.split("-")): v for k, v in r["digital"]["pairs"].items()}
    for name, p in r["network"]["pairs"].items():
        words = sorted(name.split("-"), key=DIGITS.index)  # the model folder sorts by name
        out.append(f"| {'-'.join(words)} | {pct(digital[frozenset(words)]['accuracy'])} | "
                   f"{pct(ideal[name]['accuracy'])} | {pct(p['accuracy'])} (of {p['n']}) | "
                   f"{PAPER_PAIRS.get('-'.join(words), '-')} |")
    return out


def sweep_table(rows: list[dict], key: str, label: str) -> list[str]:
    out = [f"| {label} | accuracy | ideal c.Phi | insertion loss (dB) | readout error |",
           "|---|---|---|---|---|"]
    for r in rows:
        out.append(f"| {r[key]:g} | {pct(r['accuracy'])} | {pct(r['ideal_accuracy'])} | "
                   f"{r['insertion_loss_db']:.1f} | {100 * r['readout_error']:.3f}% |")
    return out


def correlation(data: Path, clips: int = 16) -> list[str]:
    """Mass-spring low-pass displacements against the digital features, 8 bins, on the first
    `clips` word clips of the test split: median correlation per bin."""
    import numpy as np

    from springc.kws.data.dataset import open_dataset

    test = [c for c in open_dataset(data).split("test") if c.label != "_silence_"][:clips]
    r = msp.feature_correlation(msp.load_signals(test, False, 0, []).astype(np.float64),
                                msp.MassSpringSettings(bins=8, delays=3))
    med = np.median(r, axis=0)
    return ["| bin | " + " | ".join(str(i) for i in range(len(med))) + " |",
            "|---|" + "---|" * len(med),
            "| median r | " + " | ".join(f"{v:.3f}" for v in med) + " |"]


def budget_section(models: Path, data: Path, clips: int = 8) -> list[str]:
    """Where the input work goes in the 4 x 2 classifier (`springc eval MODEL --budget 8`)."""
    tag = f"kws12-n{SWEEP_SIZE[0]}-m{SWEEP_SIZE[1]}"
    model = models / f"mass-spring-{tag}"
    parts = energy.model_budget(model, budget_signals(model, data, clips))
    return [f"## Where the input work goes ({SWEEP_SIZE[0]} x {SWEEP_SIZE[1]}, {clips} test "
            "clips)", "",
            f"`springc eval MODEL --budget {clips}` (energy balance closes to "
            f"{energy.check_balance(parts).max():.0e}):", "", *energy.budget_table(parts), "",
            "The Mel filters (unit masses, stiffness (2 pi f)^2, driven by forces alpha "
            "(w_a^2 + w_b^2) u(t), paper Sec. III.A) take the input work and dissipate nearly "
            "all of it. The first quadratic coupling passes a tiny share to the low-pass "
            "masses: passive squaring of the filter displacements (the energy out grows with "
            "the square of the energy in, paper Fig. 5, at every amplitude: the filters stay "
            "linear); the compressors then hold the envelope's cube root. The "
            "head squarers cost the rest, set by eps (sweep above). The insertion loss is the "
            "readouts' row.", ""]


def page(data: Path, sizes: list[dict], pairs: dict, eps: list[dict], comp: list[dict],
         seconds: float, plot: Path, corr: list[str], budget: list[str]) -> str:
    """The page: the plot, the accuracy tables, the features, the energy budget and the
    reading of it all, then how it was measured."""
    lines = [
        "# Mass-spring keyword spotter: results",
        "",
        f"Plot: `{plot.name}` beside this page after a run (not committed).",
        "",
        *_size_section(sizes),
        "## Digit pairs (paper Fig. 8b), 4 x 2",
        "",
        *pairs_table(pairs),
        "",
        *_sweep_section(eps, comp),
        *FEATURES,
        *corr,
        "",
        *budget,
        *READING,
        "",
        *_throughput(sizes, seconds),
        *_parameters(msp.MassSpringSettings()),
        *_how_measured(sizes[0]["network"]["n"]),
    ]
    return "\n".join(lines)


def _size_section(sizes: list[dict]) -> list[str]:
    """The 12-class accuracy table by size, what one clip is worth, and its columns."""
    return [
        "## GSCD 12-class task by size",
        "",
        *size_table(sizes),
        "",
        "Small corpus, small test split: one clip is "
        f"{100 / sizes[0]['network']['n']:.1f} points. The readout error is the median "
        "|network decision - c.Phi decision| over the median |c.Phi decision|.",
        "",
        "Columns: *digital* is the paper's architecture evaluated numerically "
        "(`springc.kws.features.digital`); *ideal c.Phi* is the same trained mass-spring model "
        "read out exactly from the simulated features (so its difference to the network is due "
        "to the physical classifier alone); *network* is the simulated mass-spring classifier.",
        "",
    ]


def _sweep_section(eps: list[dict], comp: list[dict]) -> list[str]:
    """The squaring-error and compression-threshold sweeps (paper Fig. 8e-f)."""
    return [
        "## Accuracy against insertion loss (paper Fig. 8e-f), "
        f"{SWEEP_SIZE[0]} x {SWEEP_SIZE[1]}",
        "",
        "Squaring error eps = A^2 gamma / (alpha kc) of the classifier heads (A: peak terminal "
        "displacement, kc: the delay line's stiffness scale):",
        "",
        *sweep_table(eps, "epsilon", "eps"),
        "",
        "Feature compression threshold A_c (m of filter displacement; the compressor's Duffing "
        "coefficient l_i = kq / e_i^2 with e_i the low-pass level of a tone of amplitude A_c, "
        "smaller compresses more), default eps:",
        "",
        *sweep_table(comp, "threshold", "A_c"),
        "",
    ]


def _throughput(sizes: list[dict], seconds: float) -> list[str]:
    """The largest size's network's clips per second and the whole script's time."""
    net8 = sizes[-1]["network"]["throughput"]
    return [
        "## Throughput",
        "",
        f"The {sizes[-1]['bins']} x {sizes[-1]['delays']} classifier network "
        f"({sizes[-1]['network']['n']} test clips): "
        f"{net8['clips_per_s']:.2f} clips/s on {net8['cores']} cores (Dask local cluster, "
        f"float32 RK4 at {msp.INPUT_RATE * msp.SUBSTEPS / 1000:g} kHz, including the numba "
        f"compile). Whole script: {seconds / 60:.1f} "
        "min.",
        "",
    ]


def _parameters(s: msp.MassSpringSettings) -> list[str]:
    """The network's default parameters as a table."""
    return [
        "## Network parameters (defaults)",
        "",
        "| parameter | value |",
        "|---|---|",
        *[f"| {k} | {v} |" for k, v in settings_table(s)],
        "",
    ]


def _how_measured(test_clips: int) -> list[str]:
    """The command, the corpus and what every mass-spring accuracy simulates."""
    return [
        "## How it was measured",
        "",
        "Regenerated by `python scripts/results_massspring.py --data DIR --out "
        "docs/results-massspring.md` (the corpus: `springc data synth DIR --clips 1600 --seed 1 "
        f"--words {CORPUS_WORDS}`, the built-in synthetic GSCD-layout corpus, held-out splits "
        f"class-balanced as in the paper; {test_clips} test clips). Every "
        "mass-spring accuracy is a simulation of the whole network, sound to decision: the "
        "feature extraction (two-mode Mel filters, quadratic couplings into critically damped "
        "50 Hz low-pass masses, cube-root compressors, delay lines with reflection-free "
        "terminals) feeding every "
        "class head (mvm encoding Q, quadratic couplings carrying lambda, readout tau = 80 s) "
        "in one netlist (`classifier.spr` in each model folder), RK4 at "
        f"{msp.INPUT_RATE * msp.SUBSTEPS / 1000:g} kHz. Decisions: "
        "readout / design scale + intercept; no parameter is fitted on test data.",
        "",
    ]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--out", type=Path, default=Path("docs/results-massspring.md"))
    ap.add_argument("--models", type=Path, default=Path("out/results-massspring"))
    ap.add_argument("--jobs", type=int, default=0)
    args = ap.parse_args()
    start = time.perf_counter()
    sizes = [run_size(args.data, args.models, n, m, "kws12", args.jobs) for n, m in SIZES]
    pairs = run_size(args.data, args.models, 4, 2, "digits-pairs", args.jobs)
    tag = f"kws12-n{SWEEP_SIZE[0]}-m{SWEEP_SIZE[1]}"
    eps = epsilon_sweep(args.models / f"mass-spring-{tag}", args.data, EPSILONS, jobs=args.jobs)
    comp = compression_sweep(args.data, THRESHOLDS, args.models / "compression",
                             bins=SWEEP_SIZE[0], delays=SWEEP_SIZE[1], jobs=args.jobs)
    plot = args.out.with_name("results-massspring-sweeps.png")
    plot_sweeps(plot, eps, comp, f"mass-spring KWS {SWEEP_SIZE[0]} x {SWEEP_SIZE[1]}, "
                "built-in corpus")
    seconds = time.perf_counter() - start
    (args.models / "results.json").write_text(json.dumps(
        {"eps": eps, "compression": comp}, indent=2) + "\n")
    tmp = args.out.with_suffix(".tmp")
    tmp.write_text(page(args.data, sizes, pairs, eps, comp, seconds, plot, correlation(args.data),
                        budget_section(args.models, args.data)))
    os.replace(tmp, args.out)
    print(f"wrote {args.out} and {plot} in {seconds / 60:.1f} min")


if __name__ == "__main__":
    main()
