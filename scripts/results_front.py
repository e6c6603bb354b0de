"""Regenerate docs/results-front.md (and results-front.png beside it, not committed): the
accuracy-versus-insertion-loss front (paper Fig. 8e-f) of the SVM-transferred mass-spring
network against the same network with its heads refitted on its exact response (the refit
of `springc tune`, `springc.kws.tuning.refit`), cross-validated over speakers.

    springc data synth /tmp/corpus14 --clips 1600 --seed 1 \\
        --words yes,no,up,down,left,right,on,off,stop,go,one,two,three,four
    python scripts/results_front.py --data /tmp/corpus14

Per size and fold (speaker folds as `springc cv`; each fold's clips tested by models that
never heard their speakers): the SVM on the training folds' Phi (C chosen on the next fold,
as `springc cv` does) transferred to heads at each squaring error eps; the whole network
(front end and heads) simulated on --test clips of the held-out fold (transferred), on
the training folds' clips (J, the zero modes' integrals), the refit's C chosen on the next
fold as the SVM's, the refit fitted again on every training clip with it, and its network
simulated on the same test clips. Unlike `springc tune`, which fits on its training split and
keeps the refit only when it beats the transferred network on validation, every fold's refit
is measured, so the page shows the refit itself.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import time
from pathlib import Path

import numpy as np

from springc.check import check
from springc.kws.evaluation import crossval as cv
from springc.kws.tuning import refit as rf
from springc.kws.training import transfer as tr
from springc.kws.features.digital import FeatureSettings
from springc.kws.features.distributed import session
from springc.kws.features.massspring import integrated, load_signals, physical_settings
from springc.kws.training.svm import SVM_GRID
from springc.kws.data.task import open_task_data, task_weights
from springc.kws.training.train import feature_matrices
from springc.lang import load_text


def parse() -> argparse.Namespace:
    """Command-line options."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", type=Path)
    p.add_argument("--out", type=Path, default=Path("docs/results-front.md"))
    p.add_argument("--sizes", default="4x2:1e-5,1e-3,1e-2;8x3:1e-3,1e-2",
                   help="size:eps,eps;... (bins x delays and the squaring errors)")
    p.add_argument("--folds", type=int, default=3)
    p.add_argument("--test", type=int, default=200, help="Test clips per held-out fold.")
    p.add_argument("--refit", type=int, default=0,
                   help="Clips of the training folds but the next one the refit fits on "
                        "(0: all).")
    p.add_argument("--val", type=int, default=0,
                   help="Clips of the next fold that choose C (0: all); the refit is then "
                        "fitted again on both with that C.")
    p.add_argument("--jobs", type=int, default=0)
    p.add_argument("--json", type=Path, default=Path("/tmp/results-front.json"),
                   help="The numbers, written after every size.")
    p.add_argument("--from-json", action="store_true",
                   help="Only write the page and plot again from --json's numbers.")
    return p.parse_args()


def draw(idx: np.ndarray, n: int, seed: int) -> np.ndarray:
    """n of the indices (0 or more than there are: all), drawn with the seed, in order."""
    return np.sort(np.random.default_rng(seed).permutation(idx)[:n or len(idx)])


