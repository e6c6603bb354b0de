"""The integrator choice of the keyword-spotting networks (springc/kws/features/integration.py): the
cheapest candidate within the tolerance of the reference, measured, never assumed."""

from __future__ import annotations

import numpy as np
import pytest

from springc.check import check
from springc.errors import DataError, DivergedRuns, SimulationError, UsageError
from springc.kws.features import integration
from springc.kws.features import massspring as msp
from springc.check.accuracy import cost

SMALL = msp.MassSpringSettings(bins=2, delays=1)


def _fake(errors: dict, diverge: set, calls: list):
    """outputs(...) that returns the reference plus a known relative error per candidate."""
    base = np.array([[1.0, -2.0, 0.5], [4.0, 0.0, 1.0]])

    def outputs(signals, method, substeps, precision):
        calls.append((method, substeps, precision))
        if (method, substeps) in diverge:
            raise SimulationError("diverged")
        scale = np.abs(base).max(axis=1, keepdims=True)
        return base + errors.get((method, substeps), 0.0) * scale
    return outputs


def test_the_cheapest_candidate_within_tolerance_is_chosen() -> None:
    checked = check(msp.feature_network(SMALL))
    found = integration.candidates(checked, 1 / 16000, 0.5, 1e-3)
    net = checked.net
    assert [cost(net, *c) for c in found] == sorted(cost(net, *c) for c in found)
    assert integration.REFERENCE[:2] not in found or found[-1] == integration.REFERENCE[:2]
    # the cheapest fails the tolerance, the second diverges, the third is taken
    errors = {found[0]: 5e-3, found[2]: 4e-4}
    calls: list = []
    chosen = integration.choose(checked, np.zeros((2, 100)), _fake(errors, {found[1]}, calls),
                                0.5, 1e-3)
    assert (chosen.method, chosen.substeps) == found[2]
    assert chosen.error == pytest.approx(4e-4) and chosen.clips == 2
    assert calls[0] == ("rk4", 16, "float64")  # the reference first, in double precision
    assert [c[:2] for c in calls[1:]] == found[:3]


def test_a_candidate_may_leave_a_few_loud_clips_to_finer_steps() -> None:
    """NaN rows are clips that diverged at the candidate's step: up to a quarter of the
    sample they go to finer steps (the error is measured on the others); more, and the
    candidate is passed over."""
    checked = check(msp.feature_network(SMALL))
    found = integration.candidates(checked, 1 / 16000, 0.5, 1e-3)
    base = np.arange(1.0, 25.0).reshape(8, 3)
    loud = {found[0]: 3, found[1]: 2}

    def outputs(signals, method, substeps, precision):
        out = base * (1 + 1e-4 * ((method, substeps) != integration.REFERENCE[:2]))
        out[:loud.get((method, substeps), 0)] = np.nan
        return out

    chosen = integration.choose(checked, np.zeros((8, 100)), outputs, 0.5, 1e-3)
    assert (chosen.method, chosen.substeps) == found[1]  # 3 of 8 loud: passed over
    assert chosen.error == pytest.approx(1e-4)


def test_no_candidate_is_a_user_error() -> None:
    checked = check(msp.feature_network(SMALL))
    found = integration.candidates(checked, 1 / 16000, 0.5, 1e-3)
    with pytest.raises(UsageError, match="no integrator up to 32 substeps meets"):
        integration.choose(checked, np.zeros((2, 100)),
                           _fake({c: 1e-2 for c in found}, set(), []), 0.5, 1e-3)


def test_every_candidate_is_stable_at_rest() -> None:
    """An eighth of the estimated substeps can fall below the stability limit (here RK4 at a
    1 ms sample step: 8 substeps estimated, 7.8 needed for stability): such a step is no
    candidate, the stable ones are."""
    checked = check(msp.feature_network(SMALL))
    limit = checked.step_limit("rk4").dt
    found = integration.candidates(checked, 1e-3, 0.5, 1e-3, methods=("rk4",))
    assert found and all(1e-3 / sub <= limit * (1 + 1e-9) for _, sub in found)
    assert 1e-3 / 4 > limit  # so the eighth, quarter and half of 8 were dropped


