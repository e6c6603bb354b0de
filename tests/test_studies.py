"""springc.kws.evaluation.studies: a sweep's threshold against curves whose crossing is known,
a stage's distortion against a known offset, the stage study's choice of clips."""

from __future__ import annotations

import math

import numpy as np
import pytest
import soundfile as sf

from springc.kws.evaluation.studies import distortion, falls_below, first_command_clips


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


def test_distortion_is_the_rms_error_over_the_ideal_peak() -> None:
    """Signals (channels, clips, time): an offset c on a sine of peak 2 is c / 2 of it; the
    largest channel within each clip, then the median over clips."""
    t = np.linspace(0, 1, 1001)
    ideal = np.stack([np.stack([2 * np.sin(2 * np.pi * 5 * t)] * 3),
                      np.stack([np.sin(2 * np.pi * 3 * t)] * 3)])
    got = ideal.copy()
    got[0] += np.array([0.02, 0.04, 0.06])[:, None]  # channel 0 of each clip
    assert distortion(got, ideal) == pytest.approx(0.02, rel=1e-12)


def test_first_command_clips_pass_over_unknown_words_and_repeats(tmp_path) -> None:
    """One clip per command word of the test split; 'cat' (not a command)
    and a second 'yes' are passed over: each clip is a tone, told apart by its frequency."""
    rate = 16000
    t = np.arange(rate) / rate
    tests = []
    for word, hz in (("yes", 300), ("cat", 500), ("yes", 700), ("no", 1000)):
        (tmp_path / word).mkdir(exist_ok=True)
        name = f"{word}/s{len(tests)}_nohash_0.wav"
        sf.write(tmp_path / name, 0.3 * np.sin(2 * np.pi * hz * t), rate, subtype="FLOAT")
        tests.append(name)
    (tmp_path / "testing_list.txt").write_text("\n".join(tests) + "\n")
    (tmp_path / "validation_list.txt").write_text("")
    got = first_command_clips(tmp_path, 2)
    assert got.shape == (2, rate)
    peaks = np.argmax(np.abs(np.fft.rfft(got, axis=1)), axis=1) * rate / got.shape[1]
    assert sorted(peaks) == [300, 1000]  # the split's own order (its words sorted)
