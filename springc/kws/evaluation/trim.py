"""Trimming a fabricated keyword spotter after fabrication (`springc eval MODEL --mc N
--spread S --trim K`): each device is measured on K labelled clips of the validation split
and only what a finished device can still change is refitted, the gain and the offset with
which each readout's displacement is read (an electrode's bias and a comparator's offset in
a MEMS device: two numbers per decision row). The mechanics stay as fabricated, and the
untrimmed accuracy is always reported beside the trimmed one, on the same test clips.

The fit: decision row r of clip i becomes g_r d_ir + o_r. For each of the model's selection
models (`evaluate.selection_models`: the 12-class model, or each digit pair) the trimmed
rows are the logits of a softmax (a binary model's one row beside a zero logit) times a
free temperature T, which an argmax ignores; the mean cross-entropy over the labelled clips
of the model's classes plus a ridge (g - 1)^2 + o^2 per row keeps a row that the clips say
little about at its nominal reading. The ridge's weight (as many clips as `PRIORS` lists) is
chosen by the held-out cross-entropy over `FOLDS` folds of the labelled clips themselves; its
largest, a million clips, leaves the reading as it was, so a device is trimmed only where its
own clips say that a trim predicts better.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

PRIORS = (1.0, 10.0, 100.0, 1e6)  # the ridge's weights tried, in clips
FOLDS = 4  # folds of the labelled clips that choose it
LOG_T = 8.0  # the temperature's range, e^-8 to e^8 (decisions are of order 1)


@dataclass(frozen=True)
class Trim:
    """Per decision row, the gain and offset it is read with after trimming; per selection
    model, the ridge's weight chosen (in clips)."""

    gain: np.ndarray
    offset: np.ndarray
    priors: tuple[float, ...] = ()

    def apply(self, d: np.ndarray) -> np.ndarray:
        """Trimmed decisions (clips, rows)."""
        return d * self.gain + self.offset


def fit(models: list, d: np.ndarray, y: np.ndarray) -> Trim:
    """The trim of decision rows `d` (clips, rows) from the clips' true classes `y`;
    `models` as `evaluate.selection_models` gives them (each reads its own rows)."""
    gain, offset, priors = np.ones(d.shape[1]), np.zeros(d.shape[1]), []
    for _, model in models:
        rows = np.nonzero(model.coef.any(axis=0))[0]  # the decision rows it reads, in order
        mine = np.isin(y, model.classes)
        if not mine.any():
            continue
        index = {c: k for k, c in enumerate(model.classes)}  # what its argmax names
        labels = np.array([index[c] for c in y[mine]])
        binary = len(model.classes) == 2
        prior = chosen_prior(d[mine][:, rows], labels, binary)
        z = _minimise(d[mine][:, rows], labels, binary, prior)
        gain[rows], offset[rows] = z[:len(rows)], z[len(rows):2 * len(rows)]
        priors.append(prior)
    return Trim(gain, offset, tuple(priors))


def chosen_prior(d: np.ndarray, labels: np.ndarray, binary: bool) -> float:
    """The weight of `PRIORS` whose trims, fitted on all folds of the clips but one, give
    the least cross-entropy on the one left out, summed over the folds (clip k in fold
    k mod `FOLDS`); the first of equals."""
    folds = np.arange(len(d)) % min(FOLDS, len(d))
    scores = []
    for prior in PRIORS:
        total = 0.0
        for f in np.unique(folds):
            fit_on, held = folds != f, folds == f
            z = _minimise(d[fit_on], labels[fit_on], binary, prior)
            total += loss(z, d[held], labels[held], binary, 0.0)[0] * held.sum()
        scores.append(total)
    return PRIORS[int(np.argmin(scores))]


def _minimise(d: np.ndarray, labels: np.ndarray, binary: bool, prior: float) -> np.ndarray:
    """The trim parameters (gains, offsets, log T) of one selection model's rows: L-BFGS
    on `loss` with its gradient, from the untrimmed reading."""
    from scipy.optimize import minimize

    rows = d.shape[1]
    start = np.concatenate([np.ones(rows), np.zeros(rows), [0.0]])
    # T within e^+-LOG_T: on clips that a trim separates, the cross-entropy falls as T grows
    bounds = [(None, None)] * (2 * rows) + [(-LOG_T, LOG_T)]
    return minimize(loss, start, args=(d, labels, binary, prior), jac=True,
                    method="L-BFGS-B", bounds=bounds).x


