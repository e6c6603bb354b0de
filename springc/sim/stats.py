"""Statistics of a Monte Carlo population and their first-order prediction
(`springc sim --reduce SPEC --stats`, `springc.Result.stats()`).

Per reduction, step point and run: the mean, standard deviation, 5/50/95% quantiles, minimum
and maximum over the `.mc` samples, beside the linear prediction of the deviation,
    var R = sum over p of (dR/dp sigma_p)^2,
where p runs over the top-level `.param`s whose value is a random function alone (global
draws), sigma_p is that function's standard deviation and dR/dp the exact discrete adjoint
gradient (`springc.grad.gradient`) at the nominal design of the step point. Draws written
elsewhere (per instance or element: local mismatch) are not in the prediction, and the
report says so: where they matter, the Monte Carlo deviation exceeds the prediction.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from springc.errors import SpringcError, UsageError
from springc.grad import gradient
from springc.lang import ast, draws
from springc.lang.expr import Env, scalar, value
from springc.lang.files import beside, read_array

QUANTILES = (0.05, 0.5, 0.95)


@dataclass(frozen=True)
class Row:
    """One reduction at one step point and run: the samples' statistics, the reduction at
    the nominal design and its predicted deviation (None with `why_not` saying why)."""

    spec: str
    steps: tuple[tuple[str, float], ...]
    run: str
    samples: np.ndarray = field(repr=False)
    nominal: float | None = None
    predicted_std: float | None = None
    why_not: str | None = None

    @property
    def mean(self) -> float:
        return float(np.mean(self.samples))

    @property
    def std(self) -> float:
        """The sample standard deviation (ddof=1; 0 for one sample)."""
        return float(np.std(self.samples, ddof=1)) if len(self.samples) > 1 else 0.0

    @property
    def quantiles(self) -> tuple[float, ...]:
        return tuple(float(q) for q in np.quantile(self.samples, QUANTILES))

    def where(self) -> str:
        parts = [f"{k}={v:g}" for k, v in self.steps] + [self.run]
        return ", ".join(parts)


@dataclass
class Report:
    """Every row, the global random parameters the prediction covers (name -> sigma, at the
    first step point), those it cannot (a random function inside an expression) and whether
    the netlist draws locally too (not covered)."""

    rows: list[Row]
    sigmas: dict[str, float]
    uncovered: list[str]
    local: bool

    def text(self) -> str:
        """The table `springc sim --stats` prints."""
        lines = [f"{'reduction':<16} {'where':<18} {'n':>6} {'mean':>12} {'std':>11} "
                 f"{'std(pred)':>11} {'q05':>12} {'q50':>12} {'q95':>12} {'min':>12} "
                 f"{'max':>12}"]
        for r in self.rows:
            pred = "-" if r.predicted_std is None else f"{r.predicted_std:.5g}"
            q05, q50, q95 = r.quantiles
            lines.append(f"{r.spec:<16} {r.where():<18} {len(r.samples):>6} {r.mean:>12.6g} "
                         f"{r.std:>11.5g} {pred:>11} {q05:>12.6g} {q50:>12.6g} {q95:>12.6g} "
                         f"{r.samples.min():>12.6g} {r.samples.max():>12.6g}")
        lines += self._notes()
        return "\n".join(lines)

    def _notes(self) -> list[str]:
        covered = ", ".join(f"{k} (sigma {s:.4g})" for k, s in self.sigmas.items())
        notes = [f"std(pred): first-order prediction sqrt(sum (dR/dp sigma_p)^2) over the "
                 f"global random parameters: {covered or 'none'}"]
        if self.uncovered:
            notes.append("not in the prediction (a random function inside an expression): "
                         + ", ".join(self.uncovered))
        if self.local:
            notes.append("not in the prediction: local (per-instance or per-element) draws; "
                         "the Monte Carlo std includes them")
        notes += sorted({f"no prediction for {r.spec}: {r.why_not}" for r in self.rows
                         if r.why_not})
        return notes

    def figure(self):
        """A histogram of every row's samples, the mean and the predicted +-1 sigma marked."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        count = len(self.rows)
        cols = min(count, 3)
        rows = -(-count // cols)
        fig, axes = plt.subplots(rows, cols, squeeze=False, figsize=(4.2 * cols, 3.2 * rows))
        for ax, r in zip(axes.flat, self.rows):
            ax.hist(r.samples, bins=max(10, min(60, int(math.sqrt(len(r.samples))))),
                    color="0.6")
            ax.axvline(r.mean, color="k", lw=1, label="mean")
            if r.predicted_std is not None and r.nominal is not None:
                for s in (-1, 1):
                    ax.axvline(r.nominal + s * r.predicted_std, color="C1", ls="--", lw=1,
                               label="nominal +- std(pred)" if s < 0 else None)
            ax.set_title(f"{r.spec} ({r.where()})", fontsize="small")
            ax.legend(fontsize="x-small")
        for ax in list(axes.flat)[count:]:
            ax.set_visible(False)
        fig.tight_layout()
        return fig


def population(result, predict: bool = True) -> Report:
    """The statistics of `result` (a `springc.Result` of a `.mc` netlist with reductions),
    with the first-order prediction where `predict`."""
    points = result.points
    if points is None or points[0].sample is None:
        raise UsageError("statistics need Monte Carlo samples: the netlist has no .mc line",
                         hint="add .mc N [seed=S] and random functions (gauss, agauss, unif, "
                              "aunif)")
    if not result.reductions:
        raise UsageError("statistics need reductions: give --reduce SPEC")
    groups: dict[tuple, list[int]] = {}
    for i, p in enumerate(points):
        groups.setdefault(p.steps, []).append(i)
    pn = result.netlist.source
    sigmas, uncovered = global_sigmas(pn.statements, dict(points[0].steps))
    rows = []
    for steps, idx in groups.items():
        step_sigmas = global_sigmas(pn.statements, dict(steps))[0]
        for spec, data in result.reductions.items():
            pred = _predict(result, spec, steps, step_sigmas) if predict else None
            for r, run in enumerate(result.runs):
                nominal, std, why = pred[r] if pred else (None, None, None)
                rows.append(Row(spec, steps, run, np.asarray(data[idx, r], np.float64),
                                nominal, std, why))
    return Report(rows, sigmas, uncovered, local_draws(pn.statements))


def _predict(result, spec: str, steps: tuple, sigmas: dict[str, float]) -> list[tuple]:
    """(nominal value, predicted deviation, None) per run, or (None, None, why) per run."""
    if not sigmas:
        return [(None, None, "no top-level .param is a random function")] * len(result.runs)
    st = result.settings
    try:
        g = gradient(result.netlist.source, spec, list(sigmas), result.inputs.get("inputs"),
                     result.inputs.get("input_rate"), values=dict(steps), tstep=st.tstep,
                     tstop=st.tstop, substeps=st.substeps, method=st.method,
                     channel=result.inputs.get("channel"))
    except SpringcError as err:
        return [(None, None, err.message)] * len(result.runs)
    sig = np.array(list(sigmas.values()))
    std = np.sqrt(((g.grad * sig) ** 2).sum(axis=1))
    return [(float(g.values[spec][r]), float(std[r]), None) for r in range(len(result.runs))]


def sigma(func: str, args: list[float]) -> float:
    """The standard deviation of the random function `func(*args)` (docs/language.md)."""
    nom, spread = float(args[0]), float(args[1])
    scale = abs(nom) * spread if func in ("gauss", "unif") else spread
    if func in ("gauss", "agauss"):
        return scale / (float(args[2]) if len(args) == 3 else 1.0)
    if func in ("unif", "aunif"):
        return scale / math.sqrt(3.0)
    raise TypeError(f"not a random function: {func}")


def global_sigmas(statements: list, steps: dict[str, float]
                  ) -> tuple[dict[str, float], list[str]]:
    """The top-level `.param`s that are a random function alone, with its deviation at the
    step values `steps` (a stepped parameter is a number, not random), and the names of those
    with a random function inside a larger expression."""
    env = Env()
    sigmas: dict[str, float] = {}
    uncovered: list[str] = []
    for stmt in statements:
        if not isinstance(stmt, ast.Directive):
            continue
        if stmt.name == "data":
            env.vars[stmt.args[0].parts[0]] = read_array(beside(stmt.args[1]),
                                                         stmt.args[1].loc)
        if stmt.name != "param":
            continue
        for kw in stmt.args:
            if kw.key in steps:
                env.vars[kw.key] = steps[kw.key]
                continue
            call = _lone_call(kw.value)
            if call is not None:
                sigmas[kw.key] = sigma(call.func, [scalar(a, env) for a in call.args])
            elif _calls(kw.value):
                uncovered.append(kw.key)
            env.vars[kw.key] = value(kw.value, env)
    return sigmas, uncovered


def _lone_call(node) -> ast.Call | None:
    """The random call that `node` is ({gauss(...)} or gauss(...)), else None."""
    while isinstance(node, ast.Brace):
        node = node.expr
    if isinstance(node, ast.Call) and node.func in draws.FUNCTIONS:
        return node
    return None


def _calls(node) -> bool:
    """Whether the AST subtree `node` holds a random function call."""
    if isinstance(node, ast.Call) and node.func in draws.FUNCTIONS:
        return True
    if isinstance(node, (list, tuple)):
        return any(_calls(n) for n in node)
    if dataclasses.is_dataclass(node):
        return any(_calls(getattr(node, f.name)) for f in dataclasses.fields(node))
    return False


def local_draws(statements: list) -> bool:
    """Whether any random function is written outside the top-level `.param` lines."""
    return any(_calls(s) for s in statements
               if not (isinstance(s, ast.Directive) and s.name == "param"))
