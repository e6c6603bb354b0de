"""Regenerate docs/results-scale.md: the keyword spotter at data-set scale, 8x3, digital and
mass-spring, every stage timed, and the extrapolation to the Google Speech Commands data set.

    python scripts/results_scale.py --clips 20000 --out /tmp/scale

A rerun with the same OUT after a failure skips the stages it has measured (OUT/stages.json).

Runs the installed `springc` as a user would (fresh kernel cache in OUT/kernels, so the
compile times are in): `data synth`, `train` digital, `train --realisation mass-spring` (its
report's per-phase seconds), `eval` of the whole classifier network; then the mass-spring
feature extraction of the same clips with 1 and with 2 local Dask workers (uncached), for
the scaling. Extrapolation: each stage's per-clip time times 105,829 clips, on this machine
and on a cluster of W such workers at the measured per-worker rate.
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

GSCD_CLIPS = 105829  # the paper's data set (v0.02)
SCALING_CLIPS = 256  # training clips whose features are timed with 1 and 2 workers
CHECK_CLIPS = 64  # test clips the pipeline's integration is checked on


def springc(args: list[str], env: dict, done: Path) -> tuple[float, str]:
    """Run `springc ARGS`: its wall seconds and standard output (a failure stops the
    script; progress goes to the terminal). Kept in the JSON file `done` under the command
    line, so a rerun after a failure skips the stages it has."""
    key = " ".join(args)
    kept = json.loads(done.read_text()) if done.is_file() else {}
    if key in kept:
        print(f"$ springc {key}  (measured before: {kept[key][0]:.0f} s)", flush=True)
        return kept[key][0], kept[key][1]
    print("$ springc " + key, flush=True)
    start = time.perf_counter()
    run = subprocess.run(["springc", *args], check=True, env=env, stdout=subprocess.PIPE,
                         text=True)
    kept[key] = (time.perf_counter() - start, run.stdout)
    done.write_text(json.dumps(kept))
    return kept[key]


def counts(data: Path) -> dict[str, int]:
    """Clips per split of the 12-class task (as `train` balances them)."""
    from springc.kws.data.task import open_task_data

    ds = open_task_data(data, "kws12", 0, None)
    return {s: len(ds.split(s)) for s in ("train", "validation", "test")}


def scaling(data: Path, model: Path) -> dict[int, float]:
    """Mass-spring feature extraction of SCALING_CLIPS training clips with 1 and 2 local
    workers, uncached, at the model's settings: clips per second."""
    from springc.kws.features.distributed import session
    from springc.kws.features.massspring import MassSpringSettings
    from springc.kws.data.task import open_task_data
    from springc.kws.training.train import feature_matrices

    feats = json.loads((model / "settings.json").read_text())["features"]
    s = MassSpringSettings(**{k: v for k, v in feats.items() if k != "realisation"})
    ds = open_task_data(data, "kws12", 0, None)
    clips = ds.split("train")[:SCALING_CLIPS]
    out = {}
    for workers in (1, 2):
        with session(None, workers):
            feature_matrices(clips[:16], "train", "mass-spring", [s], jobs=workers,
                             use_cache=False, noise_files=ds.noise_files)  # workers warm
            start = time.perf_counter()
            feature_matrices(clips, "train", "mass-spring", [s], jobs=workers,
                             use_cache=False, noise_files=ds.noise_files)
            out[workers] = len(clips) / (time.perf_counter() - start)
    return out


def errors(data: Path, model: Path, clips: int = CHECK_CLIPS) -> dict:
    """What the classifier consumes, as the pipeline integrates it, against the tight
    reference (RK4 x16 float64) on the first `clips` test clips: the relative error (per
    clip, of its largest value; the worst clip) of Phi (the features' integration, single
    precision, loud clips at finer steps) and of the readouts x(r_k) (the whole network's)."""
    import numpy as np

    from springc.check import check
    from springc.kws.features import integration as itg
    from springc.kws.features import massspring as msp
    from springc.kws.training import transfer as tr
    from springc.kws.features.distributed import session
    from springc.kws.training.model import load_model
    from springc.kws.data.task import open_task_data
    from springc.lang import load_file

    trained = load_model(model)
    s, heads = tr.model_heads(trained)
    test = open_task_data(data, "kws12", 0, None).split("test")[:clips]
    sig = msp.load_signals(test, False, 0, [])
    method, substeps, precision = itg.REFERENCE
    checked = check(load_file(model / "classifier.spr"))
    with session(None, 2):
        phi = msp.dataset_phi(test, "test", s, noise_files=[])
        phi_ref = msp.simulate_phi(sig, s, method=method, substeps=substeps,
                                   precision=precision, chunk=msp.BATCH)
        out = _readouts(trained, checked, heads, s, sig)
    return {"clips": len(test), "phi": itg.relative_error(phi, phi_ref),
            "readouts": itg.relative_error(out["chosen"], out["reference"]),
            "loud": int(np.sum(msp.stiffness(sig, s) / s.substeps > itg.MAX_WH))}


