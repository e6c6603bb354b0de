"""Linear classifiers on fixed feature vectors: the paper's SVM (squared hinge, l2, primal,
one-versus-rest; scikit-learn's LinearSVC / liblinear) and, for the baseline, logistic
regression. With class_weight="balanced" each class's errors are weighted by
n_samples / (n_classes * n_class), so a frequent class (GSCD's `_unknown_`) cannot win by
being frequent. Features are standardised for the optimiser; the stored model is mapped back to
raw feature space so that the physical readout c . Phi + b gives exactly the same decision.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from sklearn.exceptions import ConvergenceWarning
from sklearn.linear_model import LogisticRegression
from sklearn.svm import LinearSVC
from threadpoolctl import threadpool_limits

from springc.errors import DataError

# Regularisation C, chosen on the validation split. Up to 1e4: on the demo corpus (4 x 2,
# speaker-grouped 5-fold cross-validation) both realisations still gained from 100 to 1e4
# (digital 43.5 -> 44.6%, mass-spring 38.5 -> 40.2%; measured).
SVM_GRID = (0.1, 1.0, 10.0, 100.0, 1e3, 1e4)
LOGREG_GRID = (1e-3, 1e-2, 1e-1)


@dataclass
class LinearModel:
    """decision = features @ coef.T + intercept, in raw feature space. Multiclass: one row
    per class, prediction by argmax. Binary: one row, classes[1] where the decision is > 0."""

    coef: np.ndarray  # (rows, N)
    intercept: np.ndarray  # (rows,)
    classes: np.ndarray  # (K,) str

    def decision(self, features: np.ndarray) -> np.ndarray:
        """Readouts, shape (samples, rows)."""
        return np.asarray(features, dtype=np.float64) @ self.coef.T + self.intercept

    def predict(self, features: np.ndarray) -> np.ndarray:
        """Predicted class names."""
        d = self.decision(features)
        if len(self.classes) == 2:
            return self.classes[(d[:, 0] > 0).astype(int)]
        return self.classes[np.argmax(d, axis=1)]


@dataclass(frozen=True)
class Standardiser:
    """z = (x - mean) / scale, fitted on the training split; constant features get scale 1."""

    mean: np.ndarray
    scale: np.ndarray

    @classmethod
    def fit(cls, x: np.ndarray) -> "Standardiser":
        scale = x.std(axis=0)
        return cls(x.mean(axis=0), np.where(scale > 0, scale, 1.0))

    def __call__(self, x: np.ndarray) -> np.ndarray:
        return (x - self.mean) / self.scale

    def to_raw(self, coef: np.ndarray, intercept: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Weights on z -> weights on x: w.z + b = (w/scale).x + (b - (w/scale).mean)."""
        raw = coef / self.scale
        return raw, intercept - raw @ self.mean


CLASS_WEIGHTS = (None, "balanced")


def _estimator(kind: str, c: float, class_weight: str | None = None):
    if class_weight not in CLASS_WEIGHTS:
        raise ValueError(f"unknown class weights {class_weight!r}")
    if kind == "svm":
        # max_iter: liblinear's trust-region Newton needs thousands of iterations at large C
        # on these correlated features; 1000 (sklearn's default) stops early there, which
        # the validation score then judges like any other regularisation
        return LinearSVC(C=c, loss="squared_hinge", penalty="l2", dual=False, max_iter=1000,
                         class_weight=class_weight)
    if kind == "logreg":
        return LogisticRegression(C=c, max_iter=500, class_weight=class_weight)
    raise ValueError(f"unknown classifier kind {kind!r}")


def fit_linear(x: np.ndarray, y: np.ndarray, c: float, kind: str = "svm",
               class_weight: str | None = None) -> LinearModel:
    """Fit one classifier with regularisation `c` on features x (samples, N), labels y;
    `class_weight` None (every sample counts the same) or "balanced" (every class does)."""
    classes = np.unique(y)
    if len(classes) < 2:
        raise DataError("training split", f"needs at least two classes, found {list(classes)}")
    std = Standardiser.fit(x)
    est = _estimator(kind, c, class_weight)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)  # the validation score judges it
        est.fit(std(x), y)
    coef, intercept = std.to_raw(est.coef_, np.atleast_1d(est.intercept_))
    return LinearModel(coef, intercept, est.classes_.astype(str))


def accuracy(model: LinearModel, x: np.ndarray, y: np.ndarray) -> float:
    """Fraction of samples classified correctly."""
    return float(np.mean(model.predict(x) == y))


def select(x_train: np.ndarray, y_train: np.ndarray, x_val: np.ndarray, y_val: np.ndarray,
           kind: str = "svm", grid: tuple[float, ...] = SVM_GRID, jobs: int = 1,
           class_weight: str | None = None, score: Callable = accuracy,
           ) -> tuple[LinearModel, float, dict[float, float]]:
    """Fit one model per C in `grid` (in `jobs` threads: liblinear and lbfgs release the
    GIL), keep the best on the validation split by `score(model, x, y)` (default: accuracy;
    ties: smaller C, the stronger regularisation). `class_weight` as in `fit_linear`.
    Returns (model, C, {C: validation score})."""
    if not grid:
        raise ValueError("empty regularisation grid")
    fit = lambda c: fit_linear(x_train, y_train, c, kind, class_weight)  # noqa: E731
    # one BLAS thread per fit: the grid is the parallelism, and BLAS threads spinning on a
    # busy machine cost many times the CPU time (docs/performance.md#training)
    # warning filters are process-wide: set here too, as fit_linear's own catch_warnings
    # is not thread-safe
    with warnings.catch_warnings(), threadpool_limits(1), \
            ThreadPoolExecutor(max(1, min(jobs, len(grid)))) as pool:
        warnings.simplefilter("ignore", ConvergenceWarning)
        models = list(pool.map(fit, grid))
    scores = {c: score(m, x_val, y_val) for c, m in zip(grid, models)}
    best = max(range(len(grid)), key=lambda i: (scores[grid[i]], -grid[i]))
    return models[best], grid[best], scores
