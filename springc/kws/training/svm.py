"""Linear classifiers on fixed feature vectors: the paper's SVM (squared hinge, l2, primal,
one-versus-rest, liblinear's objective, solved exactly by `springc.kws.training.hinge`) and, for the
baseline, logistic regression (scikit-learn). With class_weight="balanced" each class's
errors are weighted by n_samples / (n_classes * n_class) (`row_costs`), so a frequent class
(GSCD's `_unknown_`) cannot win by being frequent. Features are standardised for the optimiser; the
stored model is mapped back to raw feature space so that the physical readout c . Phi + b
gives exactly the same decision.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from sklearn.exceptions import ConvergenceWarning
from sklearn.linear_model import LogisticRegression
from threadpoolctl import threadpool_limits

from springc.errors import DataError
from springc.kws.training import hinge

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
    def fit(cls, x: np.ndarray, centre: bool = True) -> "Standardiser":
        """Fitted on x; `centre` False: scaled by the root mean square, mean 0 (a model
        without intercept stays one)."""
        scale = x.std(axis=0) if centre else np.sqrt((x * x).mean(axis=0))
        mean = x.mean(axis=0) if centre else np.zeros(x.shape[1])
        return cls(mean, np.where(scale > 0, scale, 1.0))

    def __call__(self, x: np.ndarray) -> np.ndarray:
        return (x - self.mean) / self.scale

    def to_raw(self, coef: np.ndarray, intercept: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Weights on z -> weights on x: w.z + b = (w/scale).x + (b - (w/scale).mean)."""
        raw = coef / self.scale
        return raw, intercept - raw @ self.mean


CLASS_WEIGHTS = (None, "balanced")


def _check_weights(class_weight: str | None) -> None:
    if class_weight not in CLASS_WEIGHTS:
        raise ValueError(f"unknown class weights {class_weight!r}")


def row_costs(y: np.ndarray, classes: np.ndarray, signs: np.ndarray,
              class_weight: str | None) -> np.ndarray:
    """Each row's per-sample cost over C, as liblinear weighs classes: with "balanced", a
    class's weight n_samples / (n_classes * n_class) on its own samples; one-versus-rest, the
    rest of a row's samples at 1; two classes, every sample at its class's weight."""
    if class_weight is None:
        return np.ones(signs.shape)
    weight = {k: len(y) / (len(classes) * int(np.sum(y == k))) for k in classes}
    per_sample = np.array([weight[k] for k in y])
    if len(classes) == 2:
        return per_sample[None, :]
    return np.where(signs > 0, per_sample[None, :], 1.0)


def fit_linear(x: np.ndarray, y: np.ndarray, c: float, kind: str = "svm",
               class_weight: str | None = None, intercept: bool = True) -> LinearModel:
    """Fit one classifier with regularisation `c` on features x (samples, N), labels y;
    `class_weight` None (every sample counts the same) or "balanced" (every class does);
    `intercept` False (SVM only): decisions linear in x, zero at x = 0."""
    return _fits(x, y, (c,), kind, class_weight, intercept=intercept)[0]


def _fits(x: np.ndarray, y: np.ndarray, grid: tuple[float, ...], kind: str,
          class_weight: str | None, jobs: int = 1, intercept: bool = True) -> list[LinearModel]:
    """One model per C of `grid`, in its order. The SVM's are solved in increasing C, each
    starting from the last one's weights (BLAS on every core); logistic regression fits in
    `jobs` threads (lbfgs releases the GIL), one BLAS thread each."""
    _check_weights(class_weight)
    classes = np.unique(y)
    if len(classes) < 2:
        raise DataError("training split", f"needs at least two classes, found {list(classes)}")
    if not intercept and kind != "svm":
        raise ValueError("only the SVM fits without intercept")
    std = Standardiser.fit(x, centre=intercept)
    z = std(x)
    if kind == "svm":
        rows = classes[1:] if len(classes) == 2 else classes
        signs = np.where(y[None, :] == rows[:, None], 1.0, -1.0)
        weight = row_costs(y, classes, signs, class_weight)
        out, start = {}, None
        for c in sorted(grid):
            coef, icpt = hinge.fit_rows(z, signs, c * weight, start, intercept)
            start = np.hstack([coef, icpt[:, None]])
            out[c] = LinearModel(*std.to_raw(coef, icpt), classes.astype(str))
        return [out[c] for c in grid]
    if kind != "logreg":
        raise ValueError(f"unknown classifier kind {kind!r}")

    def fit(c: float) -> LinearModel:
        est = LogisticRegression(C=c, max_iter=500, class_weight=class_weight)
        est.fit(z, y)
        coef, intercept = std.to_raw(est.coef_, np.atleast_1d(est.intercept_))
        return LinearModel(coef, intercept, est.classes_.astype(str))

    # one BLAS thread per fit: the grid is the parallelism, and BLAS threads spinning on a
    # busy machine cost many times the CPU time (docs/performance.md#training); warning
    # filters are process-wide and catch_warnings is not thread-safe: set once, here
    with warnings.catch_warnings(), threadpool_limits(1), \
            ThreadPoolExecutor(max(1, min(jobs, len(grid)))) as pool:
        warnings.simplefilter("ignore", ConvergenceWarning)  # the validation score judges it
        return list(pool.map(fit, grid))


def accuracy(model: LinearModel, x: np.ndarray, y: np.ndarray) -> float:
    """Fraction of samples classified correctly."""
    return float(np.mean(model.predict(x) == y))


def select(x_train: np.ndarray, y_train: np.ndarray, x_val: np.ndarray, y_val: np.ndarray,
           kind: str = "svm", grid: tuple[float, ...] = SVM_GRID, jobs: int = 1,
           class_weight: str | None = None, score: Callable = accuracy,
           intercept: bool = True) -> tuple[LinearModel, float, dict[float, float]]:
    """Fit one model per C in `grid` (`_fits`: `jobs` threads for logistic regression),
    keep the best on the validation split by `score(model, x, y)` (default: accuracy;
    ties: smaller C, the stronger regularisation). `class_weight`, `intercept` as in
    `fit_linear`.
    Returns (model, C, {C: validation score})."""
    if not grid:
        raise ValueError("empty regularisation grid")
    models = _fits(x_train, y_train, grid, kind, class_weight, jobs, intercept)
    scores = {c: score(m, x_val, y_val) for c, m in zip(grid, models)}
    best = max(range(len(grid)), key=lambda i: (scores[grid[i]], -grid[i]))
    return models[best], grid[best], scores
