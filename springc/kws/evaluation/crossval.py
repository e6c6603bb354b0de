"""Speaker-grouped cross-validation of the 12-class keyword spotter, to compare realisations
on the whole corpus rather than on one small test split.

Every clip of the data set (all three split lists, `_silence_` windows included, none
augmented) is classified once, by an SVM trained on the folds that do not hold its speaker;
C is chosen per fold on the next fold (speaker-disjoint too) from the usual grid, and the
SVM refitted on all training folds. Realisations see the same clips in the same folds, so
their difference is paired.

Scores are class-balanced accuracies (the mean of the per-class true-positive rates): what
the accuracy would be on a test set with as many clips of every class, the paper's protocol
(`springc.kws.data.dataset.balanced`). Standard errors come from a bootstrap over speakers
(clips of one voice are not independent; `_silence_` windows count as one group each).

Why: a 136-clip balanced test split gives a difference between two realisations with a
standard error near 4 points, too coarse to judge a 2-point gap; all 1600 clips of the
built-in corpus, each tested once, bring it to about 1.5."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from springc.errors import UsageError
from springc.kws.data.dataset import SILENCE
from springc.kws.features.digital import FeatureSettings
from springc.kws.training.svm import SVM_GRID, fit_linear, select
from springc.kws.data.task import open_task_data, task_weights
from springc.kws.training.train import feature_matrices
from springc.sim.results import atomic_path

REALISATIONS = ("digital", "mass-spring")
RESAMPLES = 2000  # bootstrap draws: the standard error's own relative error ~1.6%


@dataclass
class CVOptions:
    """Everything `springc cv` needs."""

    data: Path
    settings: FeatureSettings = field(default_factory=FeatureSettings)
    realisations: tuple[str, ...] = REALISATIONS
    folds: int = 5
    seed: int = 0
    jobs: int = 0
    use_cache: bool = True
    grid: tuple[float, ...] = SVM_GRID
    massspring: object = None  # MassSpringSettings (default: from `settings`)
    scheduler: str | None = None
    tolerance: float | None = 1e-3  # chooses the integrator (None: the paper's RK4 x8)
    integration: object = None  # what `tolerance` chose, for the report


def speaker_groups(clips: list) -> np.ndarray:
    """Group label per clip: its speaker, or for a `_silence_` window the window itself."""
    return np.array([c.key() if c.label == SILENCE else c.speaker for c in clips])


def speaker_folds(groups: np.ndarray, folds: int) -> np.ndarray:
    """Fold index (0..folds-1) per clip: whole groups, largest first, each into the fold
    holding the fewest clips so far (ties: the lowest index), so folds are nearly equal."""
    names, counts = np.unique(groups, return_counts=True)
    if len(names) < folds:
        raise UsageError(f"{folds} folds need at least {folds} speakers; "
                         f"the data set has {len(names)}", hint="lower --folds")
    size = np.zeros(folds, dtype=int)
    of_group = {}
    for k in np.lexsort((names, -counts)):
        f = int(np.argmin(size))
        of_group[names[k]] = f
        size[f] += counts[k]
    return np.array([of_group[g] for g in groups])


def write_fold_views(data: Path, folds: int, out: Path) -> list[Path]:
    """Per speaker fold k (`speaker_folds` of every word clip of `data`), a GSCD-layout
    folder `out/fold{k}` of links to `data`'s files: its test list fold k, its validation
    list fold k+1, the other folds its training split, the noise folder linked whole. Every
    command that reads a data set (`springc train`, `eval`) then runs one fold of a
    speaker-disjoint cross-validation, its whole network included."""
    from springc.kws.data.dataset import open_dataset

    data = Path(data).resolve()
    clips = [c for c in open_dataset(data).clips if c.label != SILENCE]
    fold = speaker_folds(speaker_groups(clips), folds)
    names = [f"{c.path.parent.name}/{c.path.name}" for c in clips]
    views = []
    for k in range(folds):
        view = Path(out) / f"fold{k}"
        for name in names:
            (view / name).parent.mkdir(parents=True, exist_ok=True)
            if not (view / name).is_symlink():
                (view / name).symlink_to(data / name)
        noise = view / "_background_noise_"
        if not noise.is_symlink():
            noise.symlink_to(data / "_background_noise_")
        for listed, f in (("testing_list.txt", k), ("validation_list.txt", (k + 1) % folds)):
            chosen = [n for n, g in zip(names, fold) if g == f]
            (view / listed).write_text("\n".join(chosen) + "\n")
        views.append(view)
    return views


def balanced_accuracy(y: np.ndarray, correct: np.ndarray, weight: np.ndarray | None = None,
                      classes: np.ndarray | None = None) -> float:
    """Mean over classes of the (weighted) fraction of that class's clips classified right."""
    weight = np.ones(len(y)) if weight is None else weight
    classes = np.unique(y) if classes is None else classes
    rates = []
    for c in classes:
        m = (y == c) & (weight > 0)
        if m.any():
            rates.append(np.sum(weight[m] * correct[m]) / np.sum(weight[m]))
    return float(np.mean(rates))


