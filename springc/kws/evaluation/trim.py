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
of the model's classes plus a ridge (g - 1)^2 + o^2 per row that weighs like one clip keeps
a row that the clips say little about at its nominal reading.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np



@dataclass(frozen=True)
class Trim:
    """Per decision row, the gain and offset it is read with after trimming."""

    gain: np.ndarray
    offset: np.ndarray

    def apply(self, d: np.ndarray) -> np.ndarray:
        """Trimmed decisions (clips, rows)."""
        return d * self.gain + self.offset


def fit(models: list, d: np.ndarray, y: np.ndarray) -> Trim:
    """The trim of decision rows `d` (clips, rows) from the clips' true classes `y`;
    `models` as `evaluate.selection_models` gives them (each reads its own rows)."""
    gain, offset = np.ones(d.shape[1]), np.zeros(d.shape[1])
    for _, model in models:
        rows = np.nonzero(model.coef.any(axis=0))[0]  # the decision rows it reads, in order
        mine = np.isin(y, model.classes)
        if not mine.any():
            continue
        index = {c: k for k, c in enumerate(model.classes)}  # what its argmax names
        labels = np.array([index[c] for c in y[mine]])
        g, o = _fit_rows(d[mine][:, rows], labels, binary=len(model.classes) == 2)
        gain[rows], offset[rows] = g, o
    return Trim(gain, offset)


def _fit_rows(d: np.ndarray, labels: np.ndarray, binary: bool) -> tuple[np.ndarray, np.ndarray]:
    """Gains and offsets of one selection model's rows (L-BFGS on the ridged cross-entropy,
    with its gradient)."""
    from scipy.optimize import minimize

    n, rows = d.shape
    start = np.concatenate([np.ones(rows), np.zeros(rows), [0.0]])
    z = minimize(loss, start, args=(d, labels, binary), jac=True, method="L-BFGS-B").x
    return z[:rows], z[rows:2 * rows]


def loss(z: np.ndarray, d: np.ndarray, labels: np.ndarray,
         binary: bool) -> tuple[float, np.ndarray]:
    """The ridged mean cross-entropy of trim parameters z = (gains, offsets, log T) on
    decision rows `d` (clips, rows) with true row indices `labels`, and its gradient."""
    n, rows = d.shape
    ridge = 1.0 / n  # the prior weighs like one clip
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
    """The setup's model and network with `clips` labelled clips of the validation split
    (spread evenly over it) as its signals: what a device is measured on to be trimmed."""
    from springc.kws.evaluation.device import load_setup

    cal = load_setup(model_dir, data, clips, protocol, split="validation")
    return replace(setup, signals=cal.signals, y=cal.y)


def evaluate_trimmed(setup, cal, devices: int, spread, *, scheduler: str | None = None,
                     jobs: int = 0, progress=None) -> dict:
    """`device.evaluate_spread`'s report, each device (and the nominal design) also trimmed
    on the clips of `cal` (`calibration_setup`) and scored again on the same test clips:
    per device "trimmed" beside "accuracy", and their summaries."""
    import time

    from springc.kws.evaluation import device as dv
    from springc.kws.evaluation.evaluate import selection_models
    from springc.kws.features.distributed import session

    spread.validate()
    both = replace(setup, signals=np.concatenate([setup.signals, cal.signals]),
                   y=np.concatenate([setup.y, cal.y]))
    n, models = len(setup.y), selection_models(setup.model.models)

    def scored(d: np.ndarray) -> tuple[float, float]:
        trimmed = fit(models, d[n:], cal.y).apply(d[:n])
        return dv.accuracy(setup, d[:n]), dv.accuracy(setup, trimmed)

    rows, start = [], time.perf_counter()
    with session(scheduler, jobs or None):
        nominal = dv.outputs(both, both.net, scheduler=scheduler, jobs=jobs,
                             desc="nominal design")["decisions"]
        for first in range(0, devices, dv.DEVICE_GROUP):
            ks = range(first, min(first + dv.DEVICE_GROUP, devices))
            for k, dk in dv.fabricated_decisions(both, ks, spread, scheduler, jobs).items():
                rows.append({**dv.diverged_row(k, dk), "trimmed": 0.0} if isinstance(dk, str) else
                            dict(zip(("accuracy", "trimmed"), scored(dk)), device=k,
                                 diverged=False,
                                 decision_error=dv.decision_error(dk[:n], nominal[:n])))
            if progress:
                progress(dv.progress_line(rows, devices, time.perf_counter() - start))
    untrimmed, trimmed = scored(nominal)
    return {"devices": rows, "nominal": untrimmed, "nominal_trimmed": trimmed,
            "accuracy": dv.summary(np.array([r["accuracy"] for r in rows])),
            "trimmed": dv.summary(np.array([r["trimmed"] for r in rows])),
            "n": n, "trim_clips": len(cal.y), "spread": spread.sigma, "kind": spread.kind,
            "stage": spread.stage, "seed": spread.seed}
