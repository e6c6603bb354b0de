"""A model folder's README.md: what the model was trained on, with which settings, how it
scored, and the commands that reproduce it, so that a folder explains itself.

The training command is rebuilt from settings.json; settings that `springc train` has no
option for (set through `springc.kws.training.train.TrainOptions`) are listed, with their values,
instead of silently dropped from the command. A tuned model (settings.json's "tune") also
gets the `springc tune` line that made it from the trained one."""

from __future__ import annotations

import shlex
from pathlib import Path

import numpy as np

from springc.kws.training.report import counts_table, true_positive_rates

TASKS = {"kws12": "GSCD's 12 classes: the 10 commands, `_unknown_` (every other word) and "
                  "`_silence_` (windows of background noise), one-versus-rest",
         "digits-pairs": "one/two/three/four, a binary classifier per pair (paper Fig. 8b)"}
MODEL_FILES = {
    "README.md": "this page",
    "settings.json": "every setting (what this page is written from)",
    "weights.npz": "raw-Phi coefficients, intercepts, classes",
    "report.json": "the test report in full (confusion matrix, validation scores, timings)",
    "confusion.csv": "test confusion matrix (rows true, columns predicted)",
    "confusion.png": "the same, row-normalised, beside the true-positive rates",
    "per_class.csv": "test clips, correct and true-positive rate per class",
    "features.spr": "the mass-spring feature network",
    "classifier.spr": "the whole classifier network, sound to decision (includes head{k}.spr)",
    "router.spr": "the router network, sound to decision (`springc eval` simulates it)",
}
TUNED = ("filter_scale", "compression_scale")  # feature settings `springc tune` sets


def readme_text(folder: Path, settings: dict, report: dict, files: list[str]) -> str:
    """README.md of the model `folder` from its settings.json and report.json contents;
    `files` names what the folder holds."""
    parts = [_header(settings, report), _data(settings, report), _settings(settings),
             _accuracy(settings, report), _reproduce(folder, settings), _files(files)]
    return "\n\n".join(p.rstrip() for p in parts) + "\n"


def _size(settings: dict) -> str:
    return size_text(settings["features"])


def size_text(features: dict) -> str:
    """The features' size in words: "8 bins x 3 delays", "16 bins" (a router) or the
    log-Mel baseline."""
    if "bins" not in features:
        return "log-Mel baseline"
    delays = f" x {features['delays']} delays" if "delays" in features else ""
    return f"{features['bins']} bins{delays}"


def _header(settings: dict, report: dict) -> str:
    head = (f"# Keyword spotter: {settings['realisation']}, {_size(settings)}\n\n"
            f"{'Tuned' if settings.get('tune') else 'Trained'} by springc "
            f"{settings.get('springc_version', '?')}; ")
    if "accuracy" not in report:
        return head + NOT_EVALUATED
    return head + (f"test accuracy {100 * report['accuracy']:.2f}% on {report['n']} clips "
                   f"(always the most frequent class: {100 * report['majority_rate']:.2f}%).")


NOT_EVALUATED = "not evaluated on the test split (`springc eval` on this folder evaluates it)."


def _data(settings: dict, report: dict) -> str:
    data = settings.get("dataset", {})
    lines = ["## Data", "",
             f"- folder: `{data.get('path', '?')}` (GSCD layout); split fingerprints "
             + ", ".join(f"{s} `{fp}`" for s, fp in data.get("fingerprint", {}).items()),
             f"- task `{settings['task']}`: {TASKS.get(settings['task'], '')}",
             f"- held-out protocol `{settings.get('protocol')}`, class weights "
             f"`{settings.get('class_weight') or 'equal'}`, seed {settings.get('seed', 0)}"]
    if "counts" in report:
        lines += ["", "Clips per class and split:", "", "```",
                  counts_table(report["counts"]), "```"]
    return "\n".join(lines)


def _settings(settings: dict) -> str:
    from springc.kws.features.integration import from_dict

    f = {k: v for k, v in settings["features"].items() if k != "realisation"}
    lines = ["## Settings", "", f"- classifier: {settings.get('classifier')}, C = "
             f"{settings.get('C')} (chosen on the validation split)",
             "- features: " + ", ".join(f"{k} {v}" for k, v in f.items())]
    feats = settings.get("integration", {}).get("features")
    if feats:
        lines.append(f"- feature network integrated by {from_dict(feats).describe()}")
    transfer = settings.get("transfer")
    if transfer:
        lines.append(f"- classifier network: {len(transfer['heads'])} heads, squaring error "
                     f"eps {transfer['epsilon']:g}, feature amplitude "
                     f"{transfer['amplitude']:.4g} m, integrated by "
                     f"{from_dict(transfer.get('integration')).describe()}")
    tune = settings.get("tune")
    if tune:
        devices = (f", the loss over {tune['devices']} devices at a relative spread of "
                   f"{tune['spread']:g}" if tune.get("devices") else "")
        lines.append(f"- tuned by `springc tune` from `{tune['from']}`: {', '.join(tune['params'])}"
                     f" at {tune['integration']}{devices}, {tune_history_text(tune)}; the "
                     "factors are transfer's couplings and intercepts and the features' "
                     "filter_scale and compression_scale")
    refit = (transfer or {}).get("refit")
    if refit:
        lines.append(f"- heads refitted first on the transferred network's exact response "
                     f"({refit['clips']} training clips, C {refit['C']:g}; transfer's refit "
                     "holds the weights)")
    return "\n".join(lines)