def speaker_bootstrap(y: np.ndarray, correct: dict[str, np.ndarray], groups: np.ndarray,
                      resamples: int = RESAMPLES, seed: int = 0) -> dict[str, np.ndarray]:
    """Balanced accuracy of each entry of `correct` on `resamples` data sets drawn from the
    speaker groups with replacement (a group drawn twice counts twice). Same draws for every
    entry, so differences between them are paired."""
    names, index = np.unique(groups, return_inverse=True)
    rng = np.random.default_rng(seed)
    classes = np.unique(y)
    out = {k: np.empty(resamples) for k in correct}
    for r in range(resamples):
        weight = np.bincount(rng.integers(0, len(names), len(names)), minlength=len(names))
        w = weight[index].astype(float)
        for k, ok in correct.items():
            out[k][r] = balanced_accuracy(y, ok, w, classes)
    return out


def balanced_score(model, x: np.ndarray, y: np.ndarray) -> float:
    """`balanced_accuracy` of a model on (x, y): the score C is chosen by."""
    return balanced_accuracy(y, model.predict(x) == y)


def fold_model(x: np.ndarray, y: np.ndarray, fold: np.ndarray, k: int,
               grid: tuple[float, ...], class_weight: str | None, jobs: int = 1):
    """The SVM of held-out fold k and its C: C chosen on fold k+1 by balanced accuracy among
    models fitted on the other folds (`svm.select`; ties: the smaller C), then the model
    fitted on every fold but k. `jobs` threads fit the grid."""
    k_folds = int(fold.max()) + 1
    inner, val = (fold != k) & (fold != (k + 1) % k_folds), fold == (k + 1) % k_folds
    _, c, _ = select(x[inner], y[inner], x[val], y[val], "svm", grid, jobs, class_weight,
                     score=balanced_score)
    return fit_linear(x[fold != k], y[fold != k], c, "svm", class_weight), c


def fold_predictions(x: np.ndarray, y: np.ndarray, fold: np.ndarray,
                     grid: tuple[float, ...], class_weight: str | None,
                     jobs: int = 1) -> tuple[np.ndarray, list]:
    """Prediction per clip from the model of its fold (`fold_model`), and the C chosen per
    fold."""
    pred = np.empty(len(y), dtype=object)
    chosen = []
    for k in range(int(fold.max()) + 1):
        model, c = fold_model(x, y, fold, k, grid, class_weight, jobs)
        chosen.append(c)
        pred[fold == k] = model.predict(x[fold == k])
    return pred.astype(str), chosen


def realisation_features(clips: list, realisation: str, opts: CVOptions) -> np.ndarray:
    """Feature matrix (clips, N) of every clip, unaugmented, from the cache where present."""
    settings = opts.settings
    if realisation == "mass-spring":
        from springc.kws.features.massspring import integrated, physical_settings

        settings, opts.integration, _ = integrated(
            physical_settings(opts.settings, opts.massspring), clips, opts.tolerance)
    else:
        settings.validate(16000)
    return feature_matrices(clips, "cv", realisation, [settings], noise_files=[],
                            seed=opts.seed, jobs=opts.jobs, use_cache=opts.use_cache,
                            scheduler=opts.scheduler)[0]


def cross_validate(opts: CVOptions, progress=None) -> dict:
    """Cross-validate each realisation of `opts` on every clip. Returns the report: per
    realisation the balanced and plain accuracy with bootstrap standard errors and the C per
    fold; per realisation after the first, its difference from the first (paired)."""
    if opts.folds < 3:
        raise UsageError(f"--folds must be at least 3 (train, choose C, test); got {opts.folds}")
    for r in opts.realisations:
        if r not in REALISATIONS:
            raise UsageError(f"unknown realisation {r!r}; use one of {REALISATIONS}")
    ds = open_task_data(opts.data, "kws12", opts.seed, "lists")
    clips = ds.clips
    y = np.array([c.label for c in clips])
    groups = speaker_groups(clips)
    fold = speaker_folds(groups, opts.folds)
    correct, chosen = {}, {}
    for r in opts.realisations:
        if progress:
            progress(f"{r}: features of {len(clips)} clips")
        x = realisation_features(clips, r, opts)
        if progress:
            progress(f"{r}: {opts.folds} folds x {len(opts.grid)} C")
        pred, chosen[r] = fold_predictions(x, y, fold, opts.grid, task_weights("kws12"),
                                           opts.jobs or os.cpu_count() or 1)
        correct[r] = pred == y
    return cv_report(y, groups, fold, correct, chosen, opts)


