"""The keyword spotter as a fabricated device (`springc.kws.evaluation.device`): the spread
transform at netlist level (zero spread is the design, seeds reproduce, the factors have the
requested statistics and are the language's draws), the physical-scale transform (without
noise the features and decisions of the normalised network, after converting units), and
`springc eval`'s refusals of bad options."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.signal import chirp

from springc.check import check
from springc.errors import UsageError
from springc.kws.evaluation import device as dv
from springc.kws.features import integration
from springc.kws.features import massspring as msp
from springc.kws.training import transfer as tr
from springc.lang import load_text, parse, read_variation
from springc_cli.main import main
from shared_cache import KERNELS

S = msp.MassSpringSettings(bins=2, delays=1)


@pytest.fixture(scope="module")
def heads():
    return tr.stand_in_heads(S, rows=2)


@pytest.fixture(scope="module")
def net(heads):
    return load_text(tr.classifier_text(heads, S, epsilon=tr.DEFAULT_EPSILON), "<classifier>")


def coefficients(net) -> dict[tuple[str, str], np.ndarray]:
    return {(t, k): getattr(getattr(net, t), k) for t, k in dv.FABRICATED}


def test_every_element_of_the_classifier_has_a_stage(net):
    seen = set()
    for table, _ in dv.FABRICATED:
        found = dv.stages(net, table)
        assert "" not in found
        seen |= set(found)
    assert seen == set(dv.STAGES)
    assert dv.stage_of("Xh3.Xm.M2") == "couplings" and dv.stage_of("Xh0.Qy1") == "couplings"
    assert dv.stage_of("Xh1.Xr.Mr") == "readouts" and dv.stage_of("Xd1_0.Min") == "delays"
    assert dv.stage_of("Xq0.Qsq") == "compressors" and dv.stage_of("Mstray") is None


@pytest.mark.parametrize("design", [tr.Design("summing"), tr.BUFFERED],
                         ids=["summing", "buffered"])
def test_every_element_of_a_device_design_has_a_stage(design):
    """Summing heads (their nodes and springs are the couplings) and buffered taps (their
    springs are the delays'): `--mc --stage` spreads every element of these too."""
    heads = tr.heads_for([(("c0", "c1"), _rows())],
                         S, 1e-3, tr.DEFAULT_EPSILON, design)
    net = load_text(tr.classifier_text(heads, S, design=design), "<device classifier>")
    for table, _ in dv.FABRICATED:
        assert "" not in dv.stages(net, table)
    assert dv.stage_of("Xh0.Ms3") == "couplings" and dv.stage_of("Xh1.Cs2_5") == "couplings"


def _rows():
    from springc.kws.features.phi import n_features
    from springc.kws.training.svm import LinearModel

    rng = np.random.default_rng(0)
    n = n_features(S.bins, S.delays)
    return LinearModel(rng.normal(size=(2, n)), rng.normal(size=2), np.array(["c0", "c1"]))


def test_zero_spread_is_the_nominal_design_bit_for_bit(net):
    assert dv.fabricate(net, dv.Spread(0.0, seed=3), 5).text() == net.text()
    for (t, k), v in coefficients(dv.fabricate(net, dv.Spread(0.0, "global"), 2)).items():
        assert np.array_equal(v, getattr(getattr(net, t), k))


def test_one_stage_spreads_its_own_coefficients_only(net):
    device = dv.fabricate(net, dv.Spread(0.05, stage="readouts"), 1)
    changed = 0
    for (t, k), v in coefficients(device).items():
        inside = dv.stages(net, t) == "readouts"
        nominal = getattr(getattr(net, t), k)
        assert np.array_equal(v[~inside], nominal[~inside])
        changed += int(np.sum(v[inside] != nominal[inside]))
    assert changed > 0


def test_the_same_seed_makes_the_same_devices(net):
    spread = dv.Spread(0.01, seed=11)
    a, b = dv.fabricate(net, spread, 4), dv.fabricate(net, spread, 4)
    assert a.text() == b.text()
    assert dv.fabricate(net, spread, 5).text() != a.text()
    assert dv.fabricate(net, dv.Spread(0.01, seed=12), 4).text() != a.text()


def test_local_factors_have_the_requested_mean_and_deviation(net):
    sigma = 0.003
    f = np.concatenate([v.ravel() for v in
                        dv.factors(net, dv.Spread(sigma), np.arange(300)).values()])
    n = f.size
    assert n > 30000
    assert abs(f.mean() - 1) < 3 * sigma / math.sqrt(n)
    assert abs(f.std() - sigma) < 3 * sigma / math.sqrt(2 * n)
    # independent per element: two elements' factors over the devices are uncorrelated
    m = dv.factors(net, dv.Spread(sigma), np.arange(300))[("masses", "m")]
    assert abs(np.corrcoef(m[:, 0], m[:, 1])[0, 1]) < 3 / math.sqrt(300)


def test_global_factors_draw_once_per_kind(net):
    sigma = 0.02
    table = dv.factors(net, dv.Spread(sigma, "global"), np.arange(3000))
    springs, masses = table[("springs", "k")], table[("masses", "m")]
    assert np.all(springs == springs[:, :1]) and np.all(masses == masses[:, :1])
    assert not np.array_equal(springs[:, 0], masses[:, 0])
    z = springs[:, 0]
    assert abs(z.mean() - 1) < 3 * sigma / math.sqrt(len(z))
    assert abs(z.std() - sigma) < 3 * sigma / math.sqrt(2 * len(z))


def test_a_device_is_gauss_written_in_every_element_value():
    """Device k's coefficient is what `.mc` sample k draws for gauss(nom, S) written in the
    same element's value (nom (1 + S z) against nom + |nom| S z: round-off apart)."""
    text = "X1 a cell\n.subckt cell a\nM1 a m={{{m}}} b=0.5\nK1 a k=3\n.ends cell\n.tran 1m 10m\n"
    random = read_variation(parse(text.format(m="gauss(2, 0.05)") + ".mc 4 seed=7\n", "<r>"))
    nominal = load_text(text.format(m="2"), "<n>")
    for point in random.points():
        want = random.netlist(point).masses.m
        got = dv.fabricate(nominal, dv.Spread(0.05, seed=7), point.sample).masses.m
        np.testing.assert_allclose(got, want, rtol=1e-14)
        assert got[0] != 2.0


def test_a_spread_too_wide_for_a_factor_is_refused(net):
    with pytest.raises(UsageError, match="too wide"):
        dv.fabricate(net, dv.Spread(1.0), 0)


def test_physical_scale_sets_the_acoustic_force_and_every_mass(net):
    phys = dv.Physical(temp=300.0, mass=1e-9, spl=60.0, area=1e-6)
    scaled, lam = dv.physical_network(net, phys)
    driven = np.array([s.kind == "in" for s in net.forces.source])
    gains = scaled.forces.gain[driven]
    assert np.isclose(np.abs(gains).max(), 20e-6 * 1e3 * 1e-6, rtol=1e-12)  # p A at 60 dB
    np.testing.assert_allclose(scaled.masses.m, 1e-9 * net.masses.m, rtol=1e-15)
    # the in gains are the scaled ones: the displacement scale is what the force implies
    np.testing.assert_allclose(gains, net.forces.gain[driven] * 1e-9 * lam, rtol=1e-12)


def words() -> np.ndarray:
    """Two 0.12 s chirps at 16 kHz, at the level of the corpus's clips."""
    t = np.arange(1920) / 16000
    env = np.sin(np.pi * t / 0.12) ** 2
    return np.stack([0.3 * env * chirp(t, 300, 0.12, 2500, method="logarithmic"),
                     0.5 * env * chirp(t, 2500, 0.12, 300, method="logarithmic")])


@pytest.fixture(scope="module")
def _kernel_cache():
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("SPRINGC_CACHE", str(KERNELS))
        yield


def test_without_noise_the_physical_network_is_the_normalised_one(_kernel_cache):
    """Phi of the feature network (2 x 1) at physical scale, divided by lambda^2, is Phi of
    the normalised network (the kernel of test_kws_integration's RK4 x16 reference)."""
    net = msp.feature_network(S)
    plan = integration.Integration("rk4", 16, "float64")
    sig = words()
    items = np.column_stack([np.arange(len(sig)), sig])
    tstop = msp.horizon(S, sig.shape[1] / msp.INPUT_RATE)

    def phi(network, temp=None):
        return dv.network_batch(items, check(network), [msp.phi_reduction(network, S)],
                                tstop, plan, S, temp=temp)["phi"]

    phys = dv.Physical(temp=0.0, mass=1e-9, spl=60.0, area=1e-6)
    scaled, lam = dv.physical_network(net, phys)
    ref, got = phi(net), phi(scaled, phys.temp) / lam**2
    assert lam < 1e-6 and np.abs(ref).max() > 0
    assert np.abs(got - ref).max() < 1e-9 * np.abs(ref).max()


def test_devices_in_the_lanes_of_one_call_are_each_device_alone(net, heads):
    """`eval --mc`'s population: three fabricated 2x1 classifiers on two clips in the lanes
    of one kernel call give each device's readouts as its own call does."""
    spread = dv.Spread(1e-3, seed=3)
    devices = [check(dv.fabricate(net, spread, k), judge_step=False) for k in range(3)]
    plan = integration.Integration("rk4", 16, "float64")
    sig = words()
    items = np.column_stack([np.arange(len(sig)), sig])
    tstop = msp.horizon(S, sig.shape[1] / msp.INPUT_RATE)
    specs = tr.readout_reductions(heads)
    together = dv.devices_batch(items, devices, specs, tstop, plan, S)
    for p, device in enumerate(devices):
        alone = dv.network_batch(items, device, specs, tstop, plan, S, judged=False)
        for key, value in alone.items():
            assert together[key].shape[:2] == (2, 3)
            scale = np.abs(value).max()
            assert scale > 0 and np.abs(together[key][:, p] - value).max() <= 1e-12 * scale
    # the devices differ: the spread moves every readout
    assert np.abs(together["final:x(r0)"][:, 0] - together["final:x(r0)"][:, 1]).max() > 0


def test_a_device_that_diverges_at_every_retry_fails_alone(net, heads):
    """A device whose masses are a millionth of the design's (modes 1000x faster than any
    retry's step can follow) has NaN rows; the device beside it in the call is unharmed."""
    good = check(dv.fabricate(net, dv.Spread(1e-3, seed=3), 0), judge_step=False)
    light = replace(net, masses=replace(net.masses, m=net.masses.m * 1e-6))
    bad = check(light, judge_step=False)
    plan = integration.Integration("rk4", 16, "float64")
    sig = words()
    items = np.column_stack([np.arange(len(sig)), sig])
    tstop = msp.horizon(S, sig.shape[1] / msp.INPUT_RATE)
    specs = tr.readout_reductions(heads)
    together = dv.devices_batch(items, [good, bad], specs, tstop, plan, S)
    alone = dv.network_batch(items, good, specs, tstop, plan, S, judged=False)
    for key, value in alone.items():
        assert np.isnan(together[key][:, 1]).all()
        np.testing.assert_allclose(together[key][:, 0], value, rtol=1e-12, atol=0)


def test_the_snr_of_the_features():
    clean = np.array([[1.0, 2.0], [3.0, -4.0]])
    snr = dv.phi_snr_db(clean, clean * 1.1)  # noise a tenth of the signal: 20 dB everywhere
    assert snr == pytest.approx({"median": 20.0, "worst": 20.0, "pooled": 20.0})


@pytest.mark.parametrize("args, message", [
    (["--temp", "-1", "--mass", "1e-9", "--spl", "60", "--area", "1e-6"],
     "--temp must be a finite temperature >= 0 K, not -1"),
    (["--temp", "nan", "--mass", "1e-9", "--spl", "60", "--area", "1e-6"], "not nan"),
    (["--temp", "300", "--mass", "0", "--spl", "60", "--area", "1e-6"],
     "--mass must be a positive finite number of kg, not 0"),
    (["--temp", "300", "--mass", "1e-9", "--spl", "inf", "--area", "1e-6"],
     "--spl must be a finite level in dB"),
    (["--temp", "300", "--mass", "1e-9", "--spl", "60", "--area", "-1e-6"],
     "--area must be a positive finite number of m^2"),
    (["--temp", "300"], "--temp also needs --mass and --spl and --area"),
    (["--mc", "4"], "--mc also needs --spread"),
    (["--spread", "0.01"], "--spread also needs --mc"),
    (["--mc", "4", "--spread", "-0.01"], "--spread must be a finite relative deviation >= 0"),
    (["--mc", "0", "--spread", "0.01"], "--mc must be at least 1 device, not 0"),
    (["--mc", "2", "--spread", "0.01", "--seed", "-1"], "--seed must be an integer from 0"),
    (["--mc", "2", "--spread", "0.01", "--temp", "300"], "are separate studies"),
    (["--seed", "3"], "--seed draws the devices of --mc or the noise of --temp"),
    (["--clips", "3"], "--clips goes with --mc or --temp"),
    (["--trim", "8"], "--trim trims fabricated devices"),
    (["--mc", "2", "--spread", "0.01", "--trim", "1"], "--trim must measure at least 2 clips"),
])
def test_bad_options_exit_1_with_a_clear_message(tmp_path, args, message):
    result = CliRunner().invoke(main, ["eval", str(tmp_path / "model"), *args])
    assert result.exit_code == 1, result.output
    assert message in result.output and "Traceback" not in result.output