def size_run(args, clips, y, fold, groups, bins: int, delays: int, eps_list) -> dict:
    """Every fold and eps of one size: per eps the per-clip outcomes and losses of both."""
    s, _, ref = integrated(physical_settings(FeatureSettings(bins=bins, delays=delays), None),
                           clips, 1e-3)
    x = feature_matrices(clips, "cv", "mass-spring", [s], noise_files=[], jobs=args.jobs,
                         use_cache=True)[0]
    weight = task_weights("kws12")
    plan, out = None, {eps: {"test": [], "transferred": [], "refit": [], "il_t": [],
                             "il_r": [], "c": []} for eps in eps_list}
    sig = _signal_cache(clips)
    for k, model, models, idx, eps in _fold_cases(args, x, y, fold, weight, eps_list):
        heads = tr.heads_for(models, s, ref.amplitude, eps)
        net = load_text(tr.classifier_text(heads, s, epsilon=eps), "<classifier>")
        if plan is None:  # chosen once per size, on the first fold's loudest network
            plan = tr.choose_classifier_integration(check(net), heads, s, ref.signals[:16])
            print(f"{bins}x{delays}: classifier integration {plan.describe()}", flush=True)
        t0 = time.perf_counter()
        got = {n: rf.response(net, heads, s, sig(i), plan, jobs=args.jobs) for n, i in idx.items()}
        fitted = _refitted(got, y, idx, heads, models, weight)
        again = _refit_response(fitted, heads, s, ref.amplitude, eps, sig(idx["test"]), plan,
                                args.jobs)
        _record(out[eps], idx["test"], got["test"], again, fitted, model.classes, y)
        print(f"{bins}x{delays} fold {k} eps {eps:g}: transferred "
              f"{np.mean(out[eps]['transferred'][-len(idx['test']):]):.3f} refit "
              f"{np.mean(out[eps]['refit'][-len(idx['test']):]):.3f} "
              f"({time.perf_counter() - t0:.0f} s)", flush=True)
    return {"plan": plan.describe(), "eps": out}


def _signal_cache(clips):
    """idx -> the clips' signals stacked, each clip loaded once for the whole size."""
    signals = {}

    def sig(idx):
        missing = [i for i in idx if i not in signals]
        if missing:
            for i, row in zip(missing, load_signals([clips[i] for i in missing], False, 0, [])):
                signals[i] = row
        return np.stack([signals[i] for i in idx])

    return sig


def _fold_cases(args, x, y, fold, weight, eps_list):
    """Per fold (in order) and eps: the fold, its SVM trained on the other folds (C chosen on
    the next), that SVM as the heads' models, and its drawn test, refit ("fit") and C-choosing
    ("val") clips."""
    k_folds = int(fold.max()) + 1
    for k in range(k_folds):
        nxt = (k + 1) % k_folds
        inner, val = (fold != k) & (fold != nxt), fold == nxt
        model, _ = cv.fold_model(x, y, fold, k, SVM_GRID, weight)
        models = [(tuple(model.classes), model)]
        idx = {"test": draw(np.flatnonzero(fold == k), args.test, k),
               "fit": draw(np.flatnonzero(inner), args.refit, 100 + k),
               "val": draw(np.flatnonzero(val), args.val, 200 + k)}
        for eps in eps_list:
            yield k, model, models, idx, eps


def _refitted(got: dict, y, idx: dict, heads, models, weight):
    """The refit of the heads on the exact responses: C chosen on the "val" clips, then fitted
    again with it on every training clip ("fit" and "val")."""
    fitted = rf.fit((got["fit"].j, y[idx["fit"]]), (got["val"].j, y[idx["val"]]), heads,
                    models, "kws12", weight)
    both = np.concatenate([idx["fit"], idx["val"]])  # C chosen: fit on every training clip
    fitted.weights, fitted.intercepts = rf.fit_rows(
        np.concatenate([got["fit"].j, got["val"].j]), y[both], heads, models,
        fitted.c, weight)
    return fitted


def _refit_response(fitted, heads, s, amplitude: float, eps: float, signals, plan, jobs: int):
    """The refitted heads' whole network simulated on `signals`."""
    new = tr.reweighted_heads(heads, fitted.weights, fitted.intercepts, s, amplitude, eps)
    net2 = load_text(tr.classifier_text(new, s, epsilon=eps), "<refit classifier>")
    return rf.response(net2, new, s, signals, plan, jobs=jobs)


def _record(row: dict, test, got, again, fitted, classes, y) -> None:
    """One fold's test clips into `row`: the transferred and the refitted networks' outcomes
    and insertion losses, and the refit's C."""
    row["test"] += test.tolist()
    row["transferred"] += (classes[got.decisions.argmax(1)] == y[test]).tolist()
    row["refit"] += (classes[again.decisions.argmax(1)] == y[test]).tolist()
    row["il_t"] += got.loss_db.tolist()
    row["il_r"] += again.loss_db.tolist()
    row["c"].append(fitted.c)