def loss(z: np.ndarray, d: np.ndarray, labels: np.ndarray, binary: bool,
         prior: float = 1.0) -> tuple[float, np.ndarray]:
    """The ridged mean cross-entropy of trim parameters z = (gains, offsets, log T) on
    decision rows `d` (clips, rows) with true row indices `labels`, and its gradient; the
    ridge weighs like `prior` clips."""
    n, rows = d.shape
    ridge = prior / n
    g, o, t = z[:rows], z[rows:2 * rows], np.exp(z[-1])
    trimmed = d * g + o
    logits = t * (np.column_stack([np.zeros(n), trimmed]) if binary else trimmed)
    logits -= logits.max(axis=1, keepdims=True)
    p = np.exp(logits)
    p /= p.sum(axis=1, keepdims=True)
    value = -np.mean(np.log(p[np.arange(n), labels] + 1e-300))
    p[np.arange(n), labels] -= 1.0
    dl = (p[:, 1:] if binary else p) / n  # d value / d logit of the rows
    grad = np.concatenate([t * (dl * d).sum(0), t * dl.sum(0), [(dl * t * trimmed).sum()]])
    value += ridge * (np.sum((g - 1) ** 2) + np.sum(o ** 2))
    grad[:rows] += 2 * ridge * (g - 1)
    grad[rows:2 * rows] += 2 * ridge * o
    return value, grad


def calibration_setup(setup, model_dir, data, clips: int, protocol: str | None):
    """The setup with `clips` labelled clips of the validation split (spread evenly over it)
    as its signals: what a device is measured on to be trimmed."""
    from springc.kws.evaluation.device import split_signals

    signals, y = split_signals(setup.model, data, clips, protocol, "validation")
    return replace(setup, signals=signals, y=y)


def evaluate_trimmed(setup, cal, devices: int, spread, *, scheduler: str | None = None,
                     jobs: int = 0, progress=None) -> dict:
    """`device.evaluate_spread`'s report, each device (and the nominal design) also trimmed
    on the clips of `cal` (`calibration_setup`) and scored again on the same test clips:
    per device "trimmed" beside "accuracy", and their summaries."""
    from springc.kws.evaluation import device as dv
    from springc.kws.evaluation.evaluate import selection_models

    spread.validate()
    both = replace(setup, signals=np.concatenate([setup.signals, cal.signals]),
                   y=np.concatenate([setup.y, cal.y]))
    n, models = len(setup.y), selection_models(setup.model.models)

    def scored(d: np.ndarray) -> dict:
        """Untrimmed and trimmed accuracy of decisions on `both`'s clips (test, then cal)."""
        t = fit(models, d[n:], cal.y)
        return {"accuracy": dv.accuracy(setup, d[:n]),
                "trimmed": dv.accuracy(setup, t.apply(d[:n])), "priors": list(t.priors)}

    def row(k: int, dk: np.ndarray, nominal: np.ndarray) -> dict:
        return {"device": k, **scored(dk), "diverged": False,
                "decision_error": dv.decision_error(dk[:n], nominal[:n])}

    nominal, rows = dv.population(both, devices, spread, row, scheduler=scheduler, jobs=jobs,
                                  progress=progress)
    rows = [{**r, "trimmed": 0.0} if r["diverged"] else r for r in rows]
    mine = scored(nominal)
    return {"devices": rows, "nominal": mine["accuracy"], "nominal_trimmed": mine["trimmed"],
            "nominal_priors": mine["priors"],
            "accuracy": dv.summary(np.array([r["accuracy"] for r in rows])),
            "trimmed": dv.summary(np.array([r["trimmed"] for r in rows])),
            "n": n, "trim_clips": len(cal.y), "spread": spread.sigma, "kind": spread.kind,
            "stage": spread.stage, "seed": spread.seed}
