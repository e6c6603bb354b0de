"""springc.kws.evaluation.studies: a sweep's threshold against curves whose crossing is known."""

from __future__ import annotations

import math

import pytest

from springc.kws.evaluation.studies import falls_below


def test_a_curve_linear_in_log_x_crosses_where_it_says() -> None:
    # y = 0.6 - 0.1 log10(x / 1e-6): 0.55 at x = 10^-5.5, exactly, whatever the grid
    xs = [1e-6, 1e-5, 1e-4, 1e-3]
    ys = [0.6 - 0.1 * math.log10(x / 1e-6) for x in xs]
    assert falls_below(xs, ys, 0.55) == pytest.approx(10**-5.5, rel=1e-12)
    assert falls_below(xs, ys, 0.5) == pytest.approx(1e-5, rel=1e-12)  # at a grid point


def test_the_first_fall_counts_and_none_where_there_is_none() -> None:
    xs = [1e-40, 1e-36, 1e-30, 1e-20]
    assert falls_below(xs, [0.56, 0.48, 0.56, 0.04], 0.54) == pytest.approx(
        10 ** (-40 + 4 * (0.56 - 0.54) / (0.56 - 0.48)))
    assert falls_below(xs, [0.5, 0.5, 0.5, 0.5], 0.4) is None  # never falls
    assert falls_below(xs, [0.3, 0.5, 0.5, 0.5], 0.4) is None  # below from the start
    with pytest.raises(ValueError):
        falls_below(xs, [0.5], 0.4)