def summarise(run: dict, y, groups) -> list[dict]:
    """Per eps: balanced accuracies with speaker-bootstrap SEs, the paired difference and
    the median insertion losses."""
    rows = []
    for eps, r in run["eps"].items():
        idx = np.array(r["test"])
        correct = {"t": np.array(r["transferred"]), "r": np.array(r["refit"])}
        boot = cv.speaker_bootstrap(y[idx], correct, groups[idx], resamples=1000)
        acc = {n: cv.balanced_accuracy(y[idx], ok) for n, ok in correct.items()}
        rows.append({"eps": eps, "clips": len(idx), "transferred": acc["t"], "refit": acc["r"],
                     "se_t": float(boot["t"].std()), "se_r": float(boot["r"].std()),
                     "gain": acc["r"] - acc["t"],
                     "se_gain": float((boot["r"] - boot["t"]).std()),
                     "il_t": float(np.median(r["il_t"])), "il_r": float(np.median(r["il_r"])),
                     "c": r["c"]})
    return rows


def plot(results: dict, path: Path) -> None:
    """Accuracy against median insertion loss per size, transferred and refitted."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(results), figsize=(5 * len(results), 3.8), squeeze=False)
    for ax, (size, res) in zip(axes[0], results.items()):
        rows = res["rows"]
        for key, il, se, name in (("transferred", "il_t", "se_t", "SVM-transferred"),
                                  ("refit", "il_r", "se_r", "refitted on the exact response")):
            ax.errorbar([r[il] for r in rows], [100 * r[key] for r in rows],
                        yerr=[100 * r[se] for r in rows], marker="o", capsize=4, label=name)
            for r in rows:
                ax.annotate(f"eps {r['eps']:g}", (r[il], 100 * r[key]), fontsize=7,
                            textcoords="offset points", xytext=(4, 4))
        ax.set_xlabel("insertion loss, median (dB)")
        ax.set_ylabel("class-balanced accuracy (%)")
        ax.set_title(f"{size}: speaker CV")
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def loss_for(rows: list[dict], acc: float) -> float | None:
    """The insertion loss at which the transferred front reaches accuracy `acc`: linear
    between its points in order of loss, from the lowest loss up (None: never reached)."""
    pts = sorted((r["il_t"], r["transferred"]) for r in rows)
    if pts[0][1] >= acc:
        return pts[0][0]
    for (il0, a0), (il1, a1) in zip(pts, pts[1:]):
        if a0 < acc <= a1:
            return il0 + (acc - a0) / (a1 - a0) * (il1 - il0)
    return None


def accuracy_at(rows: list[dict], il: float) -> float | None:
    """The transferred front's accuracy at insertion loss `il`: linear between its points
    (None outside them)."""
    pts = sorted((r["il_t"], r["transferred"]) for r in rows)
    for (il0, a0), (il1, a1) in zip(pts, pts[1:]):
        if il0 <= il <= il1:
            return a0 + (il - il0) / (il1 - il0) * (a1 - a0)
    return None


def front_lines(rows: list[dict]) -> list[str]:
    """Where the refitted points sit against the transferred front: at equal loss (the gain
    at the same eps) and at equal accuracy (the loss the transferred network needs)."""
    out = []
    for r in rows:
        need = loss_for(rows, r["refit"])
        best = 100 * max(x["transferred"] for x in rows)
        where = (f"the transferred network needs {need:.1f} dB for it, "
                 f"{need - r['il_r']:.1f} dB more" if need is not None else
                 f"no transferred point reaches it (best {best:.1f}%)")
        at = accuracy_at(rows, r["il_r"])
        same = (f"; the transferred front at {r['il_r']:.1f} dB: {100 * at:.1f}% "
                f"({100 * (r['refit'] - at):+.1f} points)" if at is not None else "")
        out.append(f"- eps {r['eps']:g}: refitted {100 * r['refit']:.1f}% at "
                   f"{r['il_r']:.1f} dB ({100 * r['gain']:+.1f} +- {100 * r['se_gain']:.1f} "
                   f"points against the transferred network at {r['il_t']:.1f} dB{same}); "
                   f"{where}")
    return out


def page(results: dict, meta: dict) -> str:
    """The markdown page from the numbers and the run's settings (`meta`): the plot, the
    tables per size, then how it was measured."""
    lines = ["# Results: the accuracy-insertion loss front, transferred against refitted",
             "", "Plot: `results-front.png` beside this page after a run (not committed).", ""]
    for size, res in results.items():
        lines += _size_section(size, res)
    lines += ["## How it was measured", "",
              "Regenerate with `python scripts/results_front.py --data DIR` (its docstring "
              f"gives the corpus command; springc at {meta['commit']}, {meta['minutes']:.1f} "
              "min on the 2-core machine, warm feature cache). "
              f"{meta['folds']}-fold speaker cross-validation of the built-in corpus "
              f"({meta['test']} test clips drawn from each held-out fold, so "
              f"{meta['folds'] * meta['test']} per point, each tested by models that never "
              f"heard its speaker; the refit on {meta['refit'] or 'all'} clips of the training "
              f"folds but the next, C on {meta['val'] or 'all'} clips of the next fold, then "
              "fitted again on both; every fold's refit measured, without `springc tune`'s "
              "rule that keeps it only when it beats the transferred network on validation). "
              "Every accuracy is the whole network simulated, sound to "
              "decision; accuracies are class-balanced with speaker-bootstrap standard errors; "
              "the gain is paired (same clips).", ""]
    return "\n".join(lines)


def _size_section(size: str, res: dict) -> list[str]:
    """One size's table per eps and where its refitted points sit against the front."""
    rows = res["rows"]
    lines = [f"## {size} ({res['plan']})", "",
             "| eps | transferred % | refitted % | gain (points) | IL transferred dB "
             "| IL refitted dB | C per fold |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(
            f"| {r['eps']:g} | {100 * r['transferred']:.1f} +- {100 * r['se_t']:.1f} | "
            f"{100 * r['refit']:.1f} +- {100 * r['se_r']:.1f} | "
            f"{100 * r['gain']:+.1f} +- {100 * r['se_gain']:.1f} | {r['il_t']:.1f} | "
            f"{r['il_r']:.1f} | {', '.join(f'{c:g}' for c in r['c'])} |")
    lines += ["", "Against the transferred front (linear between its points):", ""]
    return lines + front_lines(rows) + [""]


