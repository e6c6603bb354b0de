"""Evaluating a trained keyword spotter on the test split (`testing_list.txt`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from springc.errors import DataError, UsageError
from springc.kws import report as rep
from springc.kws.digital import FeatureSettings
from springc.kws.model import load_model
from springc.kws.svm import LinearModel
from springc.kws.train import (PAPER_PAIRS, check_realisation, feature_matrices,
                               open_task_data, targets)


def score(models: list[tuple[tuple[str, ...], LinearModel]], x: np.ndarray, y: np.ndarray,
          task: str) -> dict:
    """The report on features x with true classes y: accuracy, n, per-class true-positive
    rate and confusion matrix; for digit pairs also the accuracy of each pair, where the
    confusion matrix pools every pair's decisions on the clips of its two words."""
    if task == "kws12":
        classes, model = models[0]
        unseen = sorted(set(y.tolist()) - set(classes))  # test labels the model never saw
        return rep.summary(y, model.predict(x), list(classes) + unseen)
    truth, guess, pairs = [], [], {}
    for classes, model in models:
        mask = np.isin(y, classes)
        pred = model.predict(x[mask])
        truth.append(y[mask])
        guess.append(pred)
        name = "-".join(classes)
        pairs[name] = {"accuracy": float(np.mean(pred == y[mask])), "n": int(mask.sum()),
                       "paper": PAPER_PAIRS.get(tuple(classes))}
    words = sorted({c for cl, _ in models for c in cl}, key=_digit_order)
    out = rep.summary(np.concatenate(truth), np.concatenate(guess), words)
    out["pairs"] = pairs
    return out


def _digit_order(word: str) -> int:
    from springc.kws.train import DIGITS

    return DIGITS.index(word) if word in DIGITS else len(DIGITS)


def evaluate_fits(fits: list, x: np.ndarray, y: np.ndarray, task: str) -> dict:
    """`score` for freshly trained fits [(classes, model, C, validation scores)], with the
    validation accuracy per C kept in the report."""
    out = score([(f[0], f[1]) for f in fits], x, y, task)
    out["validation"] = {"-".join(f[0]) if task != "kws12" else "all":
                         {f"{c:g}": s for c, s in f[3].items()} for f in fits}
    return out


def evaluate(model_dir: Path, data: Path | None = None, realisation: str | None = None,
             jobs: int = 0, use_cache: bool = True, scheduler: str | None = None) -> dict:
    """Evaluate the model in `model_dir` on the test split of `data` (default: the data set
    it was trained on). `realisation` must match the model's (or be omitted)."""
    model = load_model(model_dir)
    trained_with = model.settings["realisation"]
    realisation = realisation or trained_with
    check_realisation(realisation)
    if realisation != trained_with:
        raise UsageError(f"{model_dir} was trained with the {trained_with} realisation; "
                         f"it cannot be evaluated with --realisation {realisation}")
    data = Path(data) if data else trained_data(model)
    task = model.settings["task"]
    ds = open_task_data(data, task, int(model.settings.get("seed", 0)),
                        model.settings.get("protocol"))
    if realisation == "mass-spring":  # simulate the whole classifier network
        from springc.kws.transfer import evaluate_network

        return evaluate_network(model, ds, scheduler=scheduler, jobs=jobs, use_cache=use_cache)
    settings = _feature_settings(model)
    clips = ds.split("test")
    x = feature_matrices(clips, "test", realisation, [settings], noise_files=ds.noise_files,
                         jobs=jobs, use_cache=use_cache)[0]
    return score(model.models, x, targets(clips, task), task)


def trained_data(model) -> Path:
    """The data folder a model was trained on (settings.json); DataError if it names none."""
    path = model.settings.get("dataset", {}).get("path")
    if not path:
        raise DataError(str(model.folder / "settings.json"), "names no data set",
                        hint="pass --data DIR")
    return Path(path)


def _feature_settings(model) -> FeatureSettings:
    feats = {k: v for k, v in model.settings["features"].items() if k != "realisation"}
    if model.settings["realisation"] == "baseline":
        return FeatureSettings()
    try:
        return FeatureSettings(**feats)
    except TypeError as exc:
        raise DataError(str(model.folder / "settings.json"),
                        f"unknown feature settings ({exc})") from None
