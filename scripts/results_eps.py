"""The 8x3 classifier against the heads' squaring error eps, plain and with buffered taps.

    python scripts/results_eps.py stages --data CORPUS [--clips 2] [--buffer KB,KG ...]
    python scripts/results_eps.py accuracy --model MODEL [--buffer KB,KG ...]
    python scripts/results_eps.py peaks --model MODEL [--clips 96]
    python scripts/results_eps.py cv --data CORPUS [--size 8x3] [--buffer KB,KG ...]
    python scripts/results_eps.py fig8 --runs DIR [DIR ...] --png PNG
    python scripts/results_eps.py integration --data CORPUS [--buffer KB,KG] [--mvm-stiffness 10]
    python scripts/results_eps.py plot --out DIR

`stages`: the whole classifier (stand-in heads, as `scripts/results_stages.py` builds it) on
the first test clips of distinct command words of CORPUS, at each eps of --eps, plain and with
each buffer of --buffer (`springc.kws.training.tapbuffer`: springs KB kc from tap to buffer and
KG kc from buffer to ground). Per network and eps: the distortion of the delay taps, of the
buffer nodes (over their gain g) and of the readouts (x_r / scale, c . Phi) against the plain
network's at eps = 1e-9 (results_stages' measure: RMS error over the ideal's peak, worst
channel, median clip), and the insertion loss (median over the clips).

`accuracy`: a trained mass-spring MODEL's heads designed again at each eps (the same weights,
`transfer.heads_for`), plain and buffered, and the whole network simulated on the model's test
split as `springc eval` does: accuracy, its standard error, the change against the first eps
paired on the same clips, and the insertion loss (median).

`peaks`: the per-clip peak terminal displacement of the features (whose median over the 16
clips of the reference run is the heads' amplitude A) on --clips training clips drawn at
random (seed 0) from MODEL's corpus, as percentiles over the model's A and the factor
(peak / A)^2 by which a clip at that peak meets a larger eps than the design's.

`cv`: speaker-fold cross-validation on CORPUS as `scripts/results_front.py` does it (the
mass-spring features of every clip for --size and the compressors' threshold --threshold; per
fold the SVM on the training folds, C chosen on the next fold, its heads designed at each eps),
the whole network, plain and buffered, simulated on --test clips of the held-out fold: balanced
accuracies with speaker-bootstrap standard errors, the change against the first eps paired on
the same clips (same bootstrap draws) and the insertion loss (median). `fig8` draws the paper's
Fig. 8e-f from `cv` runs: accuracy against insertion loss over eps, and at eps = 1 over sizes
and compression thresholds. `integration`: the error of the `cv` step on the buffered
network.

The first two and `cv` print markdown tables and write them with the JSON to --out; `plot`
draws what --out holds into DIR/results-eps.png (readout distortion and accuracy against
insertion loss).
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from springc.check import check
from springc.kws.evaluation.studies import EPS_IDEAL, distortion, first_command_clips
from springc.kws.features import massspring as msp
from springc.kws.training import tapbuffer as tb
from springc.kws.training import transfer as tr
from springc.lang import load_text
from springc.sim.simulate import simulate

OUTRATE = 2000.0  # taps, buffers and readouts move below 100 Hz


def parse_buffer(text: str) -> tb.TapBuffer:
    """KB,KG in units of kc."""
    kb, kg = (float(v) for v in text.split(","))
    return tb.TapBuffer(kb, kg)


def classifier(heads, s, eps, buffer):
    """The classifier netlist at eps, plain (buffer None) or buffered, the heads' mvms at
    MVM's stiffness."""
    text = tr.classifier_text(heads, s, epsilon=eps,
                              design=tr.Design("zero-mode", buffer, MVM["stiffness"]))
    return load_text(text, f"<eps {eps:g}>")


def network(heads, s, eps, buffer):
    """The checked classifier at eps, plain (buffer None) or buffered."""
    return check(classifier(heads, s, eps, buffer))


