"""netlists/lib/readout.spr: the overdamped leaky-integrator readout (paper Sec. III.B, Fig. 6)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from springc.design import figures
from springc.lang import load_text


@pytest.fixture(scope="module")
def decay():
    return figures.experiment_readout()


def test_decay_time_matches_tau(decay):
    """After a pulse through delay line and quadratic coupling, the readout relaxes with
    tau = 2Q / (w (1 - sqrt(1 - 4Q^2))) = 80 s (Q = 0.01): within 2% (measured 0.09%)."""
    assert decay.tau_measured == pytest.approx(decay.tau_design, rel=0.02)


def test_readout_integrates_the_squared_pulse(decay):
    """x_r rises while the pulse passes and is positive (driven by g x_l^2)."""
    assert decay.x_r.min() >= -1e-12 * decay.x_r.max()
    rise = decay.t[np.argmax(decay.x_r)]
    assert rise < 1.0 < decay.tau_design


def test_paper_numbers_and_external_stiffness():
    """w_r ~ 1.25 rad/s for tau = 80 s; kext is taken off the local spring."""
    net = load_text('.include "readout.spr"\nXr r readout tau=80 qr=0.01 m=2 kext=1\n')
    w = (1 + math.sqrt(1 - 4e-4)) / (2 * 0.01 * 80)
    assert w == pytest.approx(1.25, abs=1e-3)
    assert net.masses.b[0] == pytest.approx(2 * w / 0.01)
    assert net.springs.k[0] == pytest.approx(2 * w**2 - 1)
