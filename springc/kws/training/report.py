"""Classification reports: a task's models scored on features (`score`), accuracy beside the
majority-class rate, confusion matrix (CSV and PNG), true-positive rate per class (the paper's
Fig. 8c-d), clips per class and split."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from springc.kws.training.svm import LinearModel
from springc.kws.data.task import DIGITS, PAPER_PAIRS


def confusion(y_true: np.ndarray, y_pred: np.ndarray, classes: list[str]) -> np.ndarray:
    """Counts, rows = true class, columns = predicted class, in the order of `classes`."""
    index = {c: i for i, c in enumerate(classes)}
    out = np.zeros((len(classes), len(classes)), dtype=np.int64)
    np.add.at(out, ([index[c] for c in y_true], [index[c] for c in y_pred]), 1)
    return out


def true_positive_rates(conf: np.ndarray) -> np.ndarray:
    """Per class: correct / occurrences (NaN for a class absent from the test split)."""
    totals = conf.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(totals > 0, np.diag(conf) / totals, np.nan)


def majority_rate(conf: np.ndarray) -> float:
    """The accuracy of always answering the most frequent true class: what a classifier
    that learnt nothing scores (1 / classes on balanced splits)."""
    totals = np.asarray(conf).sum(axis=1)
    return float(totals.max() / max(totals.sum(), 1)) if totals.size else 0.0


def summary(y_true: np.ndarray, y_pred: np.ndarray, classes: list[str]) -> dict:
    """{"accuracy", "majority_rate", "n", "per_class": {class: TPR or None},
    "confusion": [[...]], "classes"}."""
    conf = confusion(y_true, y_pred, classes)
    tpr = true_positive_rates(conf)
    return {
        "accuracy": float(np.trace(conf) / max(conf.sum(), 1)),
        "majority_rate": majority_rate(conf),
        "n": int(conf.sum()),
        "per_class": {c: (None if np.isnan(r) else float(r)) for c, r in zip(classes, tpr)},
        "classes": list(classes),
        "confusion": conf.tolist(),
    }


def score(models: list[tuple[tuple[str, ...], LinearModel]], x: np.ndarray, y: np.ndarray,
          task: str) -> dict:
    """The report on features x with true classes y: accuracy, n, per-class true-positive
    rate and confusion matrix; for digit pairs also the accuracy of each pair, where the
    confusion matrix pools every pair's decisions on the clips of its two words."""
    if task == "kws12":
        classes, model = models[0]
        unseen = sorted(set(y.tolist()) - set(classes))  # test labels the model never saw
        return summary(y, model.predict(x), list(classes) + unseen)
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
    out = summary(np.concatenate(truth), np.concatenate(guess), words)
    out["pairs"] = pairs
    return out


def _digit_order(word: str) -> int:
    return DIGITS.index(word) if word in DIGITS else len(DIGITS)


def evaluate_fits(fits: list, x: np.ndarray, y: np.ndarray, task: str) -> dict:
    """`score` for freshly trained fits [(classes, model, C, validation scores)], with the
    validation accuracy per C kept in the report."""
    out = score([(f[0], f[1]) for f in fits], x, y, task)
    out["validation"] = {"-".join(f[0]) if task != "kws12" else "all":
                         {f"{c:g}": s for c, s in f[3].items()} for f in fits}
    return out


def counts_table(counts: dict[str, dict[str, int]]) -> str:
    """Clips per class and split as text: one row per class, one column per split, then the
    totals and the majority-class rate (`counts` as from `Dataset.counts()`)."""
    splits = list(counts)
    labels = list(next(iter(counts.values()), {}))
    width = max(map(len, labels + ["label", "total"]))
    lines = [f"{'label':<{width}}" + "".join(f"{s:>12}" for s in splits)]
    for label in labels:
        lines.append(f"{label:<{width}}" + "".join(f"{counts[s][label]:>12}" for s in splits))
    lines.append(f"{'total':<{width}}" + "".join(f"{sum(counts[s].values()):>12}"
                                                 for s in splits))
    rates = [max(counts[s].values(), default=0) / max(sum(counts[s].values()), 1)
             for s in splits]
    lines.append(f"{'majority':<{width}}" + "".join(f"{100 * r:>11.1f}%" for r in rates))
    return "\n".join(lines)


def write_confusion_csv(path: Path, conf: np.ndarray, classes: list[str]) -> None:
    """Counts with a header row of predicted classes and a first column of true classes."""
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["true\\predicted", *classes])
        for c, row in zip(classes, conf):
            w.writerow([c, *row.tolist()])


def write_per_class_csv(path: Path, conf: np.ndarray, classes: list[str]) -> None:
    """class, test clips, correct, true-positive rate."""
    tpr = true_positive_rates(conf)
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["class", "clips", "correct", "tpr"])
        for c, row, r, k in zip(classes, conf, tpr, range(len(classes))):
            w.writerow([c, int(row.sum()), int(row[k]), "" if np.isnan(r) else f"{r:.4f}"])


def plot_confusion(path: Path, conf: np.ndarray, classes: list[str], title: str) -> None:
    """Row-normalised confusion matrix beside the true-positive rate per class (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = conf.sum(axis=1, keepdims=True)
    norm = np.divide(conf, rows, out=np.zeros(conf.shape), where=rows > 0)
    k = len(classes)
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(6 + 0.45 * k, 0.45 * k + 2),
                                 gridspec_kw={"width_ratios": [k, 3]})
    ax.imshow(norm, cmap="Blues", vmin=0, vmax=1)
    for i, j in np.ndindex(conf.shape):
        if conf[i, j]:
            ax.text(j, i, f"{norm[i, j]:.2f}", ha="center", va="center", fontsize=7,
                    color="white" if norm[i, j] > 0.5 else "black")
    ax.set_xticks(range(k), classes, rotation=60, ha="right")
    ax.set_yticks(range(k), classes)
    ax.set_xlabel("predicted")
    ax.set_ylabel("true")
    ax.set_title(title)
    bx.barh(range(k), np.nan_to_num(np.diag(norm)), color="tab:blue")
    bx.set_ylim(k - 0.5, -0.5)
    bx.set_yticks(range(k), [])
    bx.set_xlim(0, 1)
    bx.set_xlabel("true-positive rate")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