def tune_history_text(tune: dict) -> str:
    """A tune run (settings.json's `tune`) in a line: training loss per epoch, validation
    loss per epoch from the start, and the epoch kept."""
    history = tune["history"]
    train = [h["train_loss"] for h in history if "train_loss" in h]
    text = ("training loss per epoch " + " -> ".join(f"{v:.4f}" for v in train) if train
            else "no gradient epochs")
    val = [h["validation_loss"] for h in history if "validation_loss" in h]
    if val:
        text += ("; validation loss from the start " + " -> ".join(f"{v:.4f}" for v in val)
                 + f"; kept epoch {tune['chosen_epoch']}")
    return text


def _accuracy(settings: dict, report: dict) -> str:
    lines = ["## Accuracy on the test split", ""]
    if "confusion" not in report:
        return "\n".join(lines + [NOT_EVALUATED[0].upper() + NOT_EVALUATED[1:]])
    classes, conf = report["classes"], np.array(report["confusion"])
    tpr = true_positive_rates(conf)
    if settings.get("tune"):
        lines += ["The whole tuned classifier network simulated, sound to decision, as "
                  "`springc eval` does.", ""]
    elif settings["realisation"] == "mass-spring":
        lines += ["The SVM on the simulated feature network's Phi (the ideal readout c . Phi); "
                  "`springc eval` simulates the whole classifier network, sound to decision.",
                  ""]
    elif settings["realisation"] == "router":
        lines += ["The SVM on the filters' simulated energies D (the router's readouts "
                  "W . D); `springc eval` simulates the router network, sound to decision.",
                  ""]
    lines += ["| class | test clips | correct | true-positive rate |", "|---|---|---|---|"]
    for k, c in enumerate(classes):
        rate = "n/a" if np.isnan(tpr[k]) else f"{100 * tpr[k]:.1f}%"
        lines.append(f"| `{c}` | {int(conf[k].sum())} | {int(conf[k, k])} | {rate} |")
    lines.append(f"| **all** | {report['n']} | {int(np.trace(conf))} | "
                 f"**{100 * report['accuracy']:.2f}%** |")
    for name, r in report.get("pairs", {}).items():
        lines.append(f"\nPair {name}: {100 * r['accuracy']:.1f}% of {r['n']}")
    for name, scores in report.get("validation", {}).items():
        lines.append("\nValidation accuracy by C" + ("" if name == "all" else f" ({name})")
                     + ": " + ", ".join(f"{c}: {100 * v:.1f}%" for c, v in scores.items()))
    return "\n".join(lines)


def _reproduce(folder: Path, settings: dict) -> str:
    data = settings.get("dataset", {}).get("path", "DATA")
    model = shlex.quote(str(folder))
    args, missing = train_arguments(settings)
    tune = settings.get("tune")
    trained = shlex.quote(tune["from"]) if tune else model
    lines = ["## Reproduce", "", "```sh",
             "springc train --data " + shlex.quote(data) + " " + " ".join(args)
             + f" -o {trained}"]
    if tune:
        missing = {k: v for k, v in missing.items() if k not in TUNED}
        data_opt = f"--data {shlex.quote(tune['data'])} " if tune.get("data") else ""
        lines.append(f"springc tune {trained} {data_opt}-o {model} "
                     f"--params {','.join(tune['params'])} "
                     f"--epochs {tune['epochs']} --batch {tune['batch']} --clips "
                     f"{tune['clips']} --val-clips {tune.get('val_clips', 0)} "
                     f"--lr {tune['lr']:g} --il-weight {tune['il_weight']:g} "
                     f"--seed {tune['seed']}"
                     + (f" --mc {tune['devices']} --spread {tune['spread']:g}"
                        if tune.get("devices") else "")
                     + (f" --refit-clips {tune.get('refit_clips', 0)}" if tune.get("refit")
                        else " --no-refit"))
    lines += [f"springc eval {model} --data {shlex.quote(data)}   # this page's test split",
              f"springc eval {model} --data OTHER_FOLDER   # any labelled folder; no split "
              "lists: every clip is a test clip",
              f"springc classify {model} RECORDING.wav   # label and scores of one clip",
              f"springc classify {model} LONG.wav --stream --plots PLOTS   # keywords through "
              "a long recording", "```"]
    if missing:
        lines += ["", "Settings `springc train` has no option for (set through "
                  "`springc.kws.training.train.TrainOptions`): "
                  + ", ".join(f"{k} = {v!r}" for k, v in missing.items()) + "."]
    return "\n".join(lines)