def cv_report(y, groups, fold, correct: dict, chosen: dict, opts: CVOptions) -> dict:
    """The report of `cross_validate` from the per-clip outcomes."""
    boot = speaker_bootstrap(y, correct, groups, seed=opts.seed)
    first = opts.realisations[0]
    classes = np.unique(y)
    report = {"clips": len(y), "speakers": len(np.unique(groups)),
              "folds": opts.folds, "fold_sizes": np.bincount(fold).tolist(),
              "bins": opts.settings.bins, "delays": opts.settings.delays,
              "majority": float(1 / len(classes)), "realisations": {}}
    if opts.integration is not None:
        report["integration"] = opts.integration.to_dict()
    for r, ok in correct.items():
        report["realisations"][r] = {
            "balanced_accuracy": balanced_accuracy(y, ok), "se": float(boot[r].std(ddof=1)),
            "accuracy": float(ok.mean()), "c_per_fold": chosen[r],
            "per_class": {c: float(ok[y == c].mean()) for c in classes}}
        if r != first:
            diff = boot[first] - boot[r]
            report["realisations"][r]["gap"] = {
                "vs": first, "points": 100 * (balanced_accuracy(y, correct[first])
                                              - balanced_accuracy(y, ok)),
                "se": float(100 * diff.std(ddof=1)),
                "ci95": [float(100 * np.quantile(diff, 0.025)),
                         float(100 * np.quantile(diff, 0.975))],
                "disagree": float(np.mean(correct[first] != ok))}
    return report


def summary_lines(report: dict) -> list[str]:
    """The report as lines of text: one per realisation, the gap where there is one."""
    lines = [(f"{report['bins']}x{report['delays']}, {report['clips']} clips, "
             f"{report['speakers']} speakers, {report['folds']} speaker-disjoint folds; "
             f"class-balanced accuracy (chance {100 * report['majority']:.1f}%)")]
    for r, v in report["realisations"].items():
        line = (f"  {r:12s} {100 * v['balanced_accuracy']:5.1f}% +- {100 * v['se']:.1f} "
                f"(plain {100 * v['accuracy']:.1f}%)")
        if "gap" in v:
            g = v["gap"]
            line += (f"; {g['vs']} - {r} = {g['points']:+.1f} +- {g['se']:.1f} points "
                     f"(95% {g['ci95'][0]:+.1f} .. {g['ci95'][1]:+.1f})")
        lines.append(line)
    return lines


def plot(report: dict, path: Path) -> None:
    """Bar chart of the balanced accuracy per realisation with +-1 SE bars."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(report["realisations"])
    acc = [100 * report["realisations"][r]["balanced_accuracy"] for r in names]
    se = [100 * report["realisations"][r]["se"] for r in names]
    fig, ax = plt.subplots(figsize=(4 + len(names), 3.5))
    ax.bar(names, acc, yerr=se, capsize=6, color=["tab:blue", "tab:orange", "tab:green"][
        :len(names)])
    ax.axhline(100 * report["majority"], color="gray", ls=":", label="chance")
    ax.set_ylabel("class-balanced accuracy (%)")
    ax.set_title(f"{report['bins']}x{report['delays']}: {report['folds']}-fold speaker CV, "
                 f"{report['clips']} clips")
    ax.legend(loc="lower right")
    fig.tight_layout()
    with atomic_path(path, ".png") as tmp:
        fig.savefig(tmp, dpi=120, format="png")
    plt.close(fig)


def write(report: dict, out: Path) -> tuple[Path, Path]:
    """cv.json and cv.png in the folder `out` (each written whole or not at all)."""
    out = Path(out)
    with atomic_path(out / "cv.json", ".json") as tmp:
        tmp.write_text(json.dumps(report, indent=1))
    plot(report, out / "cv.png")
    return out / "cv.json", out / "cv.png"

