"""Regenerate docs/results-voices.md: how the keyword spotter hears voices it never heard, by
leaving one text-to-speech engine of the built-in corpus out of training in turn.

    python scripts/results_voices.py --out /tmp/voices/run --before docs/results-voices-before.json

For each engine E (espeak, flite, festival), as a user would with `springc`:
`data synth` a training corpus from the other two engines and a corpus of E alone (its split
lists removed, so that every clip is a test clip), `train` an 8x3 model on the first
(digital and mass-spring), then `eval` it on its own test split and on the corpus of E. The
gap is own-test accuracy minus left-out-engine accuracy; the mean gap over the three engines
is the measure of generalisation to unheard voices. A mass-spring model is evaluated by
`springc eval`, which simulates its whole classifier network.

The numbers go to OUT/voices.json; the page is written from them and from an earlier run's
JSON (`--before`, the table before the corpus changed). Text below the NOTES marker of an
existing page (what was tried, by hand) is kept.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

ENGINES = ("espeak", "flite", "festival")
REALISATIONS = ("digital", "mass-spring")
LIST_FILES = ("validation_list.txt", "testing_list.txt")
NOTES = "<!-- notes below are kept by scripts/results_voices.py -->"
ROOT = Path(__file__).resolve().parents[1]


def springc(args: list[str]) -> str:
    """Run `springc ARGS` and return its standard output (a failure stops the script;
    progress goes to the terminal)."""
    print("$ springc " + " ".join(args), flush=True)
    done = subprocess.run(["springc", *args], check=True, stdout=subprocess.PIPE, text=True)
    return done.stdout


def synth(out: Path, clips: int, engines: tuple[str, ...], seed: int) -> Path:
    """A corpus of `engines` (reused if a previous run of this script made it)."""
    if not out.exists():
        springc(["data", "synth", str(out), "--clips", str(clips), "--seed", str(seed),
                 "--engines", ",".join(engines)])
    return out


def test_only(corpus: Path) -> Path:
    """`corpus` without its split lists: `springc eval` then tests on every clip."""
    for name in LIST_FILES:
        (corpus / name).unlink(missing_ok=True)
    return corpus


def evaluate(model: Path, data: Path | None) -> dict:
    """`springc eval MODEL [--data DIR] --json`: accuracy, n, per-class rates."""
    return json.loads(springc(["eval", str(model), "--json"]
                              + (["--data", str(data)] if data else [])))


def train(data: Path, model: Path, realisation: str) -> Path:
    """An 8x3 model of `realisation` (reused if a previous run of this script made it)."""
    if not (model / "report.json").is_file():
        springc(["train", "--data", str(data), "-n", "8", "-m", "3", "--realisation",
                 realisation, "-o", str(model)])
    return model


def corpora(engine: str, args: argparse.Namespace) -> tuple[Path, Path]:
    """(training corpus without `engine`, test-only corpus of `engine` alone)."""
    others = tuple(e for e in ENGINES if e != engine)
    corpus = synth(args.out / f"without-{engine}", args.train_clips, others, args.seed)
    alone = test_only(synth(args.out / f"only-{engine}", args.test_clips, (engine,),
                            args.seed + 1))
    return corpus, alone


def leave_out(engine: str, args: argparse.Namespace) -> dict:
    """One row: per realisation own-test and left-out-engine accuracy (and, with
    `--fixed-tests`, the accuracy on that run's corpus of the engine)."""
    corpus, alone = corpora(engine, args)
    row: dict = {"engine": engine, "trained_on": tuple(e for e in ENGINES if e != engine)}
    for realisation in args.realisations:
        start = time.perf_counter()
        model = train(corpus, args.out / f"{realisation}-without-{engine}", realisation)
        own, heard = evaluate(model, None), evaluate(model, alone)
        row[realisation] = {"own": own["accuracy"], "own_n": own["n"],
                            "left_out": heard["accuracy"], "left_out_n": heard["n"],
                            "gap": own["accuracy"] - heard["accuracy"]}
        if args.fixed_tests:
            row[realisation]["fixed"] = evaluate(model, args.fixed_tests
                                                 / f"only-{engine}")["accuracy"]
        row[realisation]["seconds"] = time.perf_counter() - start
    return row


def run(args: argparse.Namespace) -> dict:
    """Every row, with what the page says about the run. Every corpus is made first, so that
    the synthesis code may change once they exist."""
    args.out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    for engine in ENGINES:
        corpora(engine, args)
    rows = [leave_out(e, args) for e in ENGINES]
    return {"train_clips": args.train_clips, "test_clips": args.test_clips, "seed": args.seed,
            "realisations": list(args.realisations), "rows": rows,
            "commit": git_commit(), "minutes": (time.perf_counter() - start) / 60,
            "machine": f"{platform.machine()}, {os.cpu_count()} cores"}


def git_commit() -> str:
    """The repository's commit (with `+changes` when the work tree differs)."""
    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
                          capture_output=True, text=True).stdout.strip()
    dirty = subprocess.run(["git", "-C", str(ROOT), "status", "--porcelain", "springc"],
                           capture_output=True, text=True).stdout.strip()
    return head + ("+changes" if dirty else "")


def mean_gap(r: dict, realisation: str) -> float:
    """The mean over engines of own-test minus left-out-engine accuracy."""
    gaps = [row[realisation]["gap"] for row in r["rows"] if realisation in row]
    return sum(gaps) / len(gaps)


