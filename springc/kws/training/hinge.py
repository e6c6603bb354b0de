"""The paper's SVM objective solved exactly by Newton's method: squared hinge loss, l2 penalty,
primal, one row per class (one-versus-rest; one row for two classes).

For each row, with x~ = (x, 1) (the intercept is a weight on a constant feature and is
penalised, as liblinear does with intercept_scaling 1), labels y = +-1 and per-sample
costs c_i (C times the sample's class weight):

    minimise  f(w) = w.w / 2 + sum_i c_i max(0, 1 - y_i w.x~_i)^2

f is convex and piecewise quadratic: on the set A of margin violators its gradient is
w + 2 X_A^T (c_A (X_A w - y_A)) and its Hessian I + 2 X_A^T diag(c_A) X_A, so Newton's method
with a backtracking line search reaches the minimum in a few dozen steps (finitely, once A
stops changing; Keerthi & DeCoste, JMLR 2005). Each step costs one N x d^2 product, which
BLAS spreads over the cores; liblinear's coordinate / trust-region solvers needed thousands of
iterations at large C on these correlated features (docs/performance.md#training).
"""

from __future__ import annotations

import numpy as np

TOL = 1e-9  # stop when |gradient| <= TOL * max(1, |gradient at the start|)
MAX_STEPS = 200


def fit_rows(z: np.ndarray, signs: np.ndarray, costs: np.ndarray,
             start: np.ndarray | None = None,
             intercept: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Minimise f for every row: features z (N, d), signs (rows, N) of +-1, costs (rows, N)
    >= 0, optional starting weights (rows, d + 1). Returns (coef (rows, d), intercept
    (rows,)) and leaves the weights in the last column as the intercept. Without
    `intercept` the constant feature is 0, so the intercept stays at its start (0)."""
    xb = np.hstack([z, np.full((len(z), 1), 1.0 if intercept else 0.0)])
    w = np.zeros((len(signs), xb.shape[1])) if start is None else np.array(start, float)
    for r in range(len(signs)):
        w[r] = _newton(xb, signs[r].astype(float), costs[r].astype(float), w[r])
    return w[:, :-1], w[:, -1]


def objective(xb: np.ndarray, y: np.ndarray, c: np.ndarray, w: np.ndarray) -> float:
    """f(w) for one row (xb: features with the constant column)."""
    slack = np.maximum(0.0, 1.0 - y * (xb @ w))
    return 0.5 * float(w @ w) + float(c @ (slack * slack))


def _newton(xb: np.ndarray, y: np.ndarray, c: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Newton's method with Armijo backtracking from w; the minimiser."""
    eye = np.eye(xb.shape[1])
    g0 = None
    f = objective(xb, y, c, w)
    for _ in range(MAX_STEPS):
        m = xb @ w
        viol = y * m < 1.0
        xa, ca = xb[viol], c[viol]
        g = w + 2.0 * xa.T @ (ca * (m[viol] - y[viol]))
        gn = float(np.linalg.norm(g))
        g0 = gn if g0 is None else g0
        if gn <= TOL * max(1.0, g0):
            break
        h = eye + 2.0 * (xa.T * ca) @ xa
        step = np.linalg.solve(h, g)
        t, slope = 1.0, float(g @ step)
        while True:
            trial = w - t * step
            ft = objective(xb, y, c, trial)
            if ft <= f - 1e-4 * t * slope or t < 1e-12:
                break
            t *= 0.5
        if ft >= f:  # no decrease left at round-off: the minimum
            break
        w, f = trial, ft
    return w
