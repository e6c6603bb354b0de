"""Regenerate docs/results-voices.md: how the keyword spotter hears voices it never heard, by
leaving one text-to-speech engine of the built-in corpus out of training in turn.

    python scripts/results_voices.py --out /tmp/voices/run --before docs/results-voices-before.json

For each engine E (espeak, flite, festival), as a user would with `springc`:
`data synth` a training corpus from the other two engines and `--draws` corpora of E alone
(seeds of their own, their split lists removed, so that every clip is a test clip), `train`
an 8x3 model on the first (digital, mass-spring and device), then test it on its own test
split and on the corpora of E (their mean). The gap is own-test accuracy minus left-out-engine
accuracy; the mean gap over the three engines
is the measure of generalisation to unheard voices. A digital model is tested by `springc
eval`; a mass-spring model by its simulated features and the ideal readout c.Phi (its own
test accuracy is its training report's, the corpus of E is read as `springc eval` reads a
folder), which saves the whole network's simulation (it reproduces c.Phi,
docs/keyword-spotting.md); a device model (summing heads), whose ideal readout is the
mass-spring model's, by `springc eval`, its whole network simulated.

The numbers go to OUT/voices.json after each model (a run that stops goes on where it
stopped; `--realisations` adds realisations to an earlier run's JSON); the page is written
from them and from an earlier run's JSON (`--before`, the table before the corpus changed).
Text below the NOTES marker of an existing page (what was tried, by hand) is kept.
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
REALISATIONS = ("digital", "mass-spring", "device", "router")
LIST_FILES = ("validation_list.txt", "testing_list.txt")
NOTES = "<!-- notes below are kept by scripts/results_voices.py -->"
ROOT = Path(__file__).resolve().parents[1]

# How the leave-one-engine-out runs are made and read, and the speakers flite and festival
# share (the page's "How it was measured", after the command).
METHOD = [
    "The built-in corpus speaks with three engines: espeak-ng (formant synthesis, 8 English "
    "accents x its voice variants), flite (kal16, awb, rms, slt) and festival "
    "(kal_diphone, ked_diphone, slt HTS). For each engine E an 8x3 model is trained on a "
    "corpus of the other two (`springc data synth DIR --engines ...`; the 12-class task, "
    "class-balanced held-out splits) and tested on its own test split (speakers it did "
    "not train on, engines it did) and on corpora of E alone whose split lists were "
    "removed, so that `springc eval MODEL --data DIR_E` tests on every clip of them "
    "(`--draws` of them, each synthesised with a seed of its own: one draw of 211 test "
    "clips moved festival's left-out accuracy by 10 points against another, far more "
    "than its binomial error). The left-out accuracy is the mean over the draws; the "
    "gap is own-test minus left-out-engine accuracy, in points; its mean over the three "
    "engines is the measure. Accuracies in percent, test clips in brackets (all draws "
    "together, then the range of the draws' accuracies). A mass-spring "
    "model is tested by its simulated features and the ideal readout c.Phi (its training "
    "report's own-test accuracy; the corpus of E read as `springc eval` reads it), not "
    "by simulating its whole classifier network, which reproduces c.Phi and would take "
    "several times longer. A device model (summing heads, `--realisation device`) shares "
    "the mass-spring model's features and ideal readout, so it is tested by simulating its "
    "whole network (`springc eval MODEL --data DIR --json`), own test split included; so "
    "is a router (16 bins, `--realisation router`, its linear passive network simulated).",
    "",
    "**flite and festival share speakers**: kal (flite kal16, festival kal_diphone) and "
    "slt (flite slt, festival cmu_us_slt_arctic_hts) are the same recorded people. "
    "Leaving flite out still trains on festival's kal and slt, and leaving festival out "
    "on flite's, so those two rows test an unheard engine, not wholly unheard speakers. "
    "Leaving espeak out trains on the 5 recorded speakers alone.",
]


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
    """Accuracy and test clips of a model on its own test split (`data` None) or on a
    folder's: `springc eval MODEL [--data DIR] --json` for a digital model and for a device
    model (its whole network simulated), the simulated features and c.Phi for a mass-spring
    one (`features_eval`)."""
    settings = json.loads((model / "settings.json").read_text())
    # a device model is a mass-spring realisation with its physical scale ("device")
    if settings["realisation"] != "mass-spring" or settings.get("device"):
        return json.loads(springc(["eval", str(model), "--json"]
                                  + (["--data", str(data)] if data else [])))
    if data is None:
        report = json.loads((model / "report.json").read_text())
        return {"accuracy": report["accuracy"], "n": report["n"]}
    return features_eval(model, data, settings)


def features_eval(model: Path, data: Path, settings: dict) -> dict:
    """A mass-spring model's ideal readout on a folder's test split, read as `springc eval`
    reads it (the model's task, seed and protocol)."""
    from springc.kws.features.massspring import MassSpringSettings
    from springc.kws.training.model import load_model
    from springc.kws.training.report import score
    from springc.kws.data.task import open_task_data, targets
    from springc.kws.training.train import feature_matrices

    print(f"$ (features of {model.name} on {data})", flush=True)
    feats = MassSpringSettings(**{k: v for k, v in settings["features"].items()
                                  if k != "realisation"})
    ds = open_task_data(data, settings["task"], int(settings.get("seed", 0)),
                        settings.get("protocol"), splits=("test",))
    clips = ds.split("test")
    x = feature_matrices(clips, "test", "mass-spring", [feats], noise_files=ds.noise_files)[0]
    return score(load_model(model).models, x, targets(clips, settings["task"]),
                 settings["task"])


def train(data: Path, model: Path, realisation: str) -> Path:
    """An 8x3 model of `realisation`, a router of 16 bins (reused if a previous run of this
    script made it)."""
    size = ["-n", "16"] if realisation == "router" else ["-n", "8", "-m", "3"]
    if not (model / "report.json").is_file():
        springc(["train", "--data", str(data), *size, "--realisation", realisation,
                 "-o", str(model)])
    return model


def corpora(engine: str, args: argparse.Namespace) -> tuple[Path, list[Path]]:
    """(training corpus without `engine`, the `args.draws` test-only corpora of `engine`
    alone, seeds seed + 1, seed + 2, ...)."""
    others = tuple(e for e in ENGINES if e != engine)
    corpus = synth(args.out / f"without-{engine}", args.train_clips, others, args.seed)
    alone = [test_only(synth(args.out / (f"only-{engine}" + (f"-{k + 1}" if k else "")),
                             args.test_clips, (engine,), args.seed + 1 + k))
             for k in range(args.draws)]
    return corpus, alone


def leave_out(engine: str, realisation: str, args: argparse.Namespace) -> dict:
    """One cell of a row: own-test and left-out-engine accuracy of one realisation (and,
    with `--fixed-tests`, the accuracy on that run's corpus of the engine)."""
    corpus, alones = corpora(engine, args)
    start = time.perf_counter()
    model = train(corpus, args.out / f"{realisation}-without-{engine}", realisation)
    own, heard = evaluate(model, None), [evaluate(model, a) for a in alones]
    left = sum(h["accuracy"] for h in heard) / len(heard)
    cell = {"own": own["accuracy"], "own_n": own["n"], "left_out": left,
            "left_out_n": sum(h["n"] for h in heard), "gap": own["accuracy"] - left,
            "left_out_draws": [h["accuracy"] for h in heard]}
    if args.fixed_tests:
        cell["fixed"] = evaluate(model, args.fixed_tests / f"only-{engine}")["accuracy"]
    cell["seconds"] = time.perf_counter() - start
    return cell


def run(args: argparse.Namespace) -> dict:
    """Every row, with what the page says about the run, kept in OUT/voices.json after each
    model. Every corpus is made first, so that the synthesis code may change once they
    exist; the digital models come before the slower mass-spring ones."""
    args.out.mkdir(parents=True, exist_ok=True)
    saved = args.out / "voices.json"
    r = json.loads(saved.read_text()) if saved.is_file() else {
        "train_clips": args.train_clips, "test_clips": args.test_clips, "seed": args.seed,
        "realisations": [], "minutes": 0.0,
        "rows": [{"engine": e, "trained_on": [x for x in ENGINES if x != e]}
                 for e in ENGINES]}
    if not all((args.out / f"{k}-{e}").is_dir() for k in ("without", "only") for e in ENGINES):
        r["corpus_commit"] = git_commit()  # the synthesis code the corpora come from
    for engine in ENGINES:
        corpora(engine, args)
    for realisation in args.realisations:
        for row in r["rows"]:
            if draws(row.get(realisation)) < args.draws:  # a new cell, or draws to add
                start = time.perf_counter()
                row[realisation] = leave_out(row["engine"], realisation, args)
                r["minutes"] += (time.perf_counter() - start) / 60
                r.update(commit=git_commit(),
                         machine=f"{platform.machine()}, {os.cpu_count()} cores")
                saved.write_text(json.dumps(r, indent=2) + "\n")
        r["realisations"] = [x for x in REALISATIONS
                             if x in r["realisations"] or x == realisation]
    return r


def draws(cell: dict | None) -> int:
    """Left-out corpora a cell was tested on (0: no cell yet; 1: a cell from before
    `--draws`, which has no list of them)."""
    if cell is None:
        return 0
    return len(cell.get("left_out_draws", [cell["left_out"]]))


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
            draws = v.get("left_out_draws", [])
            spread = (f"; {100 * min(draws):.1f}-{100 * max(draws):.1f}"
                      if len(draws) > 1 else "")
            cells += (f" {100 * v['own']:.1f} ({v['own_n']}) | {100 * v['left_out']:.1f} "
                      f"({v['left_out_n']}{spread}) | {100 * v['gap']:+.1f} |")
            cells += f" {100 * v['fixed']:.1f} |" if x in fixed else ""
        lines.append(cells)
    mean = "| **mean gap** | |" + "".join(f" | | **{100 * mean_gap(r, x):+.1f}** |"
                                         + (" |" if x in fixed else "") for x in present)
    return lines + [mean]


def describe(r: dict) -> str:
    """How a run was made, in one sentence."""
    n = draws(r["rows"][0][r["realisations"][0]])
    seeds = f"{n} of them, seeds {r['seed'] + 1}-{r['seed'] + n}" if n > 1 else \
        f"seed {r['seed'] + 1}"
    return (f"{r['train_clips']} clips per training corpus, {r['test_clips']} per left-out "
            f"corpus ({seeds}), seed {r['seed']}, corpora from springc at commit "
            f"{r.get('corpus_commit', r['commit'])}, models at {r['commit']}, "
            f"{r['minutes']:.0f} min of training and testing on {r['machine']}")


def fixed_tests(r: dict) -> bool:
    """Whether a run also tested on an earlier run's corpora (`--fixed-tests`)."""
    return any("fixed" in row.get(x, {}) for row in r["rows"] for x in REALISATIONS)


def markdown(r: dict, before: dict | None, notes: str) -> str:
    """docs/results-voices.md: the tables, how they were measured, then the kept notes."""
    lines = ["# Unheard voices: leaving one text-to-speech engine out", "",
             f"## Now ({describe(r)})", "", *table(r), ""]
    if before:
        lines += [f"## Before ({describe(before)})", "", *table(before), ""]
    lines += [
        "## How it was measured",
        "",
        f"Generated by `python scripts/results_voices.py --train-clips {r['train_clips']} "
        f"--test-clips {r['test_clips']} --realisations {','.join(r['realisations'])} "
        "--out /tmp/voices/run"
        + (" --fixed-tests /tmp/voices/before" if fixed_tests(r) else "")
        + (" --before docs/results-voices-before.json" if before else "") + "`.",
        "",
        *METHOD,
        "",
    ]
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
    parser.add_argument("--draws", type=int, default=3,
                        help="left-out corpora of each engine (seeds seed+1, ...); the "
                             "left-out accuracy is their mean")
    parser.add_argument("--realisations", default=",".join(REALISATIONS),
                        help="comma-separated: digital, mass-spring, device")
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