def _readouts(trained, checked, heads, s, sig) -> dict:
    """The readouts x(r_k) (clips, heads) of the whole network on `sig`, "chosen" at the
    model's integration and "reference" at the tight one (RK4 x16 float64)."""
    from functools import partial

    import numpy as np

    from springc.kws.evaluation.evaluate import model_integration
    from springc.kws.features import integration as itg
    from springc.kws.features import massspring as msp
    from springc.kws.training import transfer as tr

    method, substeps, precision = itg.REFERENCE
    tight = itg.Integration(method, substeps, precision)
    specs = tr.readout_reductions(heads)
    tstop = msp.horizon(s, sig.shape[1] / msp.INPUT_RATE)
    rows = [f"final:x(r{k})" for k in range(len(heads))]
    out = {}
    for name, plan in (("chosen", model_integration(trained)), ("reference", tight)):
        work = partial(tr.classifier_batch, checked=checked, specs=specs, tstop=tstop,
                       plan=plan, s=s)
        reds = msp.map_pooled(work, sig, f"readouts, {name}")
        out[name] = np.stack([reds[r] for r in rows], axis=1)
    return out


def run(clips: int, out: Path) -> dict:
    """Every stage, timed; the numbers the page is written from."""
    out.mkdir(parents=True, exist_ok=True)
    env = {**os.environ, "SPRINGC_CACHE": str(out / "kernels")}
    data, dig, ms = out / "corpus", out / "model-digital", out / "model-mass-spring"
    done = out / "stages.json"
    t = {"synth": springc(["data", "synth", str(data), "--clips", str(clips)], env, done)[0]}
    n = counts(data)
    t["train digital"] = springc(["train", "--data", str(data), "-n", "8", "-m", "3",
                                  "-o", str(dig)], env, done)[0]
    t["train mass-spring"] = springc(["train", "--data", str(data), "-n", "8", "-m", "3",
                                      "--realisation", "mass-spring", "-o", str(ms)], env,
                                     done)[0]
    t["eval mass-spring network"], text = springc(["eval", str(ms), "--json"], env, done)
    os.environ["SPRINGC_CACHE"] = env["SPRINGC_CACHE"]
    reports = {k: json.loads((p / "report.json").read_text()) for k, p in
               (("digital", dig), ("mass-spring", ms))}
    reports["network"] = json.loads(text)
    integration = json.loads((ms / "settings.json").read_text())["transfer"]["integration"]
    sc = scaling(data, ms)
    return {"clips": clips, "counts": n, "seconds": t, "reports": reports, "scaling": sc,
            "network_integration": integration, "errors": errors(data, ms),
            "machine": f"{platform.machine()}, {os.cpu_count()} cores, Python "
            f"{platform.python_version()}", "load": os.getloadavg()[2]}


def markdown(r: dict) -> str:
    """docs/results-scale.md: the tables and figures first, how it was measured after."""
    lines = [
        "# Keyword spotting at data-set scale (8x3)",
        "",
        *_stages(r),
        *_extrapolation(r),
        *_accuracy(r),
        *_how_measured(r),
    ]
    return "\n".join(lines)


def _stages(r: dict) -> list[str]:
    """Each stage's wall time and rate, scaled to the GSCD's clips; training by phase."""
    n, ms = r["counts"], r["reports"]["mass-spring"]
    total = sum(n.values())
    lines = ["| stage | wall s | clips | clips/s | 105,829 clips on this machine |",
             "|---|---|---|---|---|"]
    per = {"synth": r["clips"], "train digital": total, "train mass-spring": total,
           "eval mass-spring network": n["test"]}
    for stage, sec in r["seconds"].items():
        rate = per[stage] / sec
        lines.append(f"| {stage} | {sec:.0f} | {per[stage]} | {rate:.1f} | "
                     f"{GSCD_CLIPS / rate / 3600:.1f} h |")
    lines += ["", "Mass-spring training by phase (its report's `seconds`):", "",
              "| phase | wall s |", "|---|---|"]
    return lines + [f"| {k} | {v:.0f} |" for k, v in ms.get("seconds", {}).items()]