def write(results: dict, meta: dict, out: Path) -> None:
    """The page and its plot."""
    out.write_text(page(results, meta) + "\n")
    plot(results, out.with_suffix(".png"))
    print(f"wrote {out}")


def main() -> None:
    args = parse()
    if args.from_json:
        saved = json.loads(args.json.read_text())
        write(saved["results"], saved["meta"], args.out)
        return
    start = time.perf_counter()
    ds = open_task_data(args.data, "kws12", 0, "lists")
    clips = ds.clips
    y = np.array([c.label for c in clips])
    groups = cv.speaker_groups(clips)
    fold = cv.speaker_folds(groups, args.folds)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                            text=True).stdout.strip()
    meta = {"commit": commit, "folds": args.folds, "test": args.test, "refit": args.refit,
            "val": args.val}
    results = {}
    with session(None, args.jobs or None):
        for part in args.sizes.split(";"):
            size, eps = part.split(":")
            bins, delays = (int(v) for v in size.split("x"))
            run = size_run(args, clips, y, fold, groups, bins, delays,
                           [float(e) for e in eps.split(",")])
            results[size] = {"plan": run["plan"], "rows": summarise(run, y, groups)}
            meta["minutes"] = (time.perf_counter() - start) / 60
            args.json.write_text(json.dumps({"results": results, "meta": meta}, indent=1))
    write(results, meta, args.out)


if __name__ == "__main__":
    main()
