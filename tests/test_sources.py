"""Sources: analytic signals, interpolation, sound-file inputs and their errors."""

from __future__ import annotations

import numpy as np
import pytest
import soundfile as sf

from springc.sim import sources
from springc.errors import DataError, UsageError
from springc.kernels.integrators import TABLEAUX, get_tableau
from springc.lang.ir import IRBuilder, Source


def test_analytic_sources_follow_the_spec():
    t = np.array([0.0, 0.25, 1.0, 2.0])
    s = sources.analytic(Source("sin", (2.0, 0.5, np.pi / 2)), t)
    np.testing.assert_allclose(s, 2 * np.sin(np.pi * t + np.pi / 2), rtol=0, atol=1e-15)
    g = sources.analytic(Source("gauss", (3.0, 1.0, 0.5)), t)
    np.testing.assert_allclose(g, 3 * np.exp(-((t - 1) ** 2) / 0.5), rtol=1e-15)
    st = sources.analytic(Source("step", (4.0, 1.0)), t)
    assert st.tolist() == [0.0, 0.0, 4.0, 4.0]
    p = sources.analytic(Source("pwl", (0.5, 1.0, 1.5, 3.0)), t)
    assert p.tolist() == [1.0, 1.0, 2.0, 3.0]  # constant outside, linear between


def test_interpolate_is_linear_and_zero_after_the_end():
    sig = np.array([0.0, 1.0, -1.0])
    got = sources.interpolate(sig, 10.0, np.array([0.05, 0.15, 0.25, 0.3, 1.0]))
    np.testing.assert_allclose(got, [0.5, 0.0, -0.5, 0.0, 0.0], atol=1e-15)


def test_stage_times_use_the_tableau_nodes():
    t = sources.stage_times(3, 0.1, get_tableau("rk4"))
    np.testing.assert_allclose(t[2], [0.2, 0.25, 0.25, 0.3])


@pytest.mark.parametrize("name", sorted(TABLEAUX))
def test_at_stage_times_is_f_at_every_stage_time_bitwise(name):
    """Evaluated once per distinct time, the table is still f(stage_times) to the bit (a
    step's end is computed as the next step's start: (k + 1.0) h == (k + 1) h exactly)."""
    tab = get_tableau(name)
    calls = []

    def f(t):
        calls.append(t.size)
        return np.sin(2 * np.pi * 440.0 * t) * np.exp(t)

    got = sources.at_stage_times(f, 1000, 3e-5, tab)
    assert np.array_equal(got, f(sources.stage_times(1000, 3e-5, tab)))
    distinct = len(set(tab.c) - ({1.0} if 0.0 in tab.c else set()))
    assert calls[0] == 1001 * distinct  # RK4: two a step (c = 0 and 1/2), not four


@pytest.mark.parametrize("name", ["rk4", "heun3"])
def test_sine_table_is_the_sine_at_every_stage_time(name):
    """Angle addition against numpy's sine of the stage times: within a few round-offs of the
    angle (up to 2 pi 1234 Hz x 0.8 s: 6e3 rad), over more steps than one block and a partial
    last block."""
    tab = get_tableau(name)
    src = Source("sin", (3.0, 1234.0, 0.7))
    nsteps, h = 3 * sources.SINE_BLOCK + 17, 1e-3
    got = sources.sine_at_stage_times(src, nsteps, h, tab)
    t = sources.stage_times(nsteps, h, tab)
    want = sources.analytic(src, t)
    assert got.shape == want.shape == (nsteps, tab.stages)
    angle = 2 * np.pi * 1234.0 * t.max()
    # the amplitude times a few round-offs of the angle (measured 3.4e-12 of this 1.6e-11)
    assert np.abs(got - want).max() <= 3.0 * 4 * np.finfo(float).eps * angle


