"""Linear SVM training: raw-space weights reproduce the decision; C chosen on validation;
balanced class weights undo a 90/10 imbalance (and are sklearn's sample weights); the delays
of the architecture carry temporal order (chirp direction)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import chirp

from springc.errors import DataError
from springc.kws.features.digital import FeatureSettings, features
from springc.kws.features.phi import kernels, phi_vector, readout
from springc.kws.training.svm import LinearModel, Standardiser, accuracy, fit_linear, select


def _blobs(rng, k=3, n=60, dim=5):
    centres = rng.normal(scale=4.0, size=(k, dim))
    y = np.repeat(np.arange(k), n)
    x = centres[y] + rng.normal(size=(k * n, dim))
    x = x * rng.uniform(0.01, 100, size=dim) + rng.normal(scale=50, size=dim)  # badly scaled
    return x, np.array([f"c{i}" for i in y])


@pytest.mark.parametrize("kind", ["svm", "logreg"])
def test_raw_weights_reproduce_the_standardised_decision(kind):
    from sklearn.linear_model import LogisticRegression
    from sklearn.svm import LinearSVC

    rng = np.random.default_rng(0)
    x, y = _blobs(rng)
    model = fit_linear(x, y, 0.1, kind)
    std = Standardiser.fit(x)
    # liblinear held to a tight tolerance: the exact minimum the Newton solver reaches
    est = (LinearSVC(C=0.1, loss="squared_hinge", penalty="l2", dual=False, max_iter=100000,
                     tol=1e-12)
           if kind == "svm" else LogisticRegression(C=0.1, max_iter=500))
    est.fit(std(x), y)
    tol = 1e-6 if kind == "svm" else 1e-9
    assert np.allclose(model.decision(x), est.decision_function(std(x)), rtol=tol, atol=tol)
    assert np.array_equal(model.predict(x), est.predict(std(x)))


@pytest.mark.parametrize("classes", [2, 4])
@pytest.mark.parametrize("c", [0.1, 1e4])
def test_newton_reaches_liblinears_minimum_with_its_class_weights(classes, c):
    """Balanced class weights as liblinear applies them (one-versus-rest: a class's weight on
    its own samples, the rest at 1), to the minimum of liblinear held to a tight tolerance,
    and no point near the solution has a lower objective."""
    import warnings

    from sklearn.svm import LinearSVC

    from springc.kws.training import hinge

    rng = np.random.default_rng(classes)
    x, y = _blobs(rng, k=classes)
    keep = np.ones(len(y), bool)
    keep[np.flatnonzero(y == "c0")[: len(y) // (2 * classes)]] = False  # imbalanced
    x, y = x[keep], y[keep]
    model = fit_linear(x, y, c, class_weight="balanced")
    std = Standardiser.fit(x)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est = LinearSVC(C=c, loss="squared_hinge", penalty="l2", dual=False, max_iter=100000,
                        tol=1e-12, class_weight="balanced").fit(std(x), y)
    d = est.decision_function(std(x)).reshape(len(y), -1)
    assert np.allclose(model.decision(x), d, rtol=1e-5, atol=1e-5 * np.abs(d).max())
    signs = np.where(y == (model.classes[1] if classes == 2 else model.classes[0]), 1.0, -1.0)
    weight = len(y) / (classes * np.sum(y == model.classes[0 if classes > 2 else 1]))
    costs = c * np.where(signs > 0, weight, 1.0 if classes > 2 else
                         len(y) / (classes * np.sum(y == model.classes[0])))
    xb = np.hstack([std(x), np.ones((len(y), 1))])
    w = np.concatenate([model.coef[0] * std.scale, [model.intercept[0]
                                                     + model.coef[0] @ std.mean]])
    best = hinge.objective(xb, signs, costs, w)
    for _ in range(5):
        assert hinge.objective(xb, signs, costs, w + rng.normal(scale=1e-3, size=w.shape)) > best


def test_binary_model_has_one_row_and_thresholds_at_zero():
    rng = np.random.default_rng(1)
    x, y = _blobs(rng, k=2)
    model = fit_linear(x, y, 1.0)
    assert model.coef.shape == (1, 5)
    d = model.decision(x)[:, 0]
    assert np.array_equal(model.predict(x), np.where(d > 0, model.classes[1], model.classes[0]))
    assert accuracy(model, x, y) > 0.95


def test_validation_chooses_the_regularisation():
    rng = np.random.default_rng(2)
    x, y = _blobs(rng, n=40)
    idx = rng.permutation(len(y))
    tr, va = idx[:80], idx[80:]
    model, c, scores = select(x[tr], y[tr], x[va], y[va], grid=(1e-4, 1e-2, 1.0))
    assert c == max(scores, key=lambda k: (scores[k], -k))
    assert accuracy(model, x[va], y[va]) == scores[c]


def test_one_class_is_a_data_error():
    with pytest.raises(DataError, match="at least two classes"):
        fit_linear(np.ones((4, 2)), np.array(["a"] * 4), 1.0)


def _chirp_word(up: bool, rng) -> np.ndarray:
    t = np.arange(16000) / 16000
    f0, f1 = (300, 3000) if up else (3000, 300)
    dur, start = rng.uniform(0.3, 0.5), rng.uniform(0.1, 0.4)
    tt = np.clip(t - start, 0, dur)
    env = np.where((t > start) & (t < start + dur), np.sin(np.pi * tt / dur) ** 2, 0.0)
    word = env * chirp(tt, f0, dur, f1, method="logarithmic") * rng.uniform(0.3, 1)
    return word + 0.01 * rng.normal(size=t.size)


def test_delays_tell_rising_from_falling_chirps_and_the_readout_is_physical():
    """Rising and falling chirps share their spectrum; only the lagged cross-bin products
    (m > 1) see the order. The trained c . Phi + b equals the model's decision, and the
    eigen-decomposed kernels reproduce c . Phi (the weights can be put into springs)."""
    rng = np.random.default_rng(0)
    y = np.array(["up", "down"] * 60)
    sig = np.stack([_chirp_word(v == "up", rng) for v in y])
    results = {}
    for m in (1, 3):
        s = FeatureSettings(bins=6, delays=m, td=0.064)
        phi = phi_vector(features(sig, 16000.0, s), s)
        model, c, scores = select(phi[:80], y[:80], phi[80:100], y[80:100],
                                  grid=(1e-3, 1e-1, 10.0))
        results[m] = (scores[1e-3], accuracy(model, phi[100:], y[100:]))
    assert results[3][1] >= 0.95 and results[3][0] >= 0.95
    assert results[1][0] <= 0.75  # strongly regularised, no delays: near chance
    coef = model.coef[0]
    assert np.allclose(readout(coef, phi) + model.intercept[0], model.decision(phi)[:, 0],
                       rtol=1e-10, atol=1e-10 * np.abs(model.intercept[0]))
    w, signs = kernels(coef, 6, 3)
    x = features(sig[:2], 16000.0, s)
    assert np.allclose(readout(coef, phi_vector(x, s)), readout(coef, phi[:2]), rtol=1e-12)
    assert w.shape == (18, 6, 3) and set(np.unique(signs)) <= {-1.0, 0.0, 1.0}


def test_linear_model_predicts_by_argmax():
    m = LinearModel(np.eye(3), np.zeros(3), np.array(["a", "b", "c"]))
    assert list(m.predict(np.array([[0, 2, 1], [5, 0, 0]]))) == ["b", "a"]


def _imbalanced(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """90/10: 900 'major' at N(0, I), 100 'minor' at N((2, 0), I) in the plane."""
    rng = np.random.default_rng(seed)
    x = np.concatenate([rng.normal(size=(900, 2)), rng.normal(size=(100, 2)) + [2.0, 0.0]])
    return x, np.array(["major"] * 900 + ["minor"] * 100)


@pytest.mark.parametrize("seed", [0, 1])
def test_balanced_class_weights_stop_the_majority_from_winning(seed):
    """Unweighted, the squared hinge puts the boundary past the minority's own centre (2, 0),
    which it then calls 'major'; weighted by n / (2 n_class), the boundary moves to about
    the midpoint (x = 1) and the centre is 'minor'."""
    x, y = _imbalanced(seed)
    centre = np.array([[2.0, 0.0]])
    plain = fit_linear(x, y, 1.0)
    weighted = fit_linear(x, y, 1.0, class_weight="balanced")
    assert plain.predict(centre)[0] == "major"
    assert weighted.predict(centre)[0] == "minor"
    recall = [np.mean(m.predict(x[900:]) == "minor") for m in (plain, weighted)]
    assert recall[0] < 0.5 and recall[1] > 0.75
    boundary = -weighted.intercept[0] / weighted.coef[0, 0]  # where the decision crosses y = 0
    assert 0.7 < boundary < 1.3


@pytest.mark.parametrize("kind", ["svm", "logreg"])
def test_balanced_class_weights_equal_per_sample_weights_in_sklearn(kind):
    """class_weight="balanced" is sklearn's sample weighting by n / (classes * n_class)."""
    from sklearn.linear_model import LogisticRegression
    from sklearn.svm import LinearSVC

    x, y = _imbalanced(2)
    model = fit_linear(x, y, 0.5, kind, class_weight="balanced")
    std = Standardiser.fit(x)
    weights = np.where(y == "major", 1000 / (2 * 900), 1000 / (2 * 100))
    est = (LinearSVC(C=0.5, loss="squared_hinge", penalty="l2", dual=False, max_iter=5000)
           if kind == "svm" else LogisticRegression(C=0.5, max_iter=500))
    est.fit(std(x), y, sample_weight=weights)
    assert np.allclose(model.decision(x)[:, 0], est.decision_function(std(x)), atol=1e-6)


def test_select_fits_with_the_class_weights():
    x, y = _imbalanced(3)
    idx = np.random.default_rng(3).permutation(len(y))
    tr, va = idx[:800], idx[800:]
    model, c, _ = select(x[tr], y[tr], x[va], y[va], grid=(0.1, 1.0), class_weight="balanced")
    again = fit_linear(x[tr], y[tr], c, class_weight="balanced")
    assert np.allclose(model.coef, again.coef) and np.allclose(model.intercept, again.intercept)
    assert not np.allclose(model.coef, fit_linear(x[tr], y[tr], c).coef, rtol=1e-2)


def test_unknown_class_weights_are_refused():
    with pytest.raises(ValueError, match="unknown class weights"):
        fit_linear(*_imbalanced(0), 1.0, class_weight="even")
