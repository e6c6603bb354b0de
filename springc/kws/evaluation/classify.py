"""What a trained model hears in recordings (`springc classify`): per file, the predicted
label and every class's score, the same decision values `evaluate` scores.

A recording is read and converted as the data sets' clips are (first channel, 16 kHz), cut or
zero-padded to one clip and pre-processed as in training (`dataset.load_clip`). The digital
and baseline models score their features; a mass-spring model's whole classifier network
(`classifier.spr`: front end and heads) is simulated and its readouts are the decisions, as
`evaluate_network` does. Scores are the rows' decision values c . Phi + b: one per class for
a multiclass model, +-d for the two classes of a binary one; a digit-pairs model adds, for
each word, its margins over the pairs it is in (positive: in its favour), and answers the
word that wins most pairs (one-versus-one voting; ties to the larger margin).
"""

from __future__ import annotations

from collections.abc import Sequence
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from springc.errors import DataError, UsageError
from springc.kws.data.dataset import (CLIP_SAMPLES, NOISE_FOLDER, SAMPLE_RATE, fit_length,
                                      inspect_audio, read_converted, warn)
from springc.kws.training.model import TrainedModel, load_model
from springc.kws.data.preprocess import preprocess
from springc.sim.audio import AUDIO_SUFFIXES

CLIP_SECONDS = CLIP_SAMPLES / SAMPLE_RATE
FILES_AT_ONCE = 256  # clips read and scored together: 33 MB of signal, many batches of 16


@dataclass(frozen=True)
class Recording:
    """A sound file as the models hear it: float64 mono at SAMPLE_RATE, whole."""

    path: Path
    signal: np.ndarray

    @property
    def seconds(self) -> float:
        return len(self.signal) / SAMPLE_RATE


# -- inputs -------------------------------------------------------------------------------------


def sound_files(inputs: Sequence[Path]) -> list[Path]:
    """The files named and the sound files under the folders named (sorted, hidden files and
    `_background_noise_` left out). DataError for a missing path, a named file that is not a
    sound file, a folder holding none, or a file whose header (or float samples) shows it
    cannot be used (`dataset.inspect_audio`)."""
    if not inputs:
        raise UsageError("no input: give sound files or folders")
    out = []
    for path in map(Path, inputs):
        if path.is_dir():
            found = _under(path)
            if not found:
                raise DataError(str(path), "holds no sound file "
                                f"({', '.join(AUDIO_SUFFIXES)})")
            out += found
        elif not path.exists():
            raise DataError(str(path), "no such file or folder")
        elif path.suffix.lower() not in AUDIO_SUFFIXES:
            raise DataError(str(path), f"not a sound file ({', '.join(AUDIO_SUFFIXES)})")
        else:
            out.append(path)
    for path in out:  # every header before any work: a bad last file fails at once
        reason, _ = inspect_audio(path)
        if reason:
            raise DataError(str(path), reason)
    return out


def _under(folder: Path) -> list[Path]:
    """Sound files anywhere under `folder`, in sorted order."""
    def kept(p: Path) -> bool:
        parts = p.relative_to(folder).parts
        return (p.suffix.lower() in AUDIO_SUFFIXES and p.is_file()
                and not any(x.startswith(".") or x == NOISE_FOLDER for x in parts))

    return sorted(p for p in folder.rglob("*") if kept(p))


def read_recordings(inputs: Sequence[Path]) -> list[Recording]:
    """Every sound file of `inputs` read and checked (a bad file is a DataError naming it)."""
    return [Recording(path, read_converted(path)) for path in sound_files(inputs)]


def clip_signal(recording: Recording) -> np.ndarray:
    """The one-clip signal of a recording, as `dataset.load_clip` makes a word clip's: cut or
    padded to 1 s (a longer recording is warned: `--stream` hears all of it), then the
    paper's pre-processing."""
    if len(recording.signal) > CLIP_SAMPLES:
        warn(f"{recording.path}: {recording.seconds:.2f} s long; its first "
             f"{CLIP_SECONDS:g} s is classified (--stream runs over the whole recording)")
    return preprocess(fit_length(recording.signal), SAMPLE_RATE)


# -- decisions ----------------------------------------------------------------------------------


def model_for(model_dir: Path, realisation: str | None, verb: str = "classified") -> TrainedModel:
    """The model folder's model; UsageError if `realisation` is given and not the model's."""
    model = load_model(model_dir)
    trained_with = model.settings["realisation"]
    if realisation not in (None, trained_with):
        raise UsageError(f"{model_dir} was trained with the {trained_with} realisation; it "
                         f"cannot be {verb} with --realisation {realisation}")
    return model


def feature_settings(model: TrainedModel):
    """The settings of the model's features: digital FeatureSettings or MassSpringSettings."""
    if model.settings["realisation"] == "mass-spring":
        from springc.kws.training.transfer import model_heads

        return model_heads(model)[0]
    from springc.kws.evaluation.evaluate import _feature_settings

    return _feature_settings(model)