def test_common_table_tabulates_wav_and_analytic(tmp_path):
    wav = tmp_path / "ramp.wav"
    sf.write(wav, np.linspace(0, 0.99, 100), 100, subtype="DOUBLE")
    b = IRBuilder()
    b.mass("M", "a", 1.0)
    b.force("F1", "a", Source("wav", path=str(wav)))
    b.force("F2", "a", Source("sin", (1.0, 1.0)))
    b.force("F3", "a", Source("in"))
    net = b.finish()
    table = sources.common_table(net, 10, 0.005, 0.01, get_tableau("rk4"))
    assert table.shape == (10, 4, 2)
    t = sources.stage_times(10, 0.005, get_tableau("rk4"))
    np.testing.assert_allclose(table[..., 0], t, atol=1e-12)  # ramp sampled at 100 Hz: 0.01/s
    np.testing.assert_allclose(table[..., 1], np.sin(2 * np.pi * t), atol=1e-15)
    assert sources.input_forces(net) == [2] and sources.channels_used(net) == 1


def test_common_table_reads_the_channel_a_wav_source_names(tmp_path):
    wav = tmp_path / "stereo.wav"
    ramp = np.linspace(0, 0.99, 100)
    sf.write(wav, np.stack([ramp, -0.5 * ramp], axis=1), 100, subtype="DOUBLE")
    b = IRBuilder()
    b.mass("M", "a", 1.0)
    b.force("F0", "a", Source("wav", path=str(wav), channel=0))
    b.force("F1", "a", Source("wav", path=str(wav), channel=1))
    table = sources.common_table(b.finish(), 10, 0.005, 0.01, get_tableau("rk4"))
    t = sources.stage_times(10, 0.005, get_tableau("rk4"))
    np.testing.assert_allclose(table[..., 0], t, atol=1e-12)
    np.testing.assert_allclose(table[..., 1], -0.5 * t, atol=1e-12)


def test_read_inputs_pads_resamples_and_picks_channels(tmp_path):
    t = np.arange(800) / 8000
    sf.write(tmp_path / "a.wav", np.sin(2 * np.pi * 100 * t), 8000, subtype="DOUBLE")
    sf.write(tmp_path / "b.flac", 0.5 * np.sin(2 * np.pi * 100 * t[:400]), 8000)
    sf.write(tmp_path / "c.wav", np.stack([t, -t], axis=1), 8000, subtype="DOUBLE")
    paths = sources.expand_inputs([tmp_path])
    assert [p.name for p in paths] == ["a.wav", "b.flac", "c.wav"]
    with pytest.raises(DataError, match="2 channels"):
        sources.read_inputs(paths, 16000, 1)
    arr = sources.read_inputs(paths[:2], 16000, 1)
    assert arr.shape == (2, 1, 1600) and np.all(arr[1, 0, 800:] == 0)
    mid = np.sin(2 * np.pi * 100 * np.arange(1600) / 16000)
    assert np.abs(arr[0, 0, 200:1400] - mid[200:1400]).max() < 1e-3  # band-limited resampling
    stereo = sources.read_inputs(paths[2:], 8000, 1, channel=1)
    np.testing.assert_allclose(stereo[0, 0], -t)
    both = sources.read_inputs(paths[2:], 8000, 2)
    np.testing.assert_allclose(both[0], [t, -t])
    with pytest.raises(UsageError, match="one file channel"):
        sources.read_inputs(paths[2:], 8000, 2, channel=0)


def test_bad_input_paths_name_the_file(tmp_path):
    with pytest.raises(DataError, match="no such file"):
        sources.expand_inputs([tmp_path / "missing.wav"])
    with pytest.raises(DataError, match="no sound files"):
        sources.expand_inputs([tmp_path])
    bad = tmp_path / "bad.wav"
    bad.write_bytes(b"not audio")
    with pytest.raises(DataError, match="bad.wav: cannot read as audio"):
        sources.read_inputs([bad], 8000, 1)


def test_kernel_inputs_pad_for_the_last_stage():
    u = sources.kernel_inputs(np.ones((2, 1, 5)), 2, 1, 10, np.float32)
    assert u.shape == (2, 1, 12) and u.dtype == np.float32 and u[:, :, 5:].sum() == 0
