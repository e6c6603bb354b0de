"""What the result pages read off their runs: where an accuracy falls below a target, how far
a stage's signal is from its ideal, and the clips a stage study runs.

`falls_below(xs, ys, target)` is the threshold of a spread sweep (the spread at which the mean
device falls a given loss below its nominal design) and of a device-mass sweep (the mass at
which thermal noise costs that loss): the sweeps are on logarithmic grids, so the crossing is
interpolated linearly in log10 x between the two measured points around it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

EPS_IDEAL = 1e-9  # the squaring error of the reference run a stage study compares against


def falls_below(xs: Sequence[float], ys: Sequence[float], target: float) -> float | None:
    """The x (> 0, increasing) at which ys first falls to or below `target`, interpolated
    linearly in log10 x between the last point above it and the first at or below it; None
    where the first point is already at or below it, or no point falls to it."""
    if len(xs) != len(ys):
        raise ValueError(f"{len(xs)} x values against {len(ys)} y values")
    if not len(ys) or ys[0] <= target:
        return None
    logs = [math.log10(x) for x in xs]
    for (x0, y0), (x1, y1) in zip(zip(logs, ys), zip(logs[1:], ys[1:])):
        if y1 <= target < y0:
            return 10 ** (x0 + (target - y0) * (x1 - x0) / (y1 - y0))
    return None


def distortion(signal: np.ndarray, ideal: np.ndarray) -> float:
    """How far a stage's signals (channels, clips, time) are from the ideal run's: the RMS
    over time of the difference over the ideal's peak, the largest channel, the median
    clip."""
    peak = np.abs(ideal).max(axis=-1)
    rms = np.sqrt(np.mean((signal - ideal) ** 2, axis=-1))
    return float(np.median((rms / peak).max(axis=0)))


def first_command_clips(data: Path, count: int) -> np.ndarray:
    """(count, samples): the first test clips of `count` distinct command words of the data
    set `data` (silence and unknown words passed over), pre-processed as training reads
    them."""
    from springc.kws.data.dataset import load_clip, open_dataset

    chosen, words = [], set()
    for c in open_dataset(data).split("test"):
        if c.label.startswith("_") or c.word in words:
            continue
        words.add(c.word)
        chosen.append(load_clip(c))
        if len(chosen) == count:
            break
    return np.stack(chosen)
