"""netlists/lib/featurechain.spr: one channel of the feature extraction of the paper's Fig. 7a
(filter, quadratic coupling into the low-pass mass, fan-out into delay lines)."""

from __future__ import annotations

import pytest

from springc.design import figures
from springc.check.compiler import build


@pytest.fixture(scope="module")
def chain():
    return figures.experiment_features()


def test_delayed_copies_are_td_apart(chain):
    """The far ends of lines 1 and 2 (4 and 8 sites of td/4) lag each other by td within 3%
    (measured 0.998 td); line 1 lags the low-pass mass by about td (measured 1.09 td: the
    heavy, damped low-pass mass is not a line site)."""
    assert chain.arrival[1] - chain.arrival[0] == pytest.approx(chain.td, rel=0.03)
    assert chain.arrival[0] - chain.arrival_lp == pytest.approx(chain.td, rel=0.15)


def test_feature_is_the_rectified_envelope(chain):
    """Squaring makes the feature one-signed (up to a 0.1% undershoot as the lines pull back)
    although the filter output oscillates; the lines are matched, so the copies keep the
    feature's height (within 5%)."""
    assert chain.x_f.min() < -0.5 * chain.x_f.max()
    assert chain.lp.min() > -0.01 * chain.lp.max()
    assert chain.delayed.max(axis=1) == pytest.approx(chain.lp.max(), rel=0.05)


def test_chain_passes_the_checks(tmp_path):
    """`springc build` accepts the library defaults (the low-pass damping leaves room for the
    lines' impedance) and counts the parts: 2 filter masses, the low-pass mass, 4 + 8 sites."""
    net = tmp_path / "c.spr"
    net.write_text('.include "featurechain.spr"\nXc lp featurechain\n.tran 3.125e-5 0.1\n')
    report = build(net)
    assert report.dofs == 2 + 1 + 4 + 8
    assert report.elements["Q"] == 1 and report.elements["B"] == 2
    assert report.instances_by_subckt == {"featurechain": 1, "melfilter": 1, "squarer": 1,
                                          "lowpass": 1, "delayline": 2}


def test_too_little_lowpass_damping_is_an_error(tmp_path):
    """A soft low-pass spring cannot supply the lines' impedance: negative local damping."""
    from springc.errors import NetlistError

    net = tmp_path / "c.spr"
    net.write_text('.include "featurechain.spr"\nXc lp featurechain klp=1\n')
    with pytest.raises(NetlistError) as err:
        build(net)
    assert "b" in err.value.format() and "lowpass.spr" in err.value.format()