def _extrapolation(r: dict) -> list[str]:
    """The features' scaling over workers and the GSCD's hours at 2, 16 and 64 workers."""
    sc = r["scaling"]
    eff = sc[2] / (2 * sc[1])
    ev = ms_eval_rate(r)
    lines = [
        "",
        f"Scaling of the mass-spring features ({SCALING_CLIPS} clips, uncached, workers "
        f"warm): 1 worker {sc[1]:.1f} clips/s, 2 workers {sc[2]:.1f} clips/s "
        f"(parallel efficiency {eff:.0%}).",
        "",
        "Extrapolation to the Google Speech Commands data set (105,829 clips), mass-spring "
        "features of every clip plus the whole network on its test split (11,005 clips), at "
        "the measured per-worker rates:",
        "",
        "| workers | features | whole-network evaluation |",
        "|---|---|---|",
    ]
    for w in (2, 16, 64):
        feat_h = GSCD_CLIPS / (sc[1] * w * eff) / 3600
        eval_h = 11005 / (ev / 2 * w) / 3600  # ev: already 2 workers' rate
        lines.append(f"| {w} | {feat_h:.2f} h | {eval_h:.2f} h |")
    return lines


def _accuracy(r: dict) -> list[str]:
    """The test accuracies and, where measured, the integration errors against the tight
    reference."""
    ms = r["reports"]["mass-spring"]
    acc = {k: v["accuracy"] for k, v in r["reports"].items()}
    net, ni = r["reports"]["network"], r["network_integration"]
    lines = ["", f"Test accuracy: digital {100 * acc['digital']:.1f}%, mass-spring features "
             f"(ideal readout) {100 * acc['mass-spring']:.1f}%, the whole network simulated "
             f"{100 * acc['network']:.1f}% (readout error {net.get('readout_error', 0):.2g}, "
             f"integration {ni['method']} x{ni['substeps']} {ni['precision']}, within "
             f"{ni['error']:.2g} of {ni['reference']} on {ni['clips']} clips); insertion loss "
             f"{net['insertion_loss_db']['median']:.0f} dB median.", ""]
    if "errors" in r:
        e, fi = r["errors"], ms.get("integration", {}).get("features", {})
        lines += [f"Integration as the pipeline runs it, against {ni['reference']} on the "
                  f"first {e['clips']} test clips (relative to each clip's largest value, "
                  f"the worst clip): Phi {e['phi']:.2g} (features {fi.get('method')} "
                  f"x{fi.get('substeps')} {fi.get('precision')}, {e['loud']} clip(s) "
                  f"predicted too stiff for it and integrated at finer steps), readouts "
                  f"{e['readouts']:.2g} (whole network {ni['method']} x{ni['substeps']} "
                  f"{ni['precision']}); tolerance 1e-3.", ""]
    return lines


def _how_measured(r: dict) -> list[str]:
    """The command, the machine and its load, and the corpus's splits."""
    n = r["counts"]
    return [
        "## How it was measured",
        "",
        f"Generated by `python scripts/results_scale.py --clips {r['clips']}` on "
        f"{r['machine']} (load average over the last 15 minutes at the end: "
        f"{r['load']:.1f}): every stage run as `springc` commands from an empty kernel cache "
        "(compile times included).",
        "",
        f"Corpus: {r['clips']} synthesised clips (all 35 words), of which the 12-class task "
        f"uses {sum(n.values())} (train {n['train']}, validation {n['validation']}, test "
        f"{n['test']}; class-balanced held-out splits).",
        ""]


def ms_eval_rate(r: dict) -> float:
    """The whole network's clips/s on this machine's 2 workers (the eval stage)."""
    return r["counts"]["test"] / r["seconds"]["eval mass-spring network"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clips", type=int, default=20000)
    parser.add_argument("--out", type=Path, default=Path("/tmp/scale"))
    parser.add_argument("--doc", type=Path,
                        default=Path(__file__).resolve().parents[1] / "docs"
                        / "results-scale.md")
    parser.add_argument("--page-only", action="store_true",
                        help="Rewrite the page from OUT/scale.json without running anything.")
    args = parser.parse_args()
    if args.page_only:
        r = json.loads((args.out / "scale.json").read_text())
        r["scaling"] = {int(k): v for k, v in r["scaling"].items()}
    else:
        r = run(args.clips, args.out)
        (args.out / "scale.json").write_text(json.dumps(r, indent=2) + "\n")
    args.doc.write_text(markdown(r))
    print(f"written: {args.doc}", file=sys.stderr)


if __name__ == "__main__":
    main()
