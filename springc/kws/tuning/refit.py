"""The heads' weights refitted on the network's exact response: `springc tune`'s first stage.

A head's readout integrates sum_e gamma_e y_e(t)^2 (y_e: the zero modes of its mvm, the
eigen-components of C) through the leaky kernel of its slow pole, so its decision
x_r / scale + b is sum_e lambda_e J_e + b with J_e = int exp(-(T-t)/tau) y_e^2 dt. The
transfer assumes perfect squaring (J_e the integral of (q_e . phi)^2); at a large squaring
error the couplings' cubic stiffness distorts the zero modes and J_e is something else. That
stiffness is 2 gamma_e / alpha_e = 2 eps kc / A^2 for every coupling whatever the weights
(`transfer.couplings_for`), so the J_e of the transferred network are the exact response of
every network with the same eigenvectors and other weights (measured: J moves by 2e-6
relative when the weights change, 4x2 at eps 1e-2). The refit fits those weights and the
intercepts on J like train's SVM (each row against the rest, class weights as trained, C on
the validation clips) and the heads are designed for them as the transfer designs its own
(`transfer.reweighted_heads`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import numpy as np

from springc.check import check
from springc.errors import DataError
from springc.kws.features import massspring as msp
from springc.kws.training import transfer as tr
from springc.kws.features.integration import Integration
from springc.kws.training.svm import SVM_GRID, fit_linear
from springc.sim.reductions import gram_reduction

J = "J"  # the reduction's label


@dataclass
class Response:
    """What one pass of clips through a classifier network gives: the row decisions, the
    insertion loss (dB) and J (clips, coupled components of every head, in head order)."""

    decisions: np.ndarray
    loss_db: np.ndarray
    j: np.ndarray


def zero_modes(net, heads: list[tr.Head]) -> list[int]:
    """Node index of every head's coupled zero modes (its mvm's outputs), in head order."""
    names = list(net.masses.names)
    return [int(net.masses.node[names.index(f"Xh{k}.Xm.Mout{e}")])
            for k, h in enumerate(heads) for e in h.keep]


def response(net, heads: list[tr.Head], s: msp.MassSpringSettings, signals: np.ndarray,
             plan: Integration, scheduler: str | None = None, jobs: int = 0) -> Response:
    """Simulate clips (clips, samples) through the classifier network `net` (front end and
    heads) as `plan` says, on Dask: decisions, insertion loss and J."""
    nodes = zero_modes(net, heads)
    red = gram_reduction(net, tr.TAU_READOUT, nodes, nodes, range(len(nodes)), label=J)
    fn = partial(tr.classifier_batch, checked=check(net),
                 specs=tr.readout_reductions(heads) + [red],
                 tstop=msp.horizon(s, signals.shape[1] / msp.INPUT_RATE), plan=plan, s=s)
    reds = msp.map_pooled(fn, signals, "exact head response", scheduler, jobs or None)
    return Response(tr.decisions(reds, heads), tr.insertion_loss_db(reds, heads), reds[J])


@dataclass
class Refit:
    """The refitted weights (per head, its coupled components) and intercepts, the C chosen
    and the validation accuracy of each C of the grid."""

    weights: list[np.ndarray]
    intercepts: list[float]
    c: float
    scores: dict[float, float]

    def to_dict(self) -> dict:
        """As settings.json's transfer "refit" keeps it."""
        return {"weights": [w.tolist() for w in self.weights], "intercepts": self.intercepts,
                "C": self.c, "validation_accuracy": {str(c): v for c, v in self.scores.items()}}


def row_labels(models) -> list[tuple[tuple[str, ...], str]]:
    """Per head (row) in order: the classes its model decides between and the class its
    positive side stands for (a binary model's classes[1], else the row's class)."""
    out = []
    for classes, m in models:
        rows = [classes[1]] if len(m.coef) == 1 else list(classes)
        out += [(tuple(classes), c) for c in rows]
    return out


def fit_rows(j: np.ndarray, y: np.ndarray, heads: list[tr.Head], models, c: float,
             class_weight: str | None) -> tuple[list[np.ndarray], list[float]]:
    """Each head's weights on its own J columns and intercept, an SVM of its row against the
    rest on the clips of its model's classes, on standardised J (mapped back to raw J)."""
    off = np.cumsum([0] + [len(h.keep) for h in heads])
    weights, intercepts = [], []
    for k, (classes, positive) in enumerate(row_labels(models)):
        mine = np.isin(y, classes)
        if not np.any(y[mine] == positive) or np.all(y[mine] == positive):
            raise DataError("refit clips", f"need clips of '{positive}' and of other classes "
                            f"of its row, found {int(np.sum(y[mine] == positive))} of "
                            f"{int(mine.sum())}", hint="refit on more clips (--refit-clips)")
        x = j[mine, off[k]:off[k + 1]]
        mu, sd = x.mean(axis=0), x.std(axis=0)
        sd = np.where(sd > 0, sd, 1.0)
        m = fit_linear((x - mu) / sd, np.where(y[mine] == positive, "1", "0"), c,
                       class_weight=class_weight)
        w = m.coef[0] / sd
        weights.append(w)
        intercepts.append(float(m.intercept[0] - w @ mu))
    return weights, intercepts


def decide(j: np.ndarray, heads: list[tr.Head], weights: list[np.ndarray],
           intercepts: list[float]) -> np.ndarray:
    """The decisions (clips, rows) the refitted heads give on J: sum_e w_e J_e + b."""
    off = np.cumsum([0] + [len(h.keep) for h in heads])
    return np.stack([j[:, off[k]:off[k + 1]] @ w + b
                     for k, (w, b) in enumerate(zip(weights, intercepts))], axis=1)


def fit(train: tuple[np.ndarray, np.ndarray], val: tuple[np.ndarray, np.ndarray],
        heads: list[tr.Head], models, task: str, class_weight: str | None,
        grid: tuple[float, ...] = SVM_GRID) -> Refit:
    """Refit on (J, classes) of training clips, C chosen by the task's accuracy on the
    validation clips' (J, classes) (ties: the smaller C)."""
    from springc.kws.evaluation.evaluate import selection_models
    from springc.kws.training.report import score

    best, scores = None, {}
    for c in grid:
        w, b = fit_rows(*train, heads, models, c, class_weight)
        acc = score(selection_models(models), decide(val[0], heads, w, b), val[1],
                    task)["accuracy"]
        scores[c] = float(acc)
        if best is None or acc > best[0]:
            best = (acc, c, w, b)
    _, c, w, b = best
    return Refit(w, b, c, scores)