def table(r: dict) -> list[str]:
    """The leave-one-engine-out table of one run, in percent."""
    present = [x for x in REALISATIONS if x in r["realisations"]]
    fixed = {x for x in present if "fixed" in r["rows"][0][x]}
    head = "| engine left out | trained on |"
    rule = "|---|---|"
    for x in present:
        head += f" {x} own test | {x} left-out engine | {x} gap |"
        head += f" {x} left-out engine, the earlier corpus |" if x in fixed else ""
        rule += "---|---|---|" + ("---|" if x in fixed else "")
    lines = [head, rule]
    for row in r["rows"]:
        cells = f"| {row['engine']} | {' + '.join(row['trained_on'])} |"
        for x in present:
            v = row[x]
            cells += (f" {100 * v['own']:.1f} ({v['own_n']}) | {100 * v['left_out']:.1f} "
                      f"({v['left_out_n']}) | {100 * v['gap']:+.1f} |")
            cells += f" {100 * v['fixed']:.1f} |" if x in fixed else ""
        lines.append(cells)
    mean = "| **mean gap** | |" + "".join(f" | | **{100 * mean_gap(r, x):+.1f}** |"
                                         + (" |" if x in fixed else "") for x in present)
    return lines + [mean]


def describe(r: dict) -> str:
    """How a run was made, in one sentence."""
    return (f"{r['train_clips']} clips per training corpus, {r['test_clips']} per left-out "
            f"corpus, seed {r['seed']}, springc at commit {r['commit']}, "
            f"{r['minutes']:.0f} min on {r['machine']}")


def markdown(r: dict, before: dict | None, notes: str) -> str:
    """docs/results-voices.md."""
    lines = [
        "# Unheard voices: leaving one text-to-speech engine out",
        "",
        f"Generated by `python scripts/results_voices.py --train-clips {r['train_clips']} "
        f"--test-clips {r['test_clips']} --out /tmp/voices/run"
        + (" --before docs/results-voices-before.json" if before else "") + "`.",
        "",
        "The built-in corpus speaks with three engines: espeak-ng (formant synthesis, 8 English "
        "accents x its voice variants), flite (kal16, awb, rms, slt) and festival "
        "(kal_diphone, ked_diphone, slt HTS). For each engine E an 8x3 model is trained on a "
        "corpus of the other two (`springc data synth DIR --engines ...`; the 12-class task, "
        "class-balanced held-out splits) and tested on its own test split (speakers it did "
        "not train on, engines it did) and on a corpus of E alone whose split lists were "
        "removed, so that `springc eval MODEL --data DIR_E` tests on every clip of it. The "
        "gap is own-test minus left-out-engine accuracy, in points; its mean over the three "
        "engines is the measure. Accuracies in percent, test clips in brackets; a mass-spring "
        "model's accuracies are its whole classifier network simulated (`springc eval`).",
        "",
        "**flite and festival share speakers**: kal (flite kal16, festival kal_diphone) and "
        "slt (flite slt, festival cmu_us_slt_arctic_hts) are the same recorded people. "
        "Leaving flite out still trains on festival's kal and slt, and leaving festival out "
        "on flite's, so those two rows test an unheard engine, not wholly unheard speakers. "
        "Leaving espeak out trains on the 5 recorded speakers alone.",
        "",
        f"## Now ({describe(r)})",
        "",
        *table(r),
        "",
    ]
    if before:
        lines += [f"## Before ({describe(before)})", "", *table(before), ""]
    return "\n".join(lines) + "\n" + NOTES + "\n" + notes


def kept_notes(doc: Path) -> str:
    """The hand-written text below the NOTES marker of an existing page."""
    if not doc.is_file():
        return ""
    text = doc.read_text()
    return text.split(NOTES, 1)[1].lstrip("\n") if NOTES in text else ""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--train-clips", type=int, default=2400)
    parser.add_argument("--test-clips", type=int, default=600)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--realisations", default=",".join(REALISATIONS),
                        help="comma-separated: digital, mass-spring")
    parser.add_argument("--out", type=Path, default=Path("/tmp/voices/run"))
    parser.add_argument("--before", type=Path, default=None,
                        help="voices.json of an earlier run, shown as the table before")
    parser.add_argument("--doc", type=Path, default=ROOT / "docs" / "results-voices.md")
    parser.add_argument("--fixed-tests", type=Path, default=None,
                        help="an earlier run's OUT: also test on its corpora of each engine")
    args = parser.parse_args()
    args.realisations = tuple(x.strip() for x in args.realisations.split(",") if x.strip())
    unknown = sorted(set(args.realisations) - set(REALISATIONS))
    if unknown:
        parser.error(f"unknown realisation(s): {', '.join(unknown)}")
    before = json.loads(args.before.read_text()) if args.before else None
    r = run(args)
    (args.out / "voices.json").write_text(json.dumps(r, indent=2) + "\n")
    args.doc.write_text(markdown(r, before, kept_notes(args.doc)))
    print(f"written: {args.doc} (mean gap: "
          + ", ".join(f"{x} {100 * mean_gap(r, x):+.1f}" for x in args.realisations) + ")",
          file=sys.stderr)


if __name__ == "__main__":
    main()
