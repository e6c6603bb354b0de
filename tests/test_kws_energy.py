"""The energy budget of the mass-spring feature network: it closes (work in = dissipated +
left); the low-pass stage's share follows passive squaring at every amplitude (the filters
stay linear), and the terminals' share, after the compressors, squares below the compression
threshold and falls with amplitude above it (paper Fig. 5)."""

import numpy as np
import pytest

from springc.errors import UsageError
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


def test_the_sound_and_the_bound_are_the_anchors_figures():
    """../shared/design/device-anchors.md (derived there, rounded to two digits): 60 dB SPL
    on 1 mm^2 for one second is about 1 pJ, 2.4e8 k_B T at 300 K, and twelve readouts of 100
    k_B T each leave about 53 dB."""
    scale = energy.Scale.of()
    assert abs(scale.sound(1.0) / 1e-12 - 1) < 0.05
    assert abs(scale.sound(1.0) / scale.kt / 2.4e8 - 1) < 0.03
    assert abs(scale.bound_db(12, 1.0) - 53) < 0.5
    # +20 dB SPL or 100x the area each add 20 dB (the anchors' last line)
    louder = energy.Scale.of(spl=80.0)
    assert abs(louder.bound_db(12, 1.0) - scale.bound_db(12, 1.0) - 20) < 1e-9


def test_joules_per_unit_is_the_physical_networks_energy():
    """The physical network (every mass x mu, displacements x lambda, the input force the
    pressure on the membrane) is the normalised one in other units: its dissipated energy in
    J, simulated, equals the normalised budget times `Scale.joules` (the same arithmetic up to
    rounding: 1e-9)."""
    from springc.check import check
    from springc.kws.evaluation import device
    from springc.lang import load_text
    from springc.sim.simulate import simulate

    net = load_text("M1 a m=2 b=3\nK1 a k=50\nF1 a in(0) gain=4\n.tran 1m 2\n"
                    ".options method=rk4 substeps=4\n")
    scale = energy.Scale.of(device_mass=1e-8, spl=70.0, area=2e-6)
    u = np.sin(2 * np.pi * 3 * np.arange(2001) * 1e-3)[None, None, :]
    specs = ["work:in", "dissipated:all"]
    norm = simulate(check(net), u, reductions=specs).reductions
    phys = device.Physical(0.0, scale.unit_mass(net), scale.spl, scale.area)
    scaled, _ = device.physical_network(net, phys)
    real = simulate(check(scaled), u, reductions=specs).reductions
    for spec in specs:
        assert abs(real[spec][0] / (norm[spec][0] * scale.joules(net)) - 1) < 1e-9


def test_stiffer_stages_receive_that_many_times_the_energy():
    """`massspring.stage_scaled`: every stage after the Mel filters `factor` times stiffer
    (and heavier) is the same equations times the factor, but for the squarer's leverage
    stiffness g a_i on the low-pass, which grows with g and lowers bin i's levels by r_i =
    (1 + a_i) / (1 + factor a_i) (`envelope`). A tone at the upper bin's centre then puts
    factor r_1^2 times the energy into every later stage, below the compression threshold and
    above it, within the share factor a_1 that the leverage adds to the low-pass's stiffness
    (it also moves the low-pass's dynamics; measured 8e-4 of 1.4e-3 and 7e-3 of 1.4e-2), and
    the input work stays as it was: the filters feel the same cubic stiffness (g / a_i is
    unchanged), and the back-action of the stiffer low-pass is 2 g lp / w_a^2 < 1e-8."""
    s = msp.MassSpringSettings(bins=2, delays=2)
    t = np.arange(4000) / msp.INPUT_RATE
    f = msp.filters(s)[1].centre
    sig = np.stack([a * np.sin(2 * np.pi * f * t) * np.hanning(len(t)) for a in (1e-4, 1e-2)])
    plain = energy.run_budget(msp.feature_network(s), sig, 0.3)
    a = msp.leverages(s)[1]
    for factor in (10.0, 100.0):
        parts = energy.run_budget(msp.feature_network(msp.stage_scaled(s, factor)), sig, 0.3)
        assert np.all(np.abs(parts["work in"] / plain["work in"] - 1) < 1e-6)
        want = factor * ((1 + a) / (1 + factor * a)) ** 2
        for stage in ("low-pass masses", "compressors", "terminals"):
            assert np.all(np.abs(parts[stage] / plain[stage] / want - 1) < factor * a), stage
    with pytest.raises(UsageError, match="stage stiffness must be > 0"):
        msp.stage_scaled(s, 0.0)


def test_a_squarer_nearer_its_range_passes_that_much_more():
    """With the stages after it scaled to its leverage (factor a_i = 1, so the low-pass level
    is y^2 / 4 whatever R), the squarer's range R sets how much reaches them: a_i ~ R^2, so
    R / sqrt(100) passes 100 times the energy, as it detunes the filter 100 times more
    ((y / R)^2 of its stiffness, 1e-4 at y = 1e-2 and R = 1: the bound on the change)."""
    from dataclasses import replace

    s = msp.MassSpringSettings(bins=2, delays=2)
    t = np.arange(4000) / msp.INPUT_RATE
    sig = 1e-2 * np.sin(2 * np.pi * msp.filters(s)[1].centre * t) * np.hanning(len(t))
    parts = []
    for squarer_range in (10.0, 1.0):
        r = replace(s, squarer_range=squarer_range)
        net = msp.feature_network(msp.stage_scaled(r, 1 / msp.leverages(r)[1]))
        parts.append(energy.run_budget(net, sig[None], 0.3))
    assert abs(parts[1]["work in"][0] / parts[0]["work in"][0] - 1) < 1e-4
    for stage in ("low-pass masses", "compressors", "terminals"):
        assert abs(parts[1][stage][0] / parts[0][stage][0] / 100 - 1) < 2e-4, stage
    with pytest.raises(UsageError, match="squarer range must be > 0"):
        replace(s, squarer_range=0.0).validate()
