"""`springc modes` data: eigenfrequencies, damping, Q, dominant nodes and zero modes."""

from __future__ import annotations

import json

import numpy as np
import pytest

from springc.analyses.modes import mode_report, mode_text
from springc.lang.ir import IRBuilder
from springc.check import check


def _filter_like():
    """Two unit masses with b = alpha, springs w^2 and a coupling: modes at w and
    sqrt(w^2 + 2 kc), both decaying at alpha/2; plus a free body."""
    b = IRBuilder()
    b.mass("Ma", "a", 1.0, 40.0)
    b.mass("Mb", "b", 1.0, 40.0)
    b.spring("Ka", "a", 1e6)
    b.spring("Kb", "b", 1e6)
    b.coupling("C", "a", "b", 1.05e5)
    b.mass("Mf", "free", 3.0)
    return b.finish()


def test_report_numbers() -> None:
    report = mode_report(check(_filter_like()))
    low, high = report["modes"]
    assert low["omega"] == pytest.approx(1e3, rel=1e-12)
    assert high["omega"] == pytest.approx(np.sqrt(1e6 + 2.1e5), rel=1e-12)
    assert low["freq_hz"] == pytest.approx(1e3 / (2 * np.pi), rel=1e-12)
    for row in (low, high):
        assert row["damping_rate"] == pytest.approx(20.0, rel=1e-10)
        assert row["q"] == pytest.approx(row["omega"] / 40.0, rel=1e-10)
        assert row["oscillating"]
    assert {d["node"] for d in high["dominant"]} == {"a", "b"}
    assert report["zero_modes"] == [{"count": 1, "at_least": False, "dominant": ["free"]}]
    json.dumps(report)  # JSON-ready (no inf, no numpy scalars)


def test_count_limits_rows_and_text_lists_zero_modes() -> None:
    report = mode_report(check(_filter_like()), count=1)
    assert len(report["modes"]) == 1 and report["total_modes"] == 2
    text = mode_text(report)
    assert "zero modes: 1 (free motion), dominant nodes free" in text
    assert "159.155" in text  # 1000 rad/s in Hz


def test_all_to_all_block_with_designed_zero_modes() -> None:
    """n masses all coupled to all with k (graph Laplacian of K_n): one zero mode (rigid
    translation) and n - 1 modes at sqrt(n k / m)."""
    n, k, m = 8, 0.5, 2.0
    b = IRBuilder()
    for i in range(n):
        b.mass(f"M{i}", f"n{i}", m)
        for j in range(i):
            b.coupling(f"C{i}_{j}", f"n{i}", f"n{j}", k)
    report = mode_report(check(b.finish()))
    assert len(report["modes"]) == n - 1
    np.testing.assert_allclose([r["omega"] for r in report["modes"]], np.sqrt(n * k / m),
                               rtol=1e-10)
    assert report["zero_modes"][0]["count"] == 1