def stage_run(s, base_heads, signals, eps, amplitude, buffer):
    """Taps, buffer nodes / g and readouts in c . Phi units (channels, clips, T) and the
    insertion loss per clip."""
    heads = tb.rescaled(tr.redesigned_heads(base_heads, s, tb.amplitude(buffer, amplitude), eps),
                        buffer)
    names = {"delay taps": [f"x({n})" for n in msp.terminals(s)],
             "readout": [f"x(r{k})" for k in range(len(heads))]}
    if buffer:
        names["buffers"] = [f"x({n})" for n in tb.nodes(s)]
    flat = [p for stage in names.values() for p in stage]
    res = simulate(network(heads, s, eps, buffer), signals[:, None, :], msp.INPUT_RATE,
                   tstop=msp.horizon(s, signals.shape[1] / msp.INPUT_RATE), method="exp-rk4",
                   substeps=4, precision="float64", outrate=OUTRATE, probes=flat,
                   reductions=tr.readout_reductions(heads), batch=len(signals))
    out = {st: np.stack([res.probes[p] for p in pl]) for st, pl in names.items()}
    out["readout"] = out["readout"] / np.array([h.scale for h in heads])[:, None, None]
    if buffer:
        out["buffers"] = out["buffers"] / buffer.gain
    if not all(np.all(np.isfinite(v)) for v in out.values()):
        raise RuntimeError(f"the network diverged at eps {eps:g}, buffer {buffer}")
    return out, tr.insertion_loss_db(res.reductions, heads)


MVM = {"stiffness": 1.0}  # the heads' mvm stiffness over its default (--mvm-stiffness)


def stiffer_mvms(factor: float) -> None:
    """Every head's mvm designed with `factor` times the default stiffness d (its stiff modes
    sqrt(factor) higher; `transfer.classifier_text`'s mvm_stiffness)."""
    MVM["stiffness"] = factor


def stages(args) -> None:
    """Distortion per stage and insertion loss against eps, plain and buffered."""
    start = time.time()
    s = msp.MassSpringSettings(bins=8, delays=3)
    signals = first_command_clips(args.data, args.clips)
    base = tr.stand_in_heads(s)
    ideal, _ = stage_run(s, base, signals, EPS_IDEAL, 1.0, None)
    amplitude = float(np.median(np.abs(ideal["delay taps"]).max(axis=(0, 2))))
    stiffer_mvms(args.mvm_stiffness)
    rows = []
    for buffer in ([] if args.no_plain else [None]) + args.buffer:
        for eps in args.eps:
            got, loss = stage_run(s, base, signals, eps, amplitude, buffer)
            row = {"buffer": buffer.to_dict() if buffer else None, "eps": eps,
                   "taps": distortion(got["delay taps"], ideal["delay taps"]),
                   "buffers": (distortion(got["buffers"], ideal["delay taps"])
                               if buffer else None),
                   "readout": distortion(got["readout"], ideal["readout"]),
                   "loss_db": float(np.median(loss))}
            rows.append(row)
            print(row, flush=True)
    text = stages_table(rows)
    print(text)
    print(f"A = {amplitude:.4g} m, {len(signals)} clips, {time.time() - start:.0f} s")
    write(args.out, "stages", text, {"amplitude": amplitude, "clips": len(signals),
                                     "rows": rows, "seconds": time.time() - start})