def train_arguments(settings: dict) -> tuple[list[str], dict]:
    """(`springc train` options that give these settings, the settings no option gives)."""
    from springc.kws.features.digital import FeatureSettings

    f = dict(settings["features"])
    realisation = settings["realisation"]
    scale = settings.get("device")  # a device or router model's physical scale
    named = "device" if scale and realisation == "mass-spring" else realisation
    args = ["--realisation", named, "--task", settings["task"],
            "--protocol", str(settings.get("protocol")), "--class-weights",
            "balanced" if settings.get("class_weight") else "none",
            "--seed", str(settings.get("seed", 0))]
    if scale:
        args += ["--spl", f"{scale['spl']:g}", "--area", f"{scale['area']:g}",
                 "--temp", f"{scale['temp']:g}", "--device-mass", f"{scale['device_mass']:g}"]
    if realisation == "baseline":
        return args, {}
    if realisation == "router":
        from springc.kws.features.router import RouterSettings

        args += ["-n", str(f["bins"])]
        return args, _differences(f, RouterSettings(bins=f["bins"]).to_dict())
    size = {"bins": f["bins"], "delays": f["delays"], "td": f["td"], "tau": f["tau"],
            "fc": f["fc"]}
    args += ["-n", str(f["bins"]), "-m", str(f["delays"]), "--td", f"{f['td']:g}",
             "--tau", f"{f['tau']:g}", "--fc", f"{f['fc']:g}"]
    if realisation == "digital":
        args += ["--filterbank", f["filterbank"], "--feature-rate", f"{f['feature_rate']:g}"]
        given = FeatureSettings(**size, filterbank=f["filterbank"],
                                feature_rate=f["feature_rate"]).to_dict()
        return args, _differences(f, given)
    return _massspring_arguments(settings, f, size, args)


def _massspring_arguments(settings: dict, f: dict, size: dict,
                          args: list[str]) -> tuple[list[str], dict]:
    """The mass-spring options: threshold, squarer range, stage stiffness, epsilon, and how
    the integration was set."""
    from springc.kws.features.massspring import SQUARER_RANGE, from_features, stage_scaled
    from springc.kws.features.digital import FeatureSettings

    squarer_range = f.get("squarer_range", SQUARER_RANGE)
    given = from_features(FeatureSettings(**size), threshold=f["threshold"],
                          squarer_range=squarer_range)
    # `stage_scaled` multiplies klp, g, kq and kc alike; other changes are named
    ratios = [f[name] / getattr(given, name) for name in ("klp", "g", "kq", "kc")]
    factor = ratios[0] if max(ratios) - min(ratios) <= 1e-12 * ratios[0] else 1.0
    args += ["--threshold", f"{f['threshold']:g}"]
    if squarer_range != SQUARER_RANGE:
        args += ["--squarer-range", f"{squarer_range:g}"]
    if factor != 1:
        args += ["--stage-stiffness", f"{factor:g}"]
        given = stage_scaled(given, factor)
    args += ["--epsilon", f"{settings['transfer']['epsilon']:g}"]
    heads, unsaid = _design_arguments(settings)
    args += heads
    tolerance = settings.get("integration", {}).get("features", {}).get("tolerance")
    args += ["--paper-steps"] if tolerance is None else ["--tolerance", f"{tolerance:g}"]
    chosen = ("method", "substeps")  # chosen by the integration, not given
    rest = {k: v for k, v in _differences(f, given.to_dict()).items() if k not in chosen}
    return args, {**rest, **unsaid}


def _design_arguments(settings: dict) -> tuple[list[str], dict]:
    """(the head options that rebuild the recorded design where `train` would not choose it
    by itself (a device model: summing heads; else `transfer.default_design` of the
    epsilon), {"design": ...} where no option gives it: unbuffered zero-mode heads at an
    epsilon whose default is buffered)."""
    from springc.kws.training import transfer

    t = settings["transfer"]
    design = transfer.Design.from_dict(t.get("design"))
    default = (transfer.Design("summing") if settings.get("device")
               else transfer.default_design(float(t["epsilon"])))
    if "design" not in t or design == default:
        return [], {}
    if design.heads == "summing":
        return ["--heads", "summing"], {}
    if design.buffer is None and default.buffer is not None:
        return [], {"design": t["design"]}
    args = ["--heads", "zero-mode", "--mvm-stiffness", f"{design.mvm_stiffness:g}"]
    if design.buffer is not None:
        args += ["--buffer", f"{design.buffer.kb:g}", f"{design.buffer.kg:g}"]
    return args, {}


def _differences(stored: dict, given: dict) -> dict:
    """Entries of `stored` (other than the realisation) that `given` lacks or differs in."""
    return {k: v for k, v in stored.items()
            if k != "realisation" and given.get(k, object()) != v}


def _files(files: list[str]) -> str:
    lines = ["## Files", ""]
    for name in sorted(files):
        what = MODEL_FILES.get(name)
        if what is None and name.startswith("head"):
            what = "one classifier head: its mvm, quadratic couplings and readout"
        lines.append(f"- `{name}`: {what or 'see settings.json'}")
    return "\n".join(lines)
