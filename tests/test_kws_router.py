"""The router (`springc.kws.features.router`, `springc train --realisation router`): its
weights decide as the classifier does, its readouts split the filters' energy exactly, the
energy balance closes, and its physical scale converts back exactly; the commands train and
evaluate it, sound to decision."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.signal import chirp

from kws_corpora import corpus_and_model
from springc.check import check
from springc.kws.evaluation import device as dv, energy, router as rev
from springc.kws.features import router as rt
from springc.sim.simulate import simulate
from springc_cli.main import main

SMALL = rt.RouterSettings(bins=4)


def sound(seconds: float = 0.2, seed: int = 0) -> np.ndarray:
    """Two test signals: a chirp across the bank and a noise burst."""
    t = np.arange(int(seconds * rt.INPUT_RATE)) / rt.INPUT_RATE
    noise = np.random.default_rng(seed).normal(size=len(t)) * np.hanning(len(t))
    return np.stack([chirp(t, 100, seconds, 6000, method="logarithmic"), noise])


def test_router_weights_decide_as_the_classifier():
    """W >= 0, no filter hands on more than its damping, and argmax W . D = argmax coef . D
    for every D >= 0 (shifting a column moves every score alike)."""
    rng = np.random.default_rng(1)
    coef = rng.normal(size=(12, 8))
    w = rt.router_weights(coef)
    d = rng.exponential(size=(2000, 8))
    assert (w >= 0).all() and w.sum(axis=0).max() == pytest.approx(1.0, abs=1e-15)
    rt.router_network(SMALL, rt.router_weights(coef[:, :SMALL.bins]))  # every keep >= 0
    never = coef.copy()
    never[0] -= 100.0  # a class that never wins gets no readout dashpots
    assert not rt.router_weights(never)[0].any()
    np.testing.assert_array_equal(np.argmax(d @ w.T, axis=1), np.argmax(d @ coef.T, axis=1))


def test_the_readouts_split_the_filters_energy_exactly():
    """Readout r of the router dissipates sum_i W[r, i] D_i, D from the bare filterbank: the
    two networks move alike (each mass keeps its total damping), so the only difference is
    rounding in the force sums; and the budget closes (work in = dissipated + left) to what
    RK4 x8 integrates, fifth order in the step (4e-5 on speech, 3e-7 at x16)."""
    w = rt.router_weights(np.random.default_rng(2).normal(size=(3, SMALL.bins)))
    net = rt.router_network(SMALL, w)
    x = sound()
    e = rev.readouts(net, x, 3)["E"]
    d = rt.filter_energies(x, SMALL)
    np.testing.assert_allclose(e, d @ w.T, rtol=1e-9)
    res = simulate(check(net), x[:, None, :], rt.INPUT_RATE, probes=[],
                   reductions=energy.budget_reductions(net),
                   tstop=x.shape[1] / rt.INPUT_RATE + rt.RING_OUT, batch=len(x))
    parts = energy.budget(net, res.reductions)
    assert set(parts) == {"work in", "Mel filters", "readouts", "left at the end"}
    assert energy.check_balance(parts).max() < 1e-3
    assert energy.readout_count(net) == 3


def test_at_physical_scale_without_noise_the_readouts_convert_back():
    """At 0 K the physical network is the normalised one in other units: its readouts over
    mu lambda^2 are the normalised readouts (`springc.design.scale`) to rounding."""
    w = rt.router_weights(np.random.default_rng(3).normal(size=(3, SMALL.bins)))
    net = rt.router_network(SMALL, w)
    phys = dv.Physical(temp=0.0, mass=1e-10, spl=60.0, area=1e-6)
    pnet, lam = dv.physical_network(net, phys)
    x = sound()
    np.testing.assert_allclose(rev.readouts(pnet, x, 3)["E"] / (phys.mass * lam**2),
                               rev.readouts(net, x, 3)["E"], rtol=1e-9)


def test_in_silence_each_readout_dissipates_its_equipartition_share():
    """A router's dark offsets (`dark_offsets`: what each readout dissipates with no sound, at
    300 K) against equilibrium statistics: every velocity has variance k_B T / m
    (Maxwell-Boltzmann, whatever the springs), so a readout dashpot b to ground from a mass m
    dissipates b k_B T / m on average, for the clips' whole simulated time (they start at
    rest; the filters' damping, alpha >= 3000 rad/s, brings them to equilibrium within a
    millisecond of the 250 ms). The simulated force is white only up to its step h (a draw
    held over each substep, `springc.sim.thermal`): a mass damped at rate alpha then reaches
    k_B T / m (1 - alpha h / 3) to first order, alpha h / 3 up to 8% here. Bound: that deficit
    for the most damped mass a readout reads, plus four standard errors of the mean over the
    silent clips, measured from the clips themselves."""
    from springc.sim.thermal import K_B

    w = rt.router_weights(np.random.default_rng(4).normal(size=(3, SMALL.bins)))
    phys = dv.Physical(temp=300.0, mass=1e-10, spl=60.0, area=1e-6)
    pnet, _ = dv.physical_network(rt.router_network(SMALL, w), phys)
    samples = 3200
    seconds = samples / rt.INPUT_RATE + rt.RING_OUT
    dark = rev.dark_offsets(pnet, 3, samples, phys.temp, seed=5)
    clips = rev.readouts(pnet, np.zeros((rev.DARK_CLIPS, samples)), 3, temp=phys.temp,
                         seed=5 + rev.DARK_SEED)["E"]
    np.testing.assert_array_equal(dark, clips.mean(axis=0))
    mass, d = pnet.mass(), pnet.dashpots
    damping = pnet.local_damping().copy()
    assert (d.j < 0).all()  # a router's dashpots all run to ground from their i end
    np.add.at(damping, d.i, d.b)
    alpha = damping / mass
    h = 1 / rt.INPUT_RATE / rt.SUBSTEPS
    want, deficit = np.zeros(3), np.zeros(3)
    for name, i, j, b in zip(d.names, d.i, d.j, d.b):
        found = rt.READOUT.match(name)
        if found:
            r = int(found.group(1))
            want[r] += b * K_B * phys.temp / mass[i] * seconds
            deficit[r] = max(deficit[r], alpha[i] * h / 3)
    assert (want > 0).all() and deficit.max() < 0.1
    sem = clips.std(axis=0, ddof=1) / np.sqrt(rev.DARK_CLIPS)
    assert np.all(np.abs(dark - want) < deficit * want + 4 * sem), (dark / want, deficit)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A 4-bin router trained on the tiny corpus of chirps and tones, built for a 1e-10 kg
    device hearing 70 dB SPL."""
    return corpus_and_model(tmp_path_factory.mktemp("router"), "--realisation", "router",
                            "--spl", "70", "--device-mass", "1e-10")