def feature_rows(model: TrainedModel, signals: np.ndarray) -> np.ndarray:
    """Decision rows (clips, rows) of a digital or baseline model on pre-processed clips
    (clips, samples): its features, computed as training computes them, through its models."""
    if model.settings["realisation"] == "baseline":
        from springc.kws.features.baseline import baseline_features

        x = baseline_features(signals, SAMPLE_RATE).astype(np.float32)
    else:
        from springc.kws.features.digital import features
        from springc.kws.features.phi import phi_vector

        settings = feature_settings(model)
        x = phi_vector(features(signals, SAMPLE_RATE, settings), settings)
    return np.concatenate([m.decision(x) for _, m in model.models], axis=1)


def network_rows(model: TrainedModel, signals: np.ndarray, jobs: int = 0,
                 scheduler: str | None = None) -> np.ndarray:
    """Decision rows (clips, rows) of a mass-spring model: its whole classifier network
    simulated on the clips (float32 input, as the data sets' clips), integrated as
    settings.json says."""
    from springc.check.store import checked_file
    from springc.kws.evaluation.evaluate import model_integration, simulate_network
    from springc.kws.training.transfer import model_heads

    s, heads = model_heads(model)
    net = checked_file(model.folder / "classifier.spr")
    d, _, _ = simulate_network(net, heads, s, signals.astype(np.float32), scheduler=scheduler,
                               jobs=jobs, plan=model_integration(model))
    return d


def decision_rows(model: TrainedModel, signals: np.ndarray, jobs: int = 0,
                  scheduler: str | None = None) -> np.ndarray:
    """Decision rows (clips, rows) of any model on pre-processed clips."""
    if _simulated(model):
        return network_rows(model, signals, jobs, scheduler)
    return feature_rows(model, signals)


def row_names(model: TrainedModel) -> list[str]:
    """One name per decision row: the class (multiclass) or the pair `a-b` (binary: positive
    for b)."""
    names = []
    for classes, m in model.models:
        names += list(classes) if len(m.coef) > 1 else ["-".join(classes)]
    return names


def class_scores(model: TrainedModel, rows: np.ndarray) -> tuple[str, dict[str, float]]:
    """(label, {class: score}) for one clip's decision rows (see the module docstring)."""
    if len(model.models) == 1:
        classes, m = model.models[0]
        if len(m.coef) > 1:
            return classes[int(np.argmax(rows))], dict(zip(classes, map(float, rows)))
        d = float(rows[0])
        return classes[int(d > 0)], {classes[0]: -d, classes[1]: d}
    return _pair_vote(model, rows)


def _pair_vote(model: TrainedModel, rows: np.ndarray) -> tuple[str, dict[str, float]]:
    """One-versus-one voting of binary models: the word winning most pairs, ties to the
    larger summed margin; the scores are those margins."""
    margin: dict[str, float] = {}
    wins: dict[str, int] = {}
    for (classes, _), d in zip(model.models, rows):
        lo, hi = classes
        for word, signed in ((lo, -d), (hi, d)):
            margin[word] = margin.get(word, 0.0) + float(signed)
            wins[word] = wins.get(word, 0) + int(signed > 0)
    label = max(margin, key=lambda w: (wins[w], margin[w]))
    return label, margin


def classify(model_dir: Path, inputs: Sequence[Path], realisation: str | None = None,
             jobs: int = 0, scheduler: str | None = None) -> list[dict]:
    """[{"file", "label", "scores": {class: value}}] for every sound file of `inputs`
    (files or folders), one clip each; digit-pairs models add "pairs": {pair: decision}.
    Files are read FILES_AT_ONCE at a time (a GSCD folder would not fit in memory)."""
    from springc.kws.features.distributed import session

    model = model_for(model_dir, realisation)
    paths = sound_files(inputs)
    out = []
    with session(scheduler, jobs or None, clips=len(paths)) if _simulated(model) \
            else nullcontext():
        for k in range(0, len(paths), FILES_AT_ONCE):
            recordings = read_recordings(paths[k:k + FILES_AT_ONCE])
            signals = np.stack([clip_signal(r) for r in recordings])
            rows = decision_rows(model, signals, jobs, scheduler)
            out += [_result(model, rec, r) for rec, r in zip(recordings, rows)]
    return out


def _simulated(model: TrainedModel) -> bool:
    return model.settings["realisation"] == "mass-spring"


def _result(model: TrainedModel, rec: Recording, rows: np.ndarray) -> dict:
    """One file's entry of `classify`."""
    label, scores = class_scores(model, rows)
    item = {"file": str(rec.path), "label": label, "scores": scores}
    if len(model.models) > 1:
        item["pairs"] = dict(zip(row_names(model), map(float, rows)))
    return item
