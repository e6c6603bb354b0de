"""The model folder: `settings.json` (all settings), `weights.npz` (raw-Phi coefficients,
intercepts, classes, group index), `report.json`, `confusion.csv`, `confusion.png`,
`per_class.csv`. Written into a temporary sibling folder and renamed into place, so a
failed run never leaves a half-written model."""

from __future__ import annotations

import json
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from springc.errors import DataError
from springc.kws import report as rep
from springc.kws.phi import group_index, n_features
from springc.kws.svm import LinearModel

FILES = ("settings.json", "weights.npz", "report.json")


@dataclass
class TrainedModel:
    """A loaded model folder: its settings and one linear model per classifier (one for the
    12-class task, one per digit pair), each with the classes it separates."""

    folder: Path
    settings: dict
    models: list[tuple[tuple[str, ...], LinearModel]]


def _weights(settings: dict, fits: list) -> dict:
    out = {
        "coef_raw": np.concatenate([f[1].coef for f in fits]),
        "intercept": np.concatenate([f[1].intercept for f in fits]),
        "rows": np.array([len(f[1].coef) for f in fits]),
        "classes": np.array([",".join(f[1].classes) for f in fits]),
    }
    feats = settings["features"]
    if feats["realisation"] == "digital":
        out["group_index"] = group_index(feats["bins"], feats["delays"])
    return out


def write_model(folder: Path, settings: dict, fits: list, report: dict,
                extra: dict[str, str] | None = None) -> None:
    """Write the model folder atomically (replacing an existing one only when complete);
    `extra` maps further file names to their text (the mass-spring classifier netlists)."""
    folder = Path(folder)
    settings = {**settings, "C": _chosen_c(fits)}
    folder.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=folder.parent, prefix=f".{folder.name}.tmp"))
    try:
        (tmp / "settings.json").write_text(json.dumps(settings, indent=2) + "\n")
        np.savez(tmp / "weights.npz", **_weights(settings, fits))
        write_report(tmp, report, title=_title(settings, report))
        for name, text in (extra or {}).items():
            (tmp / name).write_text(text)
        if folder.exists():
            shutil.rmtree(folder)
        tmp.rename(folder)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _chosen_c(fits: list):
    if len(fits) == 1:
        return fits[0][2]
    return {"-".join(f[0]): f[2] for f in fits}


def _title(settings: dict, report: dict) -> str:
    f = settings["features"]
    size = f"{f['bins']}x{f['delays']} {f['filterbank']}" if "bins" in f else "log-Mel"
    return f"{f['realisation']} {size}: accuracy {100 * report['accuracy']:.1f}%"


def write_report(folder: Path, report: dict, title: str) -> None:
    """report.json, confusion.csv, confusion.png and per_class.csv into `folder`."""
    (folder / "report.json").write_text(json.dumps(report, indent=2) + "\n")
    classes, conf = report["classes"], np.array(report["confusion"])
    rep.write_confusion_csv(folder / "confusion.csv", conf, classes)
    rep.write_per_class_csv(folder / "per_class.csv", conf, classes)
    rep.plot_confusion(folder / "confusion.png", conf, classes, title)


def load_model(folder: Path) -> TrainedModel:
    """Read a model folder; DataError naming the file for anything missing or inconsistent."""
    folder = Path(folder)
    if not folder.is_dir():
        raise DataError(str(folder), "no such model folder")
    for name in FILES:
        if not (folder / name).is_file():
            raise DataError(str(folder / name), "missing from the model folder",
                            hint="train again with `springc train ... -o MODEL_DIR`")
    settings = _read_settings(folder / "settings.json")
    try:
        with np.load(folder / "weights.npz") as w:
            arrays = {k: w[k] for k in ("coef_raw", "intercept", "rows", "classes")}
    except (OSError, KeyError, ValueError) as exc:
        raise DataError(str(folder / "weights.npz"), f"unreadable weights ({exc})") from None
    _check_shapes(folder / "weights.npz", settings, arrays)
    return TrainedModel(folder, settings, _split_models(arrays))


def _read_settings(path: Path) -> dict:
    try:
        settings = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise DataError(str(path), f"not valid JSON ({exc})") from None
    for key in ("realisation", "task", "features"):
        if key not in settings:
            raise DataError(str(path), f"has no {key!r} entry")
    return settings


def _check_shapes(path: Path, settings: dict, a: dict) -> None:
    feats = settings["features"]
    rows = int(a["rows"].sum())
    if a["coef_raw"].shape[0] != rows or a["intercept"].shape != (rows,):
        raise DataError(str(path), "coefficient, intercept and class tables disagree")
    if feats.get("realisation") == "digital":
        try:
            expect = n_features(int(feats["bins"]), int(feats["delays"]))
        except (KeyError, TypeError, ValueError):
            raise DataError(str(path.parent / "settings.json"),
                            "features need integer 'bins' and 'delays'") from None
        if a["coef_raw"].shape[1] != expect:
            raise DataError(str(path), f"has {a['coef_raw'].shape[1]} coefficients per class "
                            f"but settings.json says {feats['bins']} bins x {feats['delays']} "
                            f"delays, which need N = {expect}",
                            hint="the model folder mixes files from different trainings")


def _split_models(a: dict) -> list[tuple[tuple[str, ...], LinearModel]]:
    out, start = [], 0
    for rows, classes in zip(a["rows"], a["classes"]):
        names = tuple(str(classes).split(","))
        sl = slice(start, start + int(rows))
        out.append((names, LinearModel(a["coef_raw"][sl], a["intercept"][sl], np.array(names))))
        start += int(rows)
    return out