def test_relative_error_is_per_clip() -> None:
    ref = np.array([[1.0, 2.0], [100.0, 0.0]])
    got = ref + np.array([[0.0, 0.002], [0.1, 0.0]])
    assert integration.relative_error(got, ref) == pytest.approx(1e-3)


def test_retries_refine_then_fall_back_to_rk4() -> None:
    plan = integration.Integration("exp-rk4", 2)
    assert plan.retries() == [("exp-rk4", 2), ("exp-rk4", 4), ("exp-rk4", 8), ("rk4", 16),
                              ("rk4", 32)]


def test_only_the_runs_that_diverged_are_simulated_again() -> None:
    # four runs: 1 and 3 are too loud for x2, 3 also for x4; each value records its try
    loud = {2: {1, 3}, 4: {3}, 8: set()}
    calls = []

    def run(method, substeps, idx):
        calls.append((substeps, idx.tolist()))
        got = {"phi": np.stack([np.full(2, 10.0 * substeps + r) for r in idx])}
        bad = [k for k, r in enumerate(idx) if r in loud[substeps]]
        if bad:
            raise DivergedRuns("diverged", np.array(bad), got)
        return got
    out = integration.run_with_retries(integration.Integration("exp-rk4", 2), run, 4)
    assert calls == [(2, [0, 1, 2, 3]), (4, [1, 3]), (8, [3])]
    assert out["phi"][:, 0].tolist() == [20.0, 41.0, 22.0, 83.0]


def test_a_first_pass_leaves_the_loud_runs_for_later() -> None:
    # tries=slice(0, 1): the diverged runs come back as NaN rows, for a later pooled pass
    def run(method, substeps, idx):
        got = {"phi": np.ones((len(idx), 2))}
        raise DivergedRuns("diverged", np.array([1]), got)
    out = integration.run_with_retries(integration.Integration("exp-rk4", 2), run, 3,
                                       slice(0, 1))
    assert np.isnan(out["phi"][1]).all() and (out["phi"][[0, 2]] == 1).all()


def test_runs_predicted_too_stiff_for_a_step_go_to_finer_ones_unsimulated() -> None:
    # w h at one substep per sample: at x2 runs 2 and 3 pass MAX_WH 2.7, at x4 run 3 still
    # does, and the last try (rk4 x32) takes whatever is left
    calls = []

    def run(method, substeps, idx):
        calls.append((method, substeps, idx.tolist()))
        return {"phi": np.stack([np.full(2, 100.0 * substeps + r) for r in idx])}
    out = integration.run_with_retries(integration.Integration("exp-rk4", 2), run, 4,
                                       stiffness=np.array([1.0, 5.3, 6.0, 100.0]))
    assert calls == [("exp-rk4", 2, [0, 1]), ("exp-rk4", 4, [2]), ("rk4", 32, [3])]
    assert out["phi"][:, 0].tolist() == [200.0, 201.0, 402.0, 3203.0]


def test_a_first_pass_too_stiff_for_every_run_leaves_them_all_for_later() -> None:
    # the one try of the part is run only for the rows' shapes: every row NaN, none taken
    # from a step it is too stiff for
    calls = []

    def run(method, substeps, idx):
        calls.append((substeps, idx.tolist()))
        return {"phi": np.ones((len(idx), 2))}
    out = integration.run_with_retries(integration.Integration("exp-rk4", 2), run, 2,
                                       slice(0, 1), np.array([8.0, 6.0]))
    assert calls == [(2, [0, 1])] and np.isnan(out["phi"]).all()


