"""Trimming fabricated devices (`springc.kws.evaluation.trim`, `springc eval --mc N --spread S
--trim K`): the fit's gradient is the central difference of its loss, a trim undoes a pure
per-row gain and offset error of the decisions, and the command reports every device
untrimmed and trimmed on the same test clips."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from springc.kws.evaluation import device, trim
from springc.kws.training.svm import LinearModel
from springc_cli.main import main
from kws_corpora import shared_corpus_and_model
from shared_cache import KERNELS

CLASSES = np.array([f"c{k}" for k in range(6)])


def models(rows: int = 6) -> list:
    pick = LinearModel(np.eye(rows), np.zeros(rows), CLASSES[:rows])
    return [(tuple(CLASSES[:rows]), pick)]


def separated(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Decisions (n, 6) whose argmax is the true class with a margin of at least 1."""
    rng = np.random.default_rng(seed)
    y = rng.integers(0, 6, n)
    d = rng.uniform(-1.5, -0.5, (n, 6))
    d[np.arange(n), y] = rng.uniform(0.5, 1.5, n)
    return d, CLASSES[y]


@pytest.mark.parametrize("binary", [False, True])
def test_the_loss_gradient_is_its_central_difference(binary):
    rng = np.random.default_rng(0)
    rows = 1 if binary else 4
    d, labels = rng.normal(size=(30, rows)), rng.integers(0, 2 if binary else rows, 30)
    z = np.concatenate([rng.uniform(0.5, 1.5, rows), rng.normal(0, 0.3, rows), [0.2]])
    _, grad = trim.loss(z, d, labels, binary)
    for i in range(len(z)):
        step = np.zeros_like(z)
        step[i] = 1e-6
        central = (trim.loss(z + step, d, labels, binary)[0]
                   - trim.loss(z - step, d, labels, binary)[0]) / 2e-6
        # central differences of a smooth O(1) function: truncation ~1e-12, round-off ~1e-10
        assert grad[i] == pytest.approx(central, rel=1e-6, abs=1e-8)


def test_a_trim_undoes_a_gain_and_offset_error_of_each_row():
    """Device rows read with gains from 0.3 to 3 and offsets up to 3: the untrimmed argmax
    is wrong on 40% of the clips. Trimmed on 200 labelled clips, it separates them all (they
    are separable, and the free temperature lets the cross-entropy demand it) and classifies
    at least 95% of 300 held-out clips (a boundary fitted to 200 clips, not the exact
    inverse of the error: 1/200 of a row's clips near it may fall either side)."""
    gain = np.array([3.0, 0.3, 1.0, 2.0, 0.5, 1.0])
    offset = np.array([3.0, -2.0, 1.5, -1.0, 0.5, -1.5])
    cal_d, cal_y = separated(200, 2)
    test_d, test_y = separated(300, 3)
    t = trim.fit(models(), cal_d * gain + offset, cal_y)
    untrimmed = CLASSES[np.argmax(test_d * gain + offset, axis=1)]
    trimmed = CLASSES[np.argmax(t.apply(test_d * gain + offset), axis=1)]
    assert np.mean(untrimmed == test_y) < 0.65
    assert np.all(CLASSES[np.argmax(t.apply(cal_d * gain + offset), axis=1)] == cal_y)
    assert np.mean(trimmed == test_y) >= 0.95


def test_a_binary_models_offset_is_trimmed():
    """One row, classes[1] where it is > 0: an offset of 2.5 on decisions of margin 1
    gives every clip to classes[1]; the trim restores the sign."""
    rng = np.random.default_rng(4)
    y = rng.integers(0, 2, 200)
    d = np.where(y == 1, 1.0, -1.0)[:, None] * rng.uniform(1.0, 2.0, (200, 1))
    pair = [(("c0", "c1"), LinearModel(np.ones((1, 1)), np.zeros(1), CLASSES[:2]))]
    t = trim.fit(pair, d + 2.5, CLASSES[y])
    assert np.mean((d[:, 0] + 2.5 > 0) == (y == 1)) < 0.8
    assert np.all((t.apply(d + 2.5)[:, 0] > 0) == (y == 1))


def test_eval_reports_every_device_untrimmed_and_trimmed(tmp_path_factory, monkeypatch):
    """`springc eval --mc 2 --trim 6 --json` on the shared 4x2 model (zero-mode heads: a
    spread of 1e-6, which they hold), and the text its report prints."""
    monkeypatch.setenv("SPRINGC_CACHE", str(KERNELS))
    _, model = shared_corpus_and_model(tmp_path_factory, "--realisation", "mass-spring")
    result = CliRunner().invoke(main, ["eval", str(model), "--mc", "2", "--spread", "1e-6",
                                       "--clips", "4", "--trim", "6", "-j", "1", "--json"])
    assert result.exit_code == 0, result.output
    report = json.loads(result.output.splitlines()[-1])
    assert report["n"] == 4 and report["trim_clips"] == 6 and len(report["devices"]) == 2
    assert 0 <= report["trimmed"]["worst"] <= report["trimmed"]["mean"] <= 1
    text = "\n".join(device.spread_lines(report, device.Spread(1e-6)))
    assert "trimmed on 6 validation clips (untrimmed, trimmed):" in text
    assert "untrimmed: mean" in text and "trimmed:   mean" in text
    for row in report["devices"]:
        assert row["diverged"] is False and set(row["priors"]) <= set(trim.PRIORS)
        assert f"  device {row['device']:<7d} {100 * row['accuracy']:6.2f}%  " \
               f"{100 * row['trimmed']:6.2f}%" in text
