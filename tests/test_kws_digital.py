"""Digital feature extraction: each stage against its analytic response."""

from __future__ import annotations

import numpy as np
import pytest

from springc.design import filters
from springc.errors import UsageError
from springc.kws.features.digital import (FeatureSettings, features, filter_responses, filterbank,
                                          horizon, lowpass)

RATE = 16000.0


def test_lowpass_step_response_is_critically_damped():
    """x'' + 2w x' + w^2 x = w^2 u with a unit step: x = 1 - (1 + w t) exp(-w t). The
    sampled step stands for a band-limited one, which switches on half a sample early: the
    error bound is half a sample times the largest slope, w / e."""
    fc = 50.0
    t = np.arange(8000) / RATE
    w = 2 * np.pi * fc
    exact = 1 - (1 + w * t) * np.exp(-w * t)
    error = np.abs(lowpass(np.ones_like(t), RATE, fc) - exact)
    assert np.max(error[80:]) < 0.5 / RATE * w / np.e * 1.05
    assert np.max(error[4000:]) < 1e-4


@pytest.mark.parametrize("f0", [20.0, 50.0, 200.0])
def test_lowpass_tone_gain_and_phase(f0):
    """Steady state: gain 1 / (1 + (f/fc)^2), phase -2 atan(f/fc)."""
    fc = 50.0
    t = np.arange(32000) / RATE
    y = lowpass(np.sin(2 * np.pi * f0 * t), RATE, fc)
    ratio = f0 / fc
    expect = np.sin(2 * np.pi * f0 * t - 2 * np.arctan(ratio)) / (1 + ratio**2)
    assert np.max(np.abs(y - expect)[8000:24000]) < 1e-4


@pytest.mark.parametrize("kind", ["two-mode", "single-mode", "triangular"])
def test_filterbank_tone_steady_state_matches_the_response(kind):
    """A tone of frequency f gives |H(f)| sin(2 pi f t + arg H(f)) once transients decay."""
    s = FeatureSettings(bins=6, filterbank=kind)
    f0 = 1000.0
    t = np.arange(16000) / RATE
    y = filterbank(np.sin(2 * np.pi * f0 * t), RATE, s)
    h = filter_responses(np.array([f0]), s)[:, 0]
    expect = np.abs(h)[:, None] * np.sin(2 * np.pi * f0 * t + np.angle(h)[:, None])
    window = slice(6000, 10000)  # 0.4-0.6 s, far from both switching edges
    assert np.max(np.abs(y[:, window] - expect[:, window])) < 1e-5 * np.max(np.abs(h))


@pytest.mark.parametrize("kind", ["two-mode", "single-mode"])
def test_mechanical_filters_are_causal(kind):
    """The response to an impulse comes after it (the FFT sign convention is right): all but
    a small Gibbs precursor (the responses are cut at Nyquist) lies after the impulse."""
    s = FeatureSettings(bins=4, filterbank=kind)
    u = np.zeros(8000)
    u[4000] = 1.0
    y = filterbank(u, RATE, s)
    energy_before = np.sum(y[:, :4000] ** 2, axis=1)
    assert np.all(energy_before < 1e-2 * np.sum(y**2, axis=1))
    assert np.abs(y[:, :3900]).max() < 1e-3 * np.abs(y).max()


def test_mechanical_filters_are_peak_normalised():
    f = np.linspace(10, 8000, 40000)
    for kind in ("two-mode", "single-mode"):
        h = filter_responses(f, FeatureSettings(bins=8, filterbank=kind))
        assert np.allclose(np.abs(h).max(axis=1), 1.0, atol=1e-3)


def test_features_are_homogeneous_of_degree_two_thirds():
    """Linear filters, |y|^(2/3), linear low-pass: scaling the input by a scales x by a^(2/3)."""
    rng = np.random.default_rng(0)
    u = rng.normal(size=16000)
    s = FeatureSettings(bins=4, delays=2)
    x1, x8 = features(u, RATE, s), features(8 * u, RATE, s)
    assert np.allclose(x8, 4 * x1, rtol=1e-4, atol=1e-5 * x1.max())


def test_features_grid_covers_the_delayed_horizon():
    s = FeatureSettings(bins=4, delays=3)
    x = features(np.zeros((2, 16000)), RATE, s)
    assert horizon(s, 1.0) == pytest.approx(1.064)
    assert x.shape == (2, 4, 1065)
    assert np.all(x == 0)


def test_tone_at_a_mel_centre_lights_its_own_bin():
    s = FeatureSettings(bins=8, filterbank="triangular")
    centres = filters.mel_edges(8)[1:-1]
    t = np.arange(16000) / RATE
    tones = np.stack([np.sin(2 * np.pi * f * t) for f in centres])
    x = features(tones, RATE, s)
    energy = x[:, :, 200:900].mean(axis=-1)
    assert np.array_equal(np.argmax(energy, axis=1), np.arange(8))
    # the steady level is |H|^(2/3) times the mean of |sin|^(2/3) = Gamma(5/6)/(sqrt(pi) Gamma(4/3))
    from scipy.special import gamma
    level = gamma(5 / 6) / (np.sqrt(np.pi) * gamma(4 / 3))
    assert np.allclose(np.diag(energy), level, rtol=2e-2)


@pytest.mark.parametrize("change,message", [
    (dict(bins=1), "--bins"),
    (dict(delays=0), "--delays"),
    (dict(filterbank="gammatone"), "unknown filterbank"),
    (dict(td=0.0315), r"td \* feature rate"),
    (dict(feature_rate=3000.0), "sample rate / feature rate"),
    (dict(fmax=9000.0), "Nyquist"),
    (dict(tau=-1.0), "positive"),
])
def test_bad_settings_are_user_errors(change, message):
    s = FeatureSettings(**change)
    with pytest.raises(UsageError, match=message):
        features(np.zeros(1600), RATE, s)