def test_stiffness_predicts_the_simulated_compressor_peaks() -> None:
    # tone bursts of rising loudness in both bins: the digital prediction against the largest
    # w = sqrt((kq + 3 l c^2) / m) of the compressors in the simulated network
    from springc.sim.simulate import simulate

    t = np.arange(4800) / 16000
    burst = np.exp(-((t - 0.1) / 0.03) ** 2)
    sig = np.stack([a * np.sin(2 * np.pi * f * t) * burst
                    for a, f in ((0.05, 400.0), (0.3, 400.0), (0.6, 3000.0), (1.0, 3000.0))])
    labels = [f"x(c{i})" for i in range(SMALL.bins)]
    res = simulate(check(msp.feature_network(SMALL)), sig[:, None, :], msp.INPUT_RATE,
                   probes=labels, method="rk4", substeps=16, precision="float64",
                   tstop=msp.horizon(SMALL, 0.3))
    c = np.stack([np.abs(res.probes[k]).max(axis=1) for k in labels], axis=1)
    duffing = msp.compressor_duffing(SMALL)
    simulated = np.sqrt((SMALL.kq + 3 * duffing * c**2) / msp.compressor_mass(SMALL))
    predicted = msp.stiffness(sig, SMALL)
    # never below, and at most 15% above (the network's low-pass also feels the compressor's
    # spring, which the prediction leaves out): a clip is not sent to a step too coarse for it
    ratio = predicted / (simulated.max(axis=1) / msp.INPUT_RATE)
    assert ratio.min() >= 0.97 and ratio.max() <= 1.15, ratio
    assert predicted[3] / predicted[0] > 10  # the loud clips stiffen the compressors
    # no sound, or none at all: the compressors at rest, sqrt(kq / m)
    rest = np.sqrt(SMALL.kq / msp.compressor_mass(SMALL)).max() / msp.INPUT_RATE
    np.testing.assert_allclose(msp.stiffness(np.zeros((2, 0)), SMALL), rest, rtol=1e-12)
    np.testing.assert_allclose(msp.stiffness(np.zeros(800), SMALL), rest, rtol=1e-12)


def test_the_last_try_raises() -> None:
    def run(method, substeps, idx):
        raise DivergedRuns("diverged", np.arange(len(idx)), {"phi": np.zeros((len(idx), 1))})
    with pytest.raises(DivergedRuns):
        integration.run_with_retries(integration.Integration("rk4", 16), run, 3)


def test_feature_network_choice_meets_its_tolerance() -> None:
    # two short tone bursts through the 2x1 network: the chosen integration is measured
    t = np.arange(3200) / 16000
    sig = np.stack([0.2 * np.sin(2 * np.pi * f * t) * np.exp(-((t - 0.1) / 0.04) ** 2)
                    for f in (300.0, 2000.0)])
    chosen = msp.choose_integration(SMALL, sig, 1e-3)
    assert chosen.error <= 1e-3 and chosen.clips == 2
    s = msp.MassSpringSettings(bins=2, delays=1, method=chosen.method, substeps=chosen.substeps)
    # in chunks of BATCH lanes, as a data set's clips run (and the choice measured them)
    got = msp.simulate_phi(sig, s, chunk=msp.BATCH, precision="float32")
    ref = msp.simulate_phi(sig, SMALL, chunk=msp.BATCH, method="rk4", substeps=16,
                           precision="float64")
    assert integration.relative_error(got, ref) <= 1e-3


def test_a_garbled_integration_entry_is_a_named_data_error() -> None:
    assert integration.from_dict(None) == integration.PAPER
    assert integration.from_dict({"method": "exp-rk4", "substeps": 2}).substeps == 2
    with pytest.raises(DataError, match="m/settings.json.*unreadable integration entry"):
        integration.from_dict({"method": "rk4", "steps": 3}, "m/settings.json")


def test_a_choice_is_remembered_for_the_same_network_sample_and_rules(tmp_path, monkeypatch,
                                                                      capsys):
    """A second training on the same front end and sample (the device design after the
    mass-spring one) takes the choice the first measured; another sample, or other rules of
    the choice, measure again."""
    monkeypatch.setenv("SPRINGC_CACHE", str(tmp_path))
    sample = np.ones((2, 5))
    measured = []

    def measure():
        measured.append(1)
        return integration.Integration("exp-rk4", 2, error=1e-5, clips=2)

    parts = ["the network's text", integration.signal_key(sample)]
    first = integration.remembered("features' integration", parts, measure)
    again = integration.remembered("features' integration", parts, measure)
    assert again == first and len(measured) == 1
    assert "of an earlier run on the same network and sample" in capsys.readouterr().err
    integration.remembered("features' integration",
                           ["the network's text", integration.signal_key(2 * sample)], measure)
    monkeypatch.setattr(integration, "TOLERANCE", 1e-4)
    integration.remembered("features' integration", parts, measure)
    assert len(measured) == 3
