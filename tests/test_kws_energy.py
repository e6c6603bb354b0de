"""The energy budget of the mass-spring feature network: it closes (work in = dissipated +
left); the low-pass stage's share follows passive squaring at every amplitude (the filters
stay linear), and the terminals' share, after the compressors, squares below the compression
threshold and falls with amplitude above it (paper Fig. 5)."""

import numpy as np

from springc.kws.evaluation import energy
from springc.kws.features import massspring as msp


def test_budget_of_the_feature_network():
    s = msp.MassSpringSettings(bins=2, delays=2)
    net = msp.feature_network(s)
    t = np.arange(4000) / msp.INPUT_RATE
    f = msp.filters(s)[0].centre
    amps = (1e-5, 1e-4, 1e-2, 1e-1)  # threshold A_c = 1e-3 of filter output (peak gain 1)
    sig = np.stack([a * np.sin(2 * np.pi * f * t) * np.hanning(len(t)) for a in amps])
    parts = energy.run_budget(net, sig, 0.3)
    # the delay-line sites are lossless: their energy is dissipated in the terminals
    assert list(parts) == ["work in", "Mel filters", "low-pass masses", "compressors",
                           "terminals", "left at the end"]
    assert np.all(energy.check_balance(parts) < 1e-6)  # measured 1.04e-7 (RK4 at 128 kHz)
    # squaring: output energy ~ a^4, input work ~ a^2, so the share grows 100x per decade;
    # in the low-pass at every amplitude (measured 100.0 and 99.5)
    share = parts["low-pass masses"] / parts["work in"]
    assert abs(share[1] / share[0] - 100) < 1 and abs(share[3] / share[2] - 100) < 2
    # after the compressors: squaring below the threshold (1e-3), and above it
    # y^2 -> (y^2)^(1/3), terminal energy ~ a^(4/3), share ~ a^(-2/3): 0.22x per decade
    # (measured 100.0 and 0.20)
    share = parts["terminals"] / parts["work in"]
    assert abs(share[1] / share[0] - 100) < 1
    assert 0.1 < share[3] / share[2] < 0.35
    rows = energy.budget_table(parts)
    assert rows[2].startswith("| work in |") and len(rows) == 2 + len(parts)
