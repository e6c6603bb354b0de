"""The model folder: `settings.json` (all settings), `weights.npz` (raw-Phi coefficients,
intercepts, classes, group index), `report.json`, `confusion.csv`, `confusion.png`,
`per_class.csv`, and `README.md`, which explains the rest to a reader
(`springc.kws.training.readme`). Written into a temporary sibling folder and renamed into place,
so a failed run never leaves a half-written model."""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from springc.version import __version__
from springc.errors import DataError
from springc.kws.training import report as rep
from springc.kws.features.phi import group_index, n_features
from springc.kws.training.readme import readme_text
from springc.kws.training.svm import LinearModel
from springc.kws.data.task import REALISATIONS

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


def check_out_folder(folder: Path) -> None:
    """DataError unless `folder` can take a model: new, empty, or an earlier model folder
    (replaced only when complete). Any other folder is the user's, never deleted."""
    folder = Path(folder)
    parent = folder.parent.absolute()
    if folder.exists() and not folder.is_dir():
        raise DataError(str(folder), "is a file, not a model folder")
    if folder.is_dir() and any(folder.iterdir()) and not (folder / "settings.json").is_file():
        raise DataError(str(folder), "is a folder that holds no model (no settings.json); "
                        "refusing to replace it", hint="give a new folder name")
    existing = next((p for p in (parent, *parent.parents) if p.exists()), None)
    if existing is not None and not existing.is_dir():
        raise DataError(str(folder), f"cannot be written: {existing} is a file, not a folder")
    if existing is not None and not os.access(existing, os.W_OK | os.X_OK):
        raise DataError(str(folder), f"cannot be written: no permission to write in {existing}")


def write_model(folder: Path, settings: dict, fits: list, report: dict,
                extra: dict[str, str] | None = None) -> None:
    """Write the model folder atomically (replacing an existing one only when complete);
    `extra` maps further file names to their text (the mass-spring classifier netlists)."""
    folder = Path(folder)
    check_out_folder(folder)
    settings = {**settings, "C": _chosen_c(fits)}
    folder.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=folder.parent, prefix=f".{folder.name}.tmp"))
    try:
        (tmp / "settings.json").write_text(json.dumps(settings, indent=2) + "\n")
        np.savez(tmp / "weights.npz", **_weights(settings, fits))
        write_report(tmp, report, title=_title(settings, report) if evaluated(report) else "")
        for name, text in (extra or {}).items():
            (tmp / name).write_text(text)
        files = [p.name for p in tmp.iterdir()] + ["README.md"]
        (tmp / "README.md").write_text(readme_text(folder, settings, report, files))
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


def evaluated(report: dict) -> bool:
    """Whether `report` holds test results (`springc tune` may skip the test split)."""
    return "confusion" in report


def _title(settings: dict, report: dict) -> str:
    f = settings["features"]
    from springc.kws.training.readme import size_text

    size = f"{f['bins']}x{f['delays']} {f['filterbank']}" if "delays" in f else size_text(f)
    return f"{f['realisation']} {size}: accuracy {100 * report['accuracy']:.1f}%"


def write_report(folder: Path, report: dict, title: str) -> None:
    """report.json, and for an evaluated report confusion.csv, confusion.png and
    per_class.csv, into `folder`."""
    (folder / "report.json").write_text(json.dumps(report, indent=2) + "\n")
    if not evaluated(report):
        return
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
    arrays = _read_weights(folder / "weights.npz")
    _check_shapes(folder / "weights.npz", settings, arrays)
    return TrainedModel(folder, settings, _split_models(arrays))


def _read_settings(path: Path) -> dict:
    try:
        settings = json.loads(path.read_text())
    except (OSError, ValueError) as exc:  # UnicodeDecodeError is a ValueError
        raise DataError(str(path), f"not valid JSON ({exc})") from None
    if not isinstance(settings, dict):
        raise DataError(str(path), f"holds a JSON {type(settings).__name__}, not an object")
    for key in ("realisation", "task", "features"):
        if key not in settings:
            raise DataError(str(path), f"has no {key!r} entry")
    for key in ("realisation", "task"):
        if not isinstance(settings[key], str):
            raise DataError(str(path), f"{key!r} must be a string, not {settings[key]!r}")
    if settings["realisation"] not in REALISATIONS:
        raise DataError(str(path), f"unknown realisation {settings['realisation']!r}; "
                        f"known: {', '.join(REALISATIONS)}")
    if not isinstance(settings["features"], dict):
        raise DataError(str(path), "'features' must be a JSON object")
    _check_version(path, settings.get("springc_version", __version__))
    return settings


def _version(text: str) -> tuple[int, ...] | None:
    """(major, minor, patch) of a version string like 0.1.0, or None if it is not one."""
    parts = text.split(".") if isinstance(text, str) else []
    if len(parts) != 3 or not all(p.isdigit() for p in parts):
        return None
    return tuple(int(p) for p in parts)


def _check_version(path: Path, written_by) -> None:
    """A model from a newer springc (or a garbled version) may hold what this one cannot
    read; one from an older springc has a subset of today's settings."""
    theirs, ours = _version(written_by), _version(__version__)
    if theirs is None:
        raise DataError(str(path), f"'springc_version' is {written_by!r}, not a version")
    if ours is not None and theirs > ours:
        raise DataError(str(path), f"written by springc {written_by}, newer than this springc "
                        f"{__version__}", hint="evaluate it with the springc that trained it")


def _read_weights(path: Path) -> dict:
    """The weight arrays of weights.npz; DataError naming it if unreadable or incomplete."""
    try:
        with np.load(path, allow_pickle=False) as w:
            arrays = {k: w[k] for k in ("coef_raw", "intercept", "rows", "classes")}
    except KeyError as exc:
        raise DataError(str(path), f"has no array {exc}") from None
    except Exception as exc:  # noqa: BLE001 - zipfile, pickle and numpy raise many types
        raise DataError(str(path), f"unreadable weights ({type(exc).__name__}: {exc})") from None
    kinds = {"coef_raw": (2, "fc"), "intercept": (1, "fc"), "rows": (1, "iu"), "classes": (1, "U")}
    for key, (ndim, kinds_ok) in kinds.items():
        a = arrays[key]
        if a.ndim != ndim or a.dtype.kind not in kinds_ok:
            raise DataError(str(path), f"array {key!r} has shape {a.shape} and type {a.dtype}; "
                            f"expected {ndim} dimension(s) of kind {kinds_ok!r}")
    if (arrays["rows"] < 1).any() or len(arrays["rows"]) != len(arrays["classes"]):
        raise DataError(str(path), "the 'rows' and 'classes' tables disagree")
    if not np.isfinite(arrays["coef_raw"]).all() or not np.isfinite(arrays["intercept"]).all():
        raise DataError(str(path), "holds NaN or infinite weights")
    return arrays


def _check_shapes(path: Path, settings: dict, a: dict) -> None:
    feats = settings["features"]
    rows = int(a["rows"].sum())
    if a["coef_raw"].shape[0] != rows or a["intercept"].shape != (rows,):
        raise DataError(str(path), "coefficient, intercept and class tables disagree")
    for names, n in zip(a["classes"], a["rows"]):
        k = len(str(names).split(","))
        if not (n == k > 2 or n == 1 and k == 2):  # one row per class, or one for a pair
            raise DataError(str(path), f"classes {str(names)!r} do not match their {n} row(s)")
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
