"""The two tasks: "kws12" (GSCD's 12 classes, one-versus-rest) and "digits-pairs" (binary SVMs
for the six pairs among one/two/three/four, the task of the paper's Fig. 8b): their clips and
classes, held-out protocol and class weights.

kws12 defaults to the paper's class-balanced held-out splits (`dataset.balanced`) and class
weights inversely proportional to the training counts, so that `_unknown_` (25 of the 35
words) dominates neither the fit nor the score."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from springc.errors import DataError, UsageError

TASKS = ("kws12", "digits-pairs")
REALISATIONS = ("digital", "baseline", "mass-spring", "router")  # how a model computes its features
DIGITS = ("one", "two", "three", "four")
PAPER_PAIRS = {("two", "three"): 0.997}  # the only pair accuracy the paper states in its text


def targets(clips: list, task: str) -> np.ndarray:
    """Class of each clip: the 12-class label, or the spoken word for digits-pairs."""
    return np.array([c.label if task == "kws12" else c.word for c in clips])


def task_protocol(task: str, protocol: str | None = None) -> str:
    """The held-out protocol: `protocol`, or the task's default (kws12: "balanced", the
    paper's; digits-pairs: "lists", its classes are single words of equal share)."""
    if protocol is None:
        return "balanced" if task == "kws12" else "lists"
    if protocol == "balanced" and task != "kws12":
        raise UsageError(f"the balanced protocol is for the kws12 task, not {task}",
                         hint="use --protocol lists")
    return protocol


def task_weights(task: str, balance_weights: bool | None = None) -> str | None:
    """The classifier's class weights: "balanced" or None (equal), by default "balanced"
    for kws12 only."""
    if balance_weights is None:
        balance_weights = task == "kws12"
    return "balanced" if balance_weights else None


def open_task_data(data: Path, task: str, seed: int = 0, protocol: str | None = None,
                   splits: tuple[str, ...] = ("train", "validation", "test")):
    """The data set restricted to what the task uses, under the held-out `protocol`
    (default: the task's, see `task_protocol`). `splits`: those the caller needs (evaluating:
    the test split alone, which a folder without split lists holds entirely); each must
    hold clips of the task, and only they are read and balanced."""
    from springc.kws.data.dataset import open_dataset, with_protocol

    if not Path(data).is_dir():
        raise DataError(str(data), "no such data folder",
                        hint="make one with `springc data synth DIR` or point at GSCD")
    if task not in TASKS:
        raise UsageError(f"unknown task {task!r}; use one of {TASKS}")
    protocol = task_protocol(task, protocol)
    ds = open_dataset(data, seed=seed, splits=splits)
    if task == "digits-pairs":
        ds = ds.subset(words=DIGITS)
    for split in splits:
        if not ds.split(split):
            raise DataError(str(data), f"the {split} split of task {task} holds no clips",
                            hint=_empty_split_hint(Path(data), task, split))
    return with_protocol(ds, protocol, seed, tuple(s for s in splits if s != "train"))


def _empty_split_hint(data: Path, task: str, split: str) -> str | None:
    """Why a split may be empty: the list that defines it, or the words the task reads."""
    from springc.kws.data.dataset import LIST_FILES

    words = f"; {task} reads the words {', '.join(DIGITS)}" if task == "digits-pairs" else ""
    if split == "train":
        return f"training clips are those no split list names{words}"
    if (data / LIST_FILES[split]).is_file():
        return f"{LIST_FILES[split]} names the {split} clips{words}"
    return words[2:] or None


def task_counts(ds, task: str) -> dict[str, dict[str, int]]:
    """{split: {class: clips}}: the 12 classes (all listed), or the words of digits-pairs."""
    if task == "kws12":
        return ds.counts()
    return {s: {w: sum(c.word == w for c in ds.split(s)) for w in DIGITS}
            for s in ("train", "validation", "test")}
