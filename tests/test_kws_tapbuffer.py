"""Buffered delay taps (springc.kws.training.tapbuffer): the buffer's gain and the load it puts
on a matched line's terminal against their linear analytics, and a buffered classifier that
passes the checks. Linear analyses and checks only: no kernel is compiled."""

import numpy as np
import pytest
import springc

from springc.check import CheckedNetlist, check
from springc.design.emit import SprWriter
from springc.kws.features import massspring as msp
from springc.kws.training import tapbuffer as tb
from springc.kws.training import transfer as tr
from springc.lang import load_text

S = msp.MassSpringSettings(bins=2, delays=2)
F_HZ = (0.5, 2.0, 8.0)  # the features' envelopes


def line_text(buffer: tb.TapBuffer | None) -> str:
    """A matched line driven at its input, its terminal f0_0 terminated as the feature network
    does, with the buffer (its node given a head's mass and damping) or without."""
    w = SprWriter()
    w.title("a matched line into one (buffered) tap")
    w.include("delayline.spr")
    w.params(ts=S.site_delay, kc=S.kc)
    w.statement("Xd", "in", "o", "delayline", "n=8", "td={ts}", "kc={kc}", "term=0",
                "term_in=1")
    w.statement("Ct", "o", "f0_0", "k={kc}")
    w.statement("Fin", "in", "in(0)")
    if buffer is None:
        w.statement("Mf0_0", "f0_0", "m={ts**2 * kc / 2}", "b={ts * kc}")
    else:
        tb.write(w, msp.MassSpringSettings(bins=1, delays=1), buffer)
        w.statement("Mu", "u0_0", "m={ts**2 * kc / 2}", "b={ts * kc}")
    return w.text()


def response(text: str, node: str) -> np.ndarray:
    net = springc.load(text)
    return np.array([net.ac(node, fmin=f, fmax=f * 1.0001, points=2).h[0] for f in F_HZ])


@pytest.fixture(scope="module")
def plain() -> np.ndarray:
    return response(line_text(None), "f0_0")


def buffer_terms(buf: tb.TapBuffer) -> tuple[float, np.ndarray]:
    """kb kc and the buffer node's own dynamic stiffness kg kc + i w b - w^2 m at F_HZ."""
    w = 2 * np.pi * np.array(F_HZ)
    m, b = S.site_mass() / 2, S.line_damping()
    return buf.kb * S.kc, buf.kg * S.kc + 1j * w * b - w**2 * m


@pytest.mark.parametrize("kb, kg", [(6e-5, 1000.0), (1e-2, 10.0)])
def test_buffer_node_is_gain_times_tap(kb, kg):
    """u = kb kc f / (kb kc + kg kc + i w b - w^2 m), the buffer node's equation of motion,
    which is g f (g = kb / (kb + kg)) below its resonance: within 1e-9."""
    buf = tb.TapBuffer(kb, kg)
    text = line_text(buf)
    ratio = response(text, "u0_0") / response(text, "f0_0")
    k_b, own = buffer_terms(buf)
    assert np.max(np.abs(ratio / (k_b / (k_b + own)) - 1)) < 1e-9
    assert np.max(np.abs(ratio / buf.gain - 1)) < 0.02


def test_tap_load_is_the_series_spring(plain):
    """The matched terminal sees the line as a dashpot Z = t_s kc and has its own, so the
    buffer, kb kc in series with the buffer node's own stiffness, takes the tap from
    F / (2 i w Z) to F / (2 i w Z + k): the measured ratio within 1% of that deviation plus
    2 (w t_s)^3, the order of the line's dispersion that the dashpot model leaves out."""
    k_b, own = buffer_terms(tb.TapBuffer(1e-2, 10.0))
    k = k_b * own / (k_b + own)
    two_iwz = 2j * 2 * np.pi * np.array(F_HZ) * S.line_damping()
    expected = two_iwz / (two_iwz + k)
    got = response(line_text(tb.TapBuffer(1e-2, 10.0)), "f0_0") / plain
    w_ts = 2 * np.pi * np.array(F_HZ) * S.site_delay
    assert np.all(np.abs(got - expected) < 1e-2 * np.abs(1 - expected) + 2 * w_ts**3)
    assert np.max(np.abs(1 - expected)) > 0.1  # the load is visible at 0.5 Hz


def test_buffered_classifier_passes_checks():
    """The whole classifier with buffered taps: heads on the buffer nodes, checks pass, and
    the heads' decision scale is g^2 the plain one's."""
    buf = tb.TapBuffer(6e-5, 1000.0)
    heads = tr.stand_in_heads(S, rows=2)
    moved = tb.rescaled(heads, buf)
    text = tr.classifier_text(moved, S, epsilon=1.0, design=tr.Design(buffer=buf))
    assert "Xh0 u0_0 u0_1 u1_0 u1_1 r0 head0" in text
    assert [h.scale for h in moved] == pytest.approx([h.scale * buf.gain**2 for h in heads])
    assert isinstance(check(load_text(text, "<buffered>")), CheckedNetlist)  # raises if not


def test_bad_buffer_refused():
    with pytest.raises(ValueError, match="kb > 0"):
        tb.TapBuffer(0.0, 1.0)


def test_mvm_stiffness_scales_the_heads_stiff_modes():
    """`mvm_stiffness` multiplies the mvms' stiffness d: their stiff modes, the network's
    fastest, go up by its square root (omega^2 by 10 within the lines' share), the modes of
    the rest stay as many."""
    from springc.check import linear

    heads = tr.stand_in_heads(S, rows=2)
    plain, stiff = (linear.modes(load_text(tr.classifier_text(
        heads, S, epsilon=1.0, design=tr.Design(mvm_stiffness=f)), "<c>")) for f in (1.0, 10.0))
    assert stiff.omega_max**2 / plain.omega_max**2 == pytest.approx(10.0, rel=1e-3)
    assert len(stiff) == len(plain)