def test_train_and_eval_simulate_the_router_sound_to_decision(trained):
    """`springc eval` of a router model simulates router.spr: its decisions are the model's
    on the simulated features (readout error at rounding), its insertion loss positive, and
    `--budget` locates the energy in the filters' and the readouts' dampers."""
    data, model = trained
    settings = json.loads((model / "settings.json").read_text())
    assert settings["classifier"].endswith("without intercept")
    assert "router.spr" in (model / "README.md").read_text()
    out = CliRunner().invoke(main, ["eval", str(model), "--json"])
    assert out.exit_code == 0, out.output
    report = json.loads(out.output)
    assert report["accuracy"] == report["digital_same_model"]["accuracy"]
    assert report["readout_error"] < 1e-9
    assert report["insertion_loss_db"]["median"] > 0
    out = CliRunner().invoke(main, ["eval", str(model), "--budget", "2", "--json"])
    assert out.exit_code == 0, out.output
    budget = json.loads(out.output)
    stages = budget["stages"]
    assert stages["readouts"]["db_of_work"] < 0 and stages["Mel filters"]["j"] > 0
    # the physical scale the model was trained for, recorded and used where none is given
    assert settings["device"] == {"spl": 70.0, "area": 1e-6, "temp": 300.0,
                                  "device_mass": 1e-10}
    assert budget["scale"]["spl"] == 70.0
    assert budget["scale"]["device_mass"] == pytest.approx(1e-10, rel=1e-12)
    assert "--spl 70 --area 1e-06 --temp 300 --device-mass 1e-10" in (
        model / "README.md").read_text()


def test_a_router_population_at_no_spread_is_its_nominal_design(trained):
    """`--mc 2 --spread 0`: every device is the nominal network, so each scores its
    accuracy with a decision error of 0."""
    _, model = trained
    out = CliRunner().invoke(main, ["eval", str(model), "--mc", "2", "--spread", "0",
                                    "--clips", "6", "--json"])
    assert out.exit_code == 0, out.output
    report = json.loads(out.stdout)  # progress goes to stderr
    assert [d["accuracy"] for d in report["devices"]] == [report["nominal"]] * 2
    assert [d["decision_error"] for d in report["devices"]] == [0.0, 0.0]


def test_thermal_noise_reports_the_decision_with_dark_offsets_subtracted(trained):
    """`--temp` on a router model (at the scale it recorded): the accuracy with noise, and
    beside it the calibrated one (each readout's mean on silent clips subtracted), both
    printed; the offsets are positive energies, one per readout."""
    _, model = trained
    out = CliRunner().invoke(main, ["eval", str(model), "--temp", "300", "--clips", "8",
                                    "--json"])
    assert out.exit_code == 0, out.output
    report = json.loads(out.stdout)
    cal = report["calibrated"]
    assert cal["dark_clips"] == rev.DARK_CLIPS and 0 <= cal["accuracy"] <= 1
    classes = json.loads((model / "report.json").read_text())["classes"]
    assert len(cal["offsets"]) == len(classes) and min(cal["offsets"]) > 0
    assert report["device_mass"] == pytest.approx(1e-10, rel=1e-12)  # as recorded
    text = dv.physical_lines(report, dv.Physical(temp=300.0, mass=report["mass"], spl=70.0,
                                                 area=1e-6))
    assert f"silent clips subtracted: accuracy {100 * cal['accuracy']:.2f}%" in text[-1]


def test_the_router_refuses_what_it_cannot_be(trained, tmp_path):
    """Binary digit pairs (the router decides by the largest readout) and a trim."""
    data, model = trained
    out = CliRunner().invoke(main, ["train", "--data", str(data), "--realisation", "router",
                                    "--task", "digits-pairs", "-o", str(tmp_path / "m")])
    assert out.exit_code == 1 and "kws12" in out.output and "Traceback" not in out.output
    out = CliRunner().invoke(main, ["eval", str(model), "--mc", "2", "--spread", "0.01",
                                    "--trim", "4"])
    assert out.exit_code == 1 and "router has none" in out.output
