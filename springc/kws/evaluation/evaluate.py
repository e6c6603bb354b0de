"""Evaluating a trained keyword spotter on the test split of any labelled folder: its features
through the SVM, or (mass-spring) the whole classifier network simulated.

Only the test split is read: `testing_list.txt` where the folder has one, else every clip of
the folder (a folder of recordings to test on needs no split lists, no training or validation
clips). Words map to classes as the model's task maps them; the held-out protocol is the
model's unless `protocol` says otherwise."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from springc.errors import DataError, UsageError
from springc.kws.features import massspring as msp
from springc.kws.features.digital import FeatureSettings
from springc.kws.features.integration import PAPER, Integration, from_dict
from springc.kws.training.model import load_model
from springc.kws.training.report import score
from springc.kws.training.svm import LinearModel
from springc.kws.data.task import open_task_data, targets
from springc.kws.training.train import check_realisation, feature_matrices
from springc.check import check
from springc.check.checks import CheckedNetlist
from springc.kws.training.transfer import (Head, classifier_batch, decisions, insertion_loss_db,
                                           model_heads, readout_reductions)


def evaluate(model_dir: Path, data: Path | None = None, realisation: str | None = None,
             jobs: int = 0, use_cache: bool = True, scheduler: str | None = None,
             protocol: str | None = None) -> dict:
    """Evaluate the model in `model_dir` on the test split of `data` (default: the data set
    it was trained on) under the held-out `protocol` (default: the model's). `realisation`
    must match the model's (or be omitted)."""
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
                        protocol or model.settings.get("protocol"), splits=("test",))
    if realisation == "mass-spring":  # simulate the whole classifier network
        return evaluate_network(model, ds, scheduler=scheduler, jobs=jobs, use_cache=use_cache)
    settings = _feature_settings(model)
    clips = ds.split("test")
    x = feature_matrices(clips, "test", realisation, [settings], noise_files=ds.noise_files,
                         jobs=jobs, use_cache=use_cache)[0]
    return score(model.models, x, targets(clips, task), task)


def budget_signals(model_dir: Path, data: Path | None, clips: int,
                   protocol: str | None = None) -> np.ndarray:
    """The first `clips` test clips of `data` (default: the model's data set) as the network
    hears them, for `energy.model_budget`: the test split alone is read, as `evaluate` reads
    it. UsageError for a model that is neither mass-spring nor a router."""
    model = load_model(model_dir)
    if model.settings["realisation"] not in ("mass-spring", "router"):
        raise UsageError("the energy budget needs a mass-spring or router model",
                         hint="train one with --realisation mass-spring or router")
    ds = open_task_data(Path(data) if data else trained_data(model), model.settings["task"],
                        int(model.settings.get("seed", 0)),
                        protocol or model.settings.get("protocol"), splits=("test",))
    return msp.load_signals(ds.split("test")[:clips], False, 0, [])


def trained_data(model) -> Path:
    """The data folder a model was trained on (settings.json); DataError if it names none."""
    path = model.settings.get("dataset", {}).get("path")
    if not path:
        raise DataError(str(model.folder / "settings.json"), "names no data set",
                        hint="pass --data DIR")
    return Path(path)


def _feature_settings(model):
    feats = {k: v for k, v in model.settings["features"].items() if k != "realisation"}
    if model.settings["realisation"] == "baseline":
        return FeatureSettings()
    try:
        if model.settings["realisation"] == "router":
            from springc.kws.features.router import RouterSettings

            return RouterSettings(**feats)
        return FeatureSettings(**feats)
    except TypeError as exc:
        raise DataError(str(model.folder / "settings.json"),
                        f"unknown feature settings ({exc})") from None


# -- the whole mass-spring network ---------------------------------------------------------------

def selection_models(models) -> list:
    """Models that read their own rows of the decision matrix (clips, all rows): so the
    physical decisions are scored exactly like the digital ones."""
    total = sum(len(m.coef) for _, m in models)
    out, start = [], 0
    for classes, m in models:
        rows = len(m.coef)
        pick = np.zeros((rows, total))
        pick[:, start:start + rows] = np.eye(rows)
        out.append((classes, LinearModel(pick, np.zeros(rows), m.classes)))
        start += rows
    return out


def simulate_network(net, heads: list[Head], s: msp.MassSpringSettings,
                     signals: np.ndarray, *, scheduler: str | None = None, jobs: int = 0,
                     plan: Integration = PAPER) -> tuple[np.ndarray, np.ndarray, float]:
    """Run clips (clips, samples) through a classifier network (flat, or checked already) on
    Dask, integrated as `plan` says: (row decisions, insertion loss in dB per clip, wall
    seconds)."""
    import time
    from functools import partial

    start = time.perf_counter()
    checked = net if isinstance(net, CheckedNetlist) else check(net)
    fn = partial(classifier_batch, checked=checked, specs=readout_reductions(heads),
                 tstop=msp.horizon(s, signals.shape[1] / msp.INPUT_RATE), plan=plan, s=s)
    reds = msp.map_pooled(fn, signals, "mass-spring classifier", scheduler, jobs or None)
    seconds = time.perf_counter() - start
    return decisions(reds, heads), insertion_loss_db(reds, heads), seconds


def model_integration(model) -> Integration:
    """How the model's classifier network is integrated (settings.json's "transfer")."""
    return from_dict(model.settings["transfer"].get("integration"),
                     str(model.folder / "settings.json"))


def evaluate_network(model, ds, *, scheduler: str | None = None, jobs: int = 0,
                     use_cache: bool = True, heads: list[Head] | None = None,
                     net=None) -> dict:
    """Simulate the model's classifier.spr (front end and every head in one network) on the
    test split: accuracy, confusion, per-class TPR and insertion loss of the physical
    decisions, next to the digital readout c . Phi of the same model on the same features.
    `heads` and `net` replace the model folder's (the epsilon study)."""
    from springc.check.store import checked_file
    from springc.kws.features.distributed import cores, session

    s, model_heads_ = model_heads(model)
    heads = heads or model_heads_
    net = net or checked_file(model.folder / "classifier.spr")  # warm: no parser, no check
    clips = ds.split("test")
    task = model.settings["task"]
    signals = msp.load_signals(clips, False, 0, [])
    plan = model_integration(model)
    with session(scheduler, jobs or None, clips=len(clips)):
        d, loss, seconds = simulate_network(net, heads, s, signals, scheduler=scheduler,
                                            jobs=jobs, plan=plan)
        phi = feature_matrices(clips, "test", "mass-spring", [s], noise_files=[], jobs=jobs,
                               use_cache=use_cache, scheduler=scheduler)[0]
    y = targets(clips, task)
    report = score(selection_models(model.models), d, y, task)
    digital = score(model.models, phi, y, task)
    ideal = np.concatenate([m.decision(phi) for _, m in model.models], axis=1)
    report.update(
        realisation="mass-spring network",
        digital_same_model={k: digital[k] for k in ("accuracy", "n", "per_class", "pairs")
                            if k in digital},
        readout_error=float(np.median(np.abs(d - ideal)) / np.median(np.abs(ideal))),
        insertion_loss_db={"median": float(np.median(loss)), "mean": float(np.mean(loss))},
        throughput={"clips": len(clips), "seconds": seconds,
                    "clips_per_s": len(clips) / seconds,
                    "cores": cores() if scheduler is None else None},
        epsilon=float(model.settings["transfer"]["epsilon"]),
        integration=plan.to_dict())
    return report