def stages_table(rows: list[dict]) -> str:
    """Markdown: one row per network and eps, the distortion per stage."""
    lines = ["| network | eps | delay taps | buffer nodes / g | readout | insertion loss dB |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        buf = "-" if r["buffers"] is None else f"{r['buffers']:.2g}"
        lines.append(f"| {_network_name(r['buffer'])} | {r['eps']:g} | {r['taps']:.2g} | {buf} | "
                     f"{r['readout']:.2g} | {r['loss_db']:.1f} |")
    return "\n".join(lines)


def accuracy(args) -> None:
    """A trained model's whole network at each eps, plain and buffered, on its test split."""
    from springc.kws.evaluation import evaluate as ev
    from springc.kws.features.distributed import session
    from springc.kws.training.model import load_model

    start = time.time()
    stiffer_mvms(args.mvm_stiffness)
    model = load_model(args.model)
    s, _ = tr.model_heads(model)
    amplitude = float(model.settings["transfer"]["amplitude"])
    signals, y = _test_split(model)
    _, picker = ev.selection_models(model.models)[0]
    plan = _integration(model, args.substeps)
    rows = []
    with session(None, args.jobs):
        for buffer in ([] if args.no_plain else [None]) + args.buffer:
            first = None
            for eps in args.eps:
                d, loss = _simulated(model.models, s, amplitude, buffer, eps, signals, plan,
                                     args.jobs)
                hits = (picker.predict(d) == y).astype(float)
                first = hits if first is None else first
                rows.append(_accuracy_row(buffer, eps, hits, first, loss, start))
                print(rows[-1], flush=True)
    text = accuracy_table(rows)
    print(text)
    write(args.out, "accuracy", text, {"model": str(args.model), "rows": rows,
                                       "seconds": time.time() - start})


def _integration(model, substeps: int | None):
    """The model's integration, at `substeps` where given (a stiffer buffer than the model's
    step allows)."""
    from springc.kws.evaluation import evaluate as ev

    plan = ev.model_integration(model)
    return replace(plan, substeps=substeps) if substeps else plan


def _test_split(model) -> tuple:
    """The model's test split: its clips' signals and targets."""
    from springc.kws.data.task import open_task_data, targets
    from springc.kws.evaluation import evaluate as ev

    ds = open_task_data(ev.trained_data(model), model.settings["task"],
                        int(model.settings.get("seed", 0)), model.settings.get("protocol"),
                        splits=("test",))
    clips = ds.split("test")
    signals = msp.load_signals(clips, False, 0, [])
    return signals, targets(clips, model.settings["task"])


def _simulated(models, s, amplitude: float, buffer, eps: float, signals, plan, jobs: int):
    """The whole network's readouts and insertion losses on `signals`: the heads of `models`
    designed again at eps for the buffer's amplitude, plain (buffer None) or buffered."""
    from springc.kws.evaluation import evaluate as ev

    heads = tb.rescaled(tr.heads_for(models, s, tb.amplitude(buffer, amplitude), eps), buffer)
    d, loss, _ = ev.simulate_network(classifier(heads, s, eps, buffer), heads, s, signals,
                                     jobs=jobs, plan=plan)
    return d, loss


def _accuracy_row(buffer, eps: float, hits: np.ndarray, first: np.ndarray, loss: np.ndarray,
                  start: float) -> dict:
    """One network and eps (in %): accuracy, its SE, the paired change against the first eps
    and the median insertion loss."""
    return {"buffer": buffer.to_dict() if buffer else None, "eps": eps,
            "accuracy": 100 * float(np.mean(hits)), "se": 100 * se(hits),
            "paired": 100 * float(np.mean(hits - first)),
            "paired_se": 100 * se(hits - first),
            "loss_db": float(np.median(loss)), "n": len(hits),
            "seconds": time.time() - start}


def crossval(args) -> None:
    """A size's network plain and buffered at each eps, cross-validated over speakers."""
    from springc.kws.data.task import open_task_data
    from springc.kws.evaluation import crossval as cv
    from springc.kws.features.distributed import session
    from springc.kws.features.integration import Integration

    start = time.time()
    stiffer_mvms(args.mvm_stiffness)
    clips = open_task_data(args.data, "kws12", 0, "lists").clips
    y = np.array([c.label for c in clips])
    groups = cv.speaker_groups(clips)
    fold = cv.speaker_folds(groups, args.folds)
    plan = Integration(args.method, args.substeps, "float64")
    with session(None, args.jobs):
        outcome = _cv_outcome(args, clips, y, fold, plan, start)
    rows = cv_rows(outcome, y, groups)
    text = cv_table(rows, args)
    print(text)
    name = f"cv-{args.size}-ac{args.threshold:g}"
    write(args.out, name, text, {"data": str(args.data), "size": args.size,
                                 "threshold": args.threshold, "rows": rows,
                                 "mvm_stiffness": args.mvm_stiffness,
                                 "plan": plan.describe(), "seconds": time.time() - start})


def _cv_outcome(args, clips, y: np.ndarray, fold: np.ndarray, plan, start: float) -> dict:
    """Per (network, eps): every fold's held-out clips simulated (indices, whether each was
    right, insertion losses), each fold's SVM trained on the other folds."""
    from springc.kws.data.task import task_weights
    from springc.kws.evaluation import crossval as cv
    from springc.kws.training.svm import SVM_GRID

    weight = task_weights("kws12")
    buffers = ([] if args.no_plain else [None]) + args.buffer
    outcome = {(label(b and b.to_dict()), eps): {"test": [], "ok": [], "loss": []}
               for b in buffers for eps in args.eps}
    s, ref, x = _cv_features(args, clips)
    for k in range(args.folds):
        model, _ = cv.fold_model(x, y, fold, k, SVM_GRID, weight)
        test = np.sort(np.random.default_rng(k).permutation(
            np.flatnonzero(fold == k))[:args.test or None])
        signals = msp.load_signals([clips[i] for i in test], False, 0, [])
        for buffer in buffers:
            for eps in args.eps:
                d, loss = _simulated([(tuple(model.classes), model)], s, ref.amplitude, buffer,
                                     eps, signals, plan, args.jobs)
                name = label(buffer and buffer.to_dict())
                row = outcome[(name, eps)]
                row["test"] += test.tolist()
                row["ok"] += (model.classes[d.argmax(1)] == y[test]).tolist()
                row["loss"] += loss.tolist()
                print(f"fold {k} {name} eps {eps:g}: "
                      f"{np.mean(row['ok'][-len(test):]):.3f}, {np.median(loss):.1f} dB "
                      f"({time.time() - start:.0f} s)", flush=True)
    return outcome


def _cv_features(args, clips) -> tuple:
    """The mass-spring settings of --size at --threshold, its reference run and every clip's
    features (cached)."""
    from springc.kws.features.digital import FeatureSettings
    from springc.kws.training.train import feature_matrices

    bins, delays = (int(v) for v in args.size.split("x"))
    given = replace(msp.physical_settings(FeatureSettings(bins=bins, delays=delays)),
                    threshold=args.threshold)
    s, _, ref = msp.integrated(msp.physical_settings(None, given), clips, 1e-3)
    x = feature_matrices(clips, "cv", "mass-spring", [s], noise_files=[], jobs=args.jobs,
                         use_cache=True)[0]
    return s, ref, x


def cv_rows(outcome: dict, y: np.ndarray, groups: np.ndarray) -> list[dict]:
    """Per network and eps (in %): balanced accuracy, its speaker-bootstrap SE, the paired change
    against the network's first eps (the same draws) and the median insertion loss."""
    from springc.kws.evaluation import crossval as cv

    rows, firsts = [], {}
    for (name, eps), r in outcome.items():
        idx, ok = np.array(r["test"]), np.array(r["ok"], float)
        first = firsts.setdefault(name, ok)
        boot = cv.speaker_bootstrap(y[idx], {"a": ok, "f": first}, groups[idx], resamples=1000)
        acc, acc_first = (100 * cv.balanced_accuracy(y[idx], v) for v in (ok, first))
        rows.append({"network": name, "eps": eps, "clips": len(idx), "accuracy": acc,
                     "se": 100 * float(boot["a"].std()), "paired": acc - acc_first,
                     "paired_se": 100 * float((boot["a"] - boot["f"]).std()),
                     "loss_db": float(np.median(r["loss"]))})
    return rows


def cv_table(rows: list[dict], args) -> str:
    """The cross-validated rows as markdown (accuracies in %)."""
    out = [f"{args.size}, compression threshold A_c {args.threshold:g} m: {args.folds}-fold "
           f"speaker cross-validation, {args.test or 'all'} test clips per fold, whole "
           f"network {args.method} x{args.substeps} float64"
           + (f", mvm stiffness x{args.mvm_stiffness:g}" if args.mvm_stiffness != 1 else "")
           + ":", "",
           "| network | eps | clips | accuracy % | change vs first eps (paired) "
           "| insertion loss dB (median) |", "|---|---|---|---|---|---|"]
    out += [f"| {r['network']} | {r['eps']:g} | {r['clips']} | {r['accuracy']:.1f} +- "
            f"{r['se']:.1f} | {r['paired']:+.1f} +- {r['paired_se']:.1f} | {r['loss_db']:.1f} |"
            for r in rows]
    return "\n".join(out)


def integration_error(args) -> None:
    """The buffered 8x3 classifier at the largest --eps (stand-in heads) on 16 clips of
    CORPUS: the readouts of exp-rk4 x4 (the `cv` step) and of finer steps against RK4 x16,
    in float64, relative to each clip's largest readout."""
    from springc.kws.data.task import open_task_data
    from springc.kws.features.integration import Integration

    stiffer_mvms(args.mvm_stiffness)
    clips = open_task_data(args.data, "kws12", 0, "lists").clips
    signals = msp.load_signals(clips[:400:25], False, 0, [])
    s = msp.MassSpringSettings(bins=8, delays=3)
    buffer = args.buffer[0] if args.buffer else tb.TapBuffer(6e-5, 1e4)
    heads = tb.rescaled(tr.stand_in_heads(s, rows=12), buffer)
    checked = network(heads, s, max(args.eps), buffer)
    specs = [f"final:x(r{k})" for k in range(len(heads))]
    tstop = msp.horizon(s, signals.shape[1] / msp.INPUT_RATE)

    def readouts(method: str, substeps: int) -> np.ndarray:
        red = tr.classifier_batch(signals, checked, specs, tstop,
                                  Integration(method, substeps, "float64"))
        return np.stack([red[k] for k in specs], axis=1)

    ref = readouts("rk4", 16)
    for method, substeps in (("exp-rk4", 4), ("exp-rk4", 8), ("rk4", 8)):
        err = (np.abs(readouts(method, substeps) - ref).max(axis=1)
               / np.abs(ref).max(axis=1))
        print(f"{method} x{substeps} float64 against rk4 x16: readout error max "
              f"{err.max():.2e}, median {np.median(err):.2e} ({len(err)} clips)", flush=True)


def peaks(args) -> None:
    """The spread of the clips' peak terminal displacement over the model's amplitude A."""
    from springc.kws.data.dataset import open_dataset
    from springc.kws.training.model import load_model

    model = load_model(args.model)
    s, _ = tr.model_heads(model)
    amplitude = float(model.settings["transfer"]["amplitude"])
    clips = open_dataset(model.settings["dataset"]["path"]).split("train")
    pick = np.random.default_rng(0).choice(len(clips), args.clips, replace=False)
    ref = msp.reference_run(msp.load_signals([clips[i] for i in pick], False, 0, []), s)
    levels = (5, 25, 50, 75, 90, 95, 99, 100)
    over = np.percentile(ref.peaks, levels) / amplitude
    text = "\n".join(["| percentile | peak / A | (peak / A)^2 |", "|---|---|---|"]
                     + [f"| {p} | {v:.3g} | {v * v:.3g} |" for p, v in zip(levels, over)])
    print(text)
    write(args.out, "peaks", text, {"model": str(args.model), "amplitude": amplitude,
                                    "peaks": ref.peaks.tolist()})


def se(x: np.ndarray) -> float:
    """Standard error of a mean."""
    return float(np.std(x, ddof=1) / np.sqrt(len(x)))


def accuracy_table(rows: list[dict]) -> str:
    """Markdown: one row per network and eps."""
    lines = ["| network | eps | accuracy % | change vs first eps (paired) | "
             "insertion loss dB |", "|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {_network_name(r['buffer'])} | {r['eps']:g} | {r['accuracy']:.1f} +- "
                     f"{r['se']:.1f} | {r['paired']:+.1f} +- {r['paired_se']:.1f} | "
                     f"{r['loss_db']:.1f} |")
    return "\n".join(lines)


def _network_name(buffer: dict | None) -> str:
    """A network's name in the tables: its buffer's springs, or plain."""
    return (f"buffered kb {buffer['kb']:g} kc, kg {buffer['kg']:g} kc" if buffer
            else "plain")


def label(buffer: dict | None) -> str:
    """A network's name in the plot's legend."""
    return f"buffered, kg {buffer['kg']:g} kc" if buffer else "plain"


def plot(args) -> None:
    """Readout distortion (stages.json) and accuracy (accuracy.json) against insertion loss,
    one line per network, eps written at every point."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for ax, name, key, ylabel in ((axes[0], "stages", "readout", "readout distortion"),
                                  (axes[1], "accuracy", "accuracy", "accuracy %")):
        path = args.out / f"{name}.json"
        if not path.exists():
            ax.set_visible(False)
            continue
        rows = json.loads(path.read_text())["rows"]
        for buf in dict.fromkeys(json.dumps(r["buffer"]) for r in rows):
            mine = [r for r in rows if json.dumps(r["buffer"]) == buf]
            ax.plot([r["loss_db"] for r in mine], [r[key] for r in mine], "o-",
                    label=label(json.loads(buf)))
            for r in mine:
                ax.annotate(f"{r['eps']:g}", (r["loss_db"], r[key]), fontsize=8)
        ax.set_xlabel("insertion loss (dB)")
        ax.set_ylabel(ylabel)
        ax.set_yscale("log" if key == "readout" else "linear")
        ax.legend()
    fig.suptitle("8x3 classifier against eps (points labelled by eps)")
    fig.tight_layout()
    fig.savefig(args.out / "results-eps.png", dpi=110)
    print(args.out / "results-eps.png")


def figure8(args) -> None:
    """The paper's Fig. 8e-f from `cv` runs (every cv-*.json under --runs): (e) accuracy
    against insertion loss over eps, per size and network; (f) at eps = 1, the sizes and the
    compression thresholds. Prints both tables and writes the PNG to --png."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = [json.loads(p.read_text()) for d in args.runs for p in sorted(d.glob("cv-*.json"))]
    rows = [dict(r, size=run["size"], threshold=run["threshold"]) for run in runs
            for r in run["rows"]]
    fig, (ax_e, ax_f) = plt.subplots(1, 2, figsize=(11, 4.2))
    _figure8e(ax_e, rows)
    _figure8f(ax_f, rows, plt.get_cmap)
    for ax in (ax_e, ax_f):
        ax.set_xlabel("insertion loss (dB, median)")
        ax.set_ylabel("accuracy % (balanced, speaker-fold CV)")
    ax_e.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(args.png, dpi=100)
    table = ["| size | A_c (m) | network | eps | clips | accuracy % | change vs its first eps "
             "| insertion loss dB |", "|---|---|---|---|---|---|---|---|"]
    table += [f"| {r['size']} | {r['threshold']:g} | {r['network']} | {r['eps']:g} | "
              f"{r['clips']} | {r['accuracy']:.1f} +- {r['se']:.1f} | {r['paired']:+.1f} +- "
              f"{r['paired_se']:.1f} | {r['loss_db']:.1f} |" for r in rows]
    print("\n".join(table))
    print(args.png)


def _figure8e(ax, rows: list[dict]) -> None:
    """Fig. 8e: at the default threshold, accuracy against insertion loss over eps, a line per
    size and network run at more than one eps."""
    sweep = [r for r in rows if r["threshold"] == msp.MassSpringSettings.threshold]
    lines = dict.fromkeys((r["size"], r["network"]) for r in sweep
                          if sum(q["size"] == r["size"] and q["network"] == r["network"]
                                 for q in sweep) > 1)
    for size, name in lines:
        mine = sorted((r for r in sweep if (r["size"], r["network"]) == (size, name)),
                      key=lambda r: r["eps"])
        ax.errorbar([r["loss_db"] for r in mine], [r["accuracy"] for r in mine],
                    [r["se"] for r in mine], fmt="o-", capsize=2, label=f"{size} {name}")
        for r in mine:
            ax.annotate(f"{r['eps']:g}", (r["loss_db"], r["accuracy"]), fontsize=7)
    ax.set_title("(e) eps (points labelled), per size and network")


def _figure8f(ax, rows: list[dict], get_cmap) -> None:
    """Fig. 8f: the buffered networks at eps = 1, a marker per bins, shaded by the compression
    threshold, edged black at 3 delays."""
    at_one = [r for r in rows if r["eps"] == 1.0 and r["network"] != "plain"]
    marker = {4: "o", 6: "^", 8: "s"}
    shades = sorted({r["threshold"] for r in at_one})
    cmap = get_cmap("viridis", max(len(shades), 2))
    for r in at_one:
        bins, delays = (int(v) for v in r["size"].split("x"))
        ax.errorbar(r["loss_db"], r["accuracy"], r["se"], fmt=marker.get(bins, "D"),
                    ms=8, capsize=2, mfc=cmap(shades.index(r["threshold"])),
                    mec="black" if delays == 3 else "0.6", ecolor="0.6")
        ax.annotate(f"{r['size']}, A_c {r['threshold']:g}", (r["loss_db"], r["accuracy"]),
                    fontsize=7)
    ax.set_title("(f) eps = 1, buffered: sizes and compression A_c")


def write(out: Path, name: str, text: str, data: dict) -> None:
    """OUT/NAME.md and OUT/NAME.json."""
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{name}.md").write_text(text + "\n")
    (out / f"{name}.json").write_text(json.dumps(data, indent=2) + "\n")


def _parser() -> argparse.ArgumentParser:
    """The command line: one subcommand per study, the networks' options on four of them."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="what", required=True)
    st = sub.add_parser("stages")
    st.add_argument("--data", type=Path, required=True)
    st.add_argument("--clips", type=int, default=2)
    st.add_argument("--no-plain", action="store_true", help="only the buffered networks")
    acc = sub.add_parser("accuracy")
    acc.add_argument("--model", type=Path, required=True)
    acc.add_argument("-j", "--jobs", type=int, default=2)
    acc.add_argument("--no-plain", action="store_true", help="only the buffered networks")
    acc.add_argument("--substeps", type=int, help="instead of the model's integration's")
    pk = sub.add_parser("peaks")
    pk.add_argument("--model", type=Path, required=True)
    pk.add_argument("--clips", type=int, default=96)
    pk.add_argument("--out", type=Path, default=Path("eps-out"))
    cvp = _cv_parser(sub)
    ie = sub.add_parser("integration")
    ie.add_argument("--data", type=Path, required=True)
    f8 = sub.add_parser("fig8")
    f8.add_argument("--runs", type=Path, nargs="+", required=True, help="cv --out folders")
    f8.add_argument("--png", type=Path, default=Path("results-fig8.png"))
    pl = sub.add_parser("plot")
    pl.add_argument("--out", type=Path, default=Path("eps-out"))
    for p in (st, acc, cvp, ie):
        _network_options(p)
    return ap


def _cv_parser(sub) -> argparse.ArgumentParser:
    """The `cv` subcommand: the corpus, size, threshold, folds and integration."""
    cvp = sub.add_parser("cv")
    cvp.add_argument("--data", type=Path, required=True)
    cvp.add_argument("--size", default="8x3", help="bins x delays")
    cvp.add_argument("--threshold", type=float, default=msp.MassSpringSettings.threshold,
                     help="the compressors' threshold A_c (m; smaller compresses more)")
    cvp.add_argument("--folds", type=int, default=3)
    cvp.add_argument("--test", type=int, default=100, help="test clips per held-out fold (0: all)")
    cvp.add_argument("-j", "--jobs", type=int, default=2)
    cvp.add_argument("--no-plain", action="store_true", help="only the buffered networks")
    cvp.add_argument("--method", default="exp-rk4")
    cvp.add_argument("--substeps", type=int, default=4)
    return cvp


def _network_options(p: argparse.ArgumentParser) -> None:
    """The options of the subcommands that build networks: eps, buffers, mvm stiffness, out."""
    p.add_argument("--eps", type=float, nargs="+", default=[1e-6, 1e-2, 1e-1, 1.0])
    p.add_argument("--buffer", type=parse_buffer, action="append", default=[])
    p.add_argument("--mvm-stiffness", type=float, default=1.0,
                   help="the heads' mvm stiffness d over its default (not the ideal's)")
    p.add_argument("--out", type=Path, default=Path("eps-out"))


def main() -> None:
    args = _parser().parse_args()
    {"stages": stages, "accuracy": accuracy, "peaks": peaks, "cv": crossval,
     "integration": integration_error, "fig8": figure8, "plot": plot}[args.what](args)


if __name__ == "__main__":
    main()
