"""springc.bench.suite: the tight reference against an analytic solution, the ladder of finer
rows, the equal-error speed-ups and the must-show verdicts. No timing is asserted (the machine
is shared): the speed-up logic is checked on rows with given wall times."""

from __future__ import annotations

import itertools
import json
import math
import types

import numpy as np
import pytest

from springc.bench import report
from springc.bench import suite as bs
from springc.check import check
from springc.lang.ir import IRBuilder, Source, Tran
from springc.sim.simulate import method_order

K, C, F, FREQ = (2 * np.pi * 300.0) ** 2, 60.0, 1e5, 280.0  # driven near resonance, Q ~ 31
TSTEP, TSTOP, STRETCH = 1e-4, 0.02, 0.01


def _oscillator():
    b = IRBuilder("driven oscillator", "<test_benchsuite>")
    b.mass("M1", "a", 1.0, C)
    b.spring("K1", "a", K)
    b.force("F1", "a", Source("sin", (F, FREQ)))
    b.probe("x", "a")
    b.tran = Tran(TSTEP, TSTOP, None)
    return b.finish()


def _analytic(t: np.ndarray) -> np.ndarray:
    """x'' + C x' + K x = F sin(W t) from rest: the particular solution plus the damped free
    oscillation that cancels its initial position and velocity."""
    w = 2 * np.pi * FREQ
    a, b = np.linalg.solve([[K - w**2, -C * w], [C * w, K - w**2]], [F, 0.0])
    sigma = C / 2
    wd = math.sqrt(K - sigma**2)
    c1 = -b
    c2 = (sigma * c1 - a * w) / wd
    free = np.exp(-sigma * t) * (c1 * np.cos(wd * t) + c2 * np.sin(wd * t))
    return a * np.sin(w * t) + b * np.cos(w * t) + free


def _case(**kw) -> bs.Case:
    args = {"configs": [("rk4", 1, "float64"), ("rk4", 2, "float64")],
            "peer_tstop": STRETCH, "peers": ("DOP853", "numpy-rk4"),
            "ladder": tuple(("rk4", s, "float64") for s in (4, 8, 16, 32, 64)),
            "ref_substeps": 256}
    args.update(kw)
    return bs.Case("osc", "driven oscillator", _oscillator(), None, TSTEP, TSTOP, **args)


@pytest.fixture
def quick_timing(monkeypatch):
    """The timing rules at their least (one ceiling measurement of a few ms, each row timed
    MIN_CALLS times): the tests read what the suite reports, not how fast it ran."""
    monkeypatch.setattr(bs, "CEILING_TRIES", 1)
    monkeypatch.setattr(bs, "CEILING_SECONDS", 0.01)
    monkeypatch.setattr(bs, "REPEAT_FOR", 0.0)


@pytest.fixture(scope="module")
def ref():
    return bs.reference(_case(), None)


def test_reference_matches_the_analytic_solution_well_below_1e9(ref):
    want = _analytic(ref.t)
    err = np.linalg.norm(ref.probes["x(a)"] - want) / np.linalg.norm(want)
    assert err < 1e-11
    # the estimate is the fine run's own error: an upper bound of the extrapolated one
    assert err <= max(ref.estimate["x(a)"], 1e-13)
    assert 1e-15 < ref.estimate["x(a)"] < 1e-10
    assert ref.stretch_estimate["x(a)"] <= ref.estimate["x(a)"] * 1.5
    # the independent check: DOP853 at rtol 1e-12 agrees to well below 1e-9
    assert ref.check["x(a)"] < 1e-10
    assert ref.floor == max(ref.stretch_estimate["x(a)"], ref.check["x(a)"])


def _peer(error: float, wall_per_run_s: float = 100.0, method: str = "DOP853") -> bs.Row:
    return bs.Row(f"peer {method}", method, 1, "float64", {"x": error}, wall_per_run_s * 0.01,
                  0.0, 0.01, 1 / wall_per_run_s, stretch_errors={"x": error})


def test_ladder_stops_at_the_first_rung_as_accurate_as_the_best_peer(ref):
    case = _case()
    rows = [bs._kernel_row(case, ref, m, s, p, 1) for m, s, p in case.configs]
    target = 1e-9
    note = bs._climb_ladder(case, ref, rows, [_peer(target), _peer(1e-3, method="ngspice")],
                            1, lambda m: None)
    ladder = [r for r in rows if "ladder" in r.note]
    assert ladder, note
    assert ladder[-1].max_stretch_error <= target < ladder[-2].max_stretch_error
    assert note == "every peer's error reached (reached: DOP853, ngspice)"
    # fourth order: each halving of the step divides the error by about 16
    ratios = [a.max_stretch_error / b.max_stretch_error for a, b in itertools.pairwise(rows)]
    assert all(10 < q < 22 for q in ratios), ratios


def test_ladder_ends_at_the_floor_or_on_round_off_when_the_peer_is_below_it(ref):
    case = _case(ladder=tuple(("rk4", s, "float64") for s in (4, 16, 64, 256, 512)))
    rows = [bs._kernel_row(case, ref, "rk4", 1, "float64", 1)]
    note = bs._climb_ladder(case, ref, rows, [_peer(1e-30)], 1, lambda m: None)
    # the target is the floor (about 1e-14 here): a rung at the floor reaches it, or round-off
    # stops the climb first; either way the note says which
    assert note.startswith(("every peer's error reached", "stopped at rk4 x")), note
    assert rows[-1].max_stretch_error < 1e-11


def test_ladder_skips_rungs_that_cannot_reach_the_peer_and_says_what_it_would_need(ref):
    case = _case(ladder=(("rk4", 2, "float64"), ("rk4", 4, "float64")))
    rows = [bs._kernel_row(case, ref, "rk4", 1, "float64", 1)]
    e1 = rows[0].max_stretch_error
    note = bs._climb_ladder(case, ref, rows, [_peer(1e-12)], 1, lambda m: None)
    assert len(rows) == 1  # x4 would give about e1 / 256: nowhere near 1e-12, nothing run
    need = 2 ** math.ceil(math.log2((e1 / 1e-12) ** 0.25))
    assert f"DOP853's 1e-12 needs about rk4 x{need} by fourth-order convergence" in note
    assert note.startswith("out of reach of the affordable ladder (up to x4)")


def _kernel(method: str, sub: int, err: float, wall_per_run_s: float, whole: float | None = None,
            precision: str = "float64") -> bs.Row:
    return bs.Row(f"kernel {method}", method, sub, precision, {"x": whole or err},
                  wall_per_run_s, 0.0, 1.0, 1 / wall_per_run_s, stretch_errors={"x": err})


def _result(rows, floor=1e-14) -> bs.CaseResult:
    res = bs.CaseResult("net", "a network", 1, 1, TSTEP, TSTOP, rows=rows, peer_tstop=STRETCH)
    res.reference = {"floor": floor}
    return res


def test_speedup_is_the_cheapest_row_at_equal_or_better_stretch_error():
    rows = [_kernel("rk4", 1, 1e-4, 0.01), _kernel("rk4", 4, 1e-8, 0.04, whole=1e-6),
            _kernel("rk4", 8, 5e-10, 0.08), _peer(2e-9, wall_per_run_s=100.0),
            _peer(1e-3, wall_per_run_s=50.0, method="ngspice")]
    out = {s["peer"]: s for s in bs.speedups(_result(rows))}
    assert out["DOP853"]["kernel"] == "rk4 x8 float64"
    assert out["DOP853"]["speedup"] == pytest.approx(100.0 / 0.08)
    assert out["ngspice"]["kernel"] == "rk4 x1 float64"  # 1e-4 <= 1e-3, the cheapest
    assert out["ngspice"]["speedup"] == pytest.approx(5000.0)
    assert not out["DOP853"]["floor_limited"]


def test_rows_without_a_finite_error_compete_for_nothing():
    """A peer that blew up (numpy-rk4 on the compressors) and a kernel row the guard stopped
    have NaN errors: no speed-up against the one, none won by the other."""
    rows = [_kernel("exp-rk4", 1, math.nan, 0.005), _kernel("rk4", 8, 5e-10, 0.08),
            _peer(math.nan, wall_per_run_s=10.0, method="numpy-rk4"),
            _peer(1e-3, wall_per_run_s=50.0)]
    out = {s["peer"]: s for s in bs.speedups(_result(rows))}
    assert list(out) == ["DOP853"]
    assert out["DOP853"]["kernel"] == "rk4 x8 float64"


def test_speedup_counts_a_peer_below_the_floor_at_the_floor_and_reports_the_closest_row():
    rows = [_kernel("rk4", 8, 5e-10, 0.08), _kernel("rk4", 16, 3e-12, 0.16),
            _peer(1e-13, wall_per_run_s=100.0)]
    s = bs.speedups(_result(rows, floor=4e-12))[0]
    assert s["floor_limited"] and s["kernel"] == "rk4 x16 float64"
    s = bs.speedups(_result(rows, floor=1e-14))[0]
    assert s["kernel"] is None and s["speedup"] is None
    assert s["closest"] == "rk4 x16 float64"
    assert s["closest_speedup"] == pytest.approx(100.0 / 0.16)
    # 3e-12 -> 1e-13 takes 30^(1/4) = 2.3 times the substeps: x64, the next power of two
    assert s["needed"] == "rk4 x64 float64"
    assert s["predicted_speedup"] == pytest.approx(100.0 / (0.16 * 4))


def test_predictions_use_the_methods_own_order_of_convergence():
    """exp-heun3 is third order: 1e-6 -> 1e-9 takes 10x the substeps (x2 -> x20 -> x32),
    where a fourth-order method would take 5.6x (x2 -> x16)."""
    for method, need, word in (("exp-heun3", 32, "third"), ("exp-rk4", 16, "fourth")):
        rows = [_kernel(method, 2, 1e-6, 0.02), _peer(1e-9, wall_per_run_s=100.0)]
        s = bs.speedups(_result(rows, floor=1e-14))[0]
        assert s["needed"] == f"{method} x{need} float64" and s["order"] == word
        assert bs._predicted(rows, method, 4) == pytest.approx(1e-6 * 0.5 ** method_order(method))


def test_verdicts_say_met_missed_and_partly_met_with_the_numbers():
    fe_rows = [_kernel("rk4", 1, 0.5, 0.004, whole=0.8), _kernel("exp-rk4", 1, 1e-4, 0.005,
                                                                 whole=3e-4),
               _kernel("exp-rk4", 16, 1e-12, 0.08), _peer(2e-11, wall_per_run_s=500.0),
               _peer(1e-4, wall_per_run_s=8000.0, method="ngspice")]
    for r in fe_rows[:3]:
        r.ceiling_fraction = 0.3
    fe = _result(fe_rows)
    fe.name = "feature"
    other = _result([_kernel("rk4", 1, 1e-6, 0.01), _peer(1e-13, wall_per_run_s=500.0)])
    other.rows[0].ceiling_fraction = 0.8
    single = _result([_kernel("rk4", 1, 1e-6, 0.01)])
    single.name, single.rows[0].ceiling_fraction = "one", 0.1
    fe.runs = other.runs = 64  # batched; `single` is one run: reported, not judged
    found = bs.claims([fe, other, single])
    by = {(v["claim"], v["scope"]): v for v in found["verdicts"]}
    assert by[("feature_1e-3", "float64")]["met"]  # 0.005 / 0.004 = 1.25x
    assert by[("feature_1e-3", "float64")]["value"] == pytest.approx(1.25)
    assert by[("speedup_DOP853", "feature")]["met"]  # 500 / 0.08 = 6250x
    assert by[("speedup_DOP853", "net")]["met"] is False  # no row reaches 1e-13
    assert by[("speedup_ngspice", "net")]["met"] is None  # ngspice did not run there
    assert by[("ceiling_70", "net float64")]["met"]
    assert not by[("ceiling_70", "feature float64")]["met"]
    assert by[("ceiling_70", "one float64")]["met"] is None
    md = report._verdicts_md(found["verdicts"])
    assert md[0] == "## The targets: met or missed"
    assert len(md) == 2 + 5 + 1 and md[-1] == ""  # one line per must-show
    assert md[2].startswith("- **MET**: Feature extractor")
    assert md[2].endswith(": float64 1.25x with exp-rk4 x1 float64.")
    assert md[3].startswith("- **PARTLY MET (1 of 2)**: Throughput")
    assert md[3].endswith(": feature float64 30% (missed); net float64 80%; "
                          "one float64 10% (one run, not a batch: not judged).")
    assert md[4].startswith("- **PARTLY MET (1 of 2)**: At least 300x faster than scipy DOP853")
    # 500 / 0.08; net: rk4 x1 is 50000x faster at 1e-6, rk4 x64 would reach 1e-13 at 781x
    assert md[4].endswith(": feature 6250x; net missed: no measured row as accurate "
                          "(predicted, not measured: 781x at rk4 x64 float64); one not run.")
    assert md[6].startswith("- **MET**: At least 50x faster than ngspice")  # net: not run
    assert md[6].endswith(": feature 1600000x; net not run; one not run.")


def test_run_case_writes_the_report_with_reference_and_ladder(tmp_path, quick_timing):
    case = _case(peers=("DOP853", "DOP853 tstep/8", "numpy-rk4"))
    res = bs.run_case(case, progress=lambda m: None)
    assert res.reference["floor"] < 1e-11
    peers = {r.method: r for r in res.rows if r.name.startswith("peer")}
    assert set(peers) == {"DOP853", "DOP853 tstep/8", "numpy-rk4"}
    # both DOP853s are far more accurate than rtol 1e-6 on this smooth problem
    assert peers["DOP853 tstep/8"].max_stretch_error < 1e-9
    # numpy RK4 at 1/tstep is the kernel's rk4 x1 on the same equations
    x1 = bs._find(res, "rk4", 1, "float64")
    assert peers["numpy-rk4"].max_stretch_error == pytest.approx(x1.max_stretch_error, rel=1e-6)
    kernels = [r for r in res.rows if r.name.startswith("kernel")]
    assert all(r.stretch_errors and r.errors for r in kernels)
    assert "reached" in res.ladder_note
    paths = report.write_report([res], tmp_path, bs.machine_info() | {"suite_wall_s": 60.0})
    assert paths["json"] == tmp_path / "bench" / "bench.json"
    data = json.loads(paths["json"].read_text())
    assert data["cases"][0]["reference"]["substeps"] == 256
    md = paths["md"].read_text()
    assert "## The targets: met or missed" in md
    assert "Reference: rk4 x256 and x128, Richardson-extrapolated" in md
    assert "the whole suite took 1.0 min" in md
    assert "Plot: [speed against error](bench/osc.png)" in md
    assert paths["osc"] == tmp_path / "bench" / "osc.png" and paths["osc"].stat().st_size > 1000
    # the stored numbers give the same page and plots again, measuring nothing
    again = report.render(paths["json"], tmp_path / "again")
    assert again["md"].read_text() == md
    assert again["json"].read_bytes() == paths["json"].read_bytes()
    assert again["osc"].read_bytes() == paths["osc"].read_bytes()


def test_paired_rows_and_the_ceiling_are_timed_in_alternation_least_and_best(monkeypatch):
    """The re-timed rows keep their least wall time and the ceiling and FMA peak their best
    measurement, one of each per round (a load burst then hits them all, not one)."""
    calls = []
    ceilings = iter([100.0, 300.0, 200.0])
    peaks = iter([4e9, 9e9, 6e9])  # flop/s

    def fake_ceiling(n_dof, batch, precision, **kw):
        calls.append("ceiling")
        return {"run_seconds_per_wall_second": next(ceilings)}

    def fake_peak(batch, precision, **kw):
        calls.append("peak")
        return {"flops_per_second": next(peaks)}

    walls = iter([0.5, 0.2, 0.3])

    def fake_sim(case, inputs, method, sub, precision, tstop=None, probes=None, reuse=False):
        calls.append("row")
        return types.SimpleNamespace(info={"wall_s": next(walls)})

    monkeypatch.setattr(bs.ceiling, "measure_ceiling", fake_ceiling)
    monkeypatch.setattr(bs.ceiling, "measure_peak", fake_peak)
    monkeypatch.setattr(bs, "_sim", fake_sim)
    case = _case(paired=(("rk4", 1, "float64"),), rounds=3)
    row = _kernel("rk4", 1, 1e-6, 0.4)
    best, peak = {"float64": 150.0}, {"float64": 0.0}
    bs._retime_paired(case, [row], 1, (best, peak), {}, {})
    assert calls == ["row", "ceiling", "peak"] * 3
    assert row.wall_s == 0.2 and row.throughput == pytest.approx(TSTOP / 0.2)
    assert best["float64"] == 300.0
    flops = bs.ceiling.rk4_flops_per_dof_step(case.net)
    assert peak["float64"] == pytest.approx(
        bs.ceiling.run_seconds_per_wall_second(9e9, flops, case.net.n, 1 / case.tstep))
    assert "least of 3 re-timings in alternation with the ceiling" in row.note


def test_unrecorded_rows_record_nothing_are_rated_and_never_decide_a_claim(monkeypatch):
    """A row run without probes: its simulations ask for no probe, it has a throughput and a
    ceiling fraction but no error, is labelled so, and the claims keep using the recorded
    row of the same configuration."""
    asked = []
    real = bs.simulate

    def spy(net, inputs, **kw):
        asked.append(kw.get("probes"))
        return real(net, inputs, **kw)

    monkeypatch.setattr(bs, "simulate", spy)
    # each row timed MIN_CALLS times; the ceiling and the peak each measured once, as long as
    # the suite measures them (the fractions of the peak are checked below 1: a short peak
    # measurement on a busy machine reads low)
    monkeypatch.setattr(bs, "REPEAT_FOR", 0.0)
    monkeypatch.setattr(bs, "CEILING_TRIES", 1)
    x1 = ("rk4", 1, "float64")
    case = _case(configs=[x1], peers=(), ladder=(), paired=(x1,), unrecorded=(x1,), rounds=2)
    res = bs.run_case(case, progress=lambda m: None)
    bare = [r for r in res.rows if not r.recorded]
    assert len(bare) == 1 and bare[0].errors == {} and bare[0].stretch_errors == {}
    assert bare[0].throughput == pytest.approx(TSTOP / bare[0].wall_s)
    assert bare[0].ceiling_fraction == pytest.approx(bare[0].throughput / res.ceiling["float64"])
    assert bare[0].peak_fraction == pytest.approx(bare[0].throughput / res.peak["float64"])
    # the unrecorded row: a warm-up, at least MIN_CALLS timed calls (more while they are
    # short) and 2 re-timings, each with no probe; every other call: the netlist's probes
    assert asked.count([]) >= 1 + bs.MIN_CALLS + 2
    assert all(p is None for p in asked if p != [])
    recorded = bs._find(res, "rk4", 1, "float64")
    assert recorded.recorded and recorded.errors
    assert bs.claims([res])["ceiling_fraction"]["osc"]["float64"] == recorded.ceiling_fraction
    md = report.markdown([res], bs.claims([res]), bs.machine_info())
    assert "| rk4 x1 float64, no probes | - | - |" in md
    frac = f"{100 * bare[0].ceiling_fraction:.0f}%"
    assert f"the same kernels recording no probe (the ceiling writes nothing): float64 {frac}" in md
    assert "no probes recorded (timing only); least of 2 re-timings" in md
    # and both rows against the machine's FMA peak, which no kernel passes
    peaks = bs.claims([res])["peak_fraction"]["osc"]
    assert peaks == {"float64": recorded.peak_fraction, "float64, no probes": bare[0].peak_fraction}
    assert 0 < recorded.peak_fraction < 1 and 0 < bare[0].peak_fraction < 1
    assert (f"- osc: RK4 x1 throughput as a fraction of the machine's FMA peak (informative): "
            f"float64 {100 * recorded.peak_fraction:.0f}%, float64, no probes "
            f"{100 * bare[0].peak_fraction:.0f}%.") in md
    # and the OS's first touch of as much fresh memory as the recorded row writes: one probe
    # of one run, 201 records padded to whole 64-byte lines of 8 float64
    touch = res.first_touch["float64"]
    assert touch["mb"] == pytest.approx(1 * 1 * 208 * 8 / 1e6)
    assert math.isfinite(touch["s"]) and touch["s"] > 0
    share = bs.claims([res])["first_touch"]["osc"]["float64"]["share"]
    assert share == pytest.approx(touch["s"] / recorded.wall_s)
    assert (f"0.00166 MB in float64: {1e3 * touch['s']:.3g} ms, {100 * share:.0f}% of the "
            "RK4 x1 call") in md
    # and the record's lines written alone into memory handed out already: the bound they
    # would set after the ceiling's own time if they overlapped none of it
    assert math.isfinite(touch["store_s"]) and touch["store_s"] > 0
    at_ceiling = TSTOP / res.ceiling["float64"]
    bound = bs.claims([res])["first_touch"]["osc"]["float64"]["store_bound"]
    assert bound == pytest.approx(at_ceiling / (at_ceiling + touch["store_s"]))
    assert (f"{1e3 * touch['store_s']:.3g} ms, which after the ceiling's own time would "
            f"leave the row at most {100 * bound:.0f}% of the ceiling") in md
    # the recorded row's calls into fresh memory, timed beside it: rated, deciding nothing
    fresh = res.fresh_wall["float64"]
    assert math.isfinite(fresh) and fresh > 0
    frac = bs.claims([res])["ceiling_fraction_fresh"]["osc"]["float64"]
    assert frac == pytest.approx(TSTOP / fresh / res.ceiling["float64"])
    assert ("recording into fresh memory every call (the OS zeroes each page before the "
            f"kernel writes it): float64 {100 * frac:.0f}%") in md


def test_timed_calls_record_into_the_buffer_of_the_call_before():
    """`_sim(reuse=True)`: the same buffer for calls of the same shape (the earlier result's
    views overwritten, with the same numbers), a fresh one otherwise."""
    case = _case()
    a = bs._sim(case, None, "rk4", 1, "float64", reuse=True)
    first = a.probes["x(a)"].copy()
    b = bs._sim(case, None, "rk4", 2, "float64", reuse=True)
    fresh = bs._sim(case, None, "rk4", 2, "float64")
    assert b.info["records"] is a.info["records"]
    assert fresh.info["records"] is not a.info["records"]
    np.testing.assert_array_equal(b.probes["x(a)"], fresh.probes["x(a)"])
    assert np.array_equal(a.probes["x(a)"], b.probes["x(a)"])  # overwritten by b
    assert not np.array_equal(first, b.probes["x(a)"])  # x2 differs from x1
    other = bs._sim(case, None, "rk4", 1, "float32", reuse=True)
    assert other.info["records"] is not a.info["records"]


def test_an_unrecorded_row_the_guard_stops_says_so_and_is_not_re_timed(monkeypatch,
                                                                      quick_timing):
    from springc.errors import SimulationError

    calls = []

    def fake_sim(case, inputs, method, sub, precision, tstop=None, probes=None, reuse=False):
        calls.append(tstop)
        if tstop is None:  # the full runs diverge, the two-step warm-up does not
            raise SimulationError("diverged at t = 0.01 s")
        return types.SimpleNamespace(info={"wall_s": 0.1, "compile_s": 1.0})

    monkeypatch.setattr(bs, "_sim", fake_sim)
    monkeypatch.setattr(bs.ceiling, "measure_ceiling",
                        lambda *a, **kw: {"run_seconds_per_wall_second": 100.0})
    x1 = ("rk4", 1, "float64")
    case = _case(unrecorded=(x1,), rounds=2)
    row = bs._unrecorded_row(case, *x1, 1)
    assert not row.recorded and not math.isfinite(row.wall_s)
    assert row.note == "stopped by the divergence guard: diverged at t = 0.01 s"
    calls.clear()
    bs._retime_paired(case, [row], 1, ({"float64": 50.0}, {"float64": 50.0}), {}, {})
    assert calls == []


def test_the_pipelines_networks_are_cases_of_the_suite():
    """kws-features and kws-classifier are the networks `train` and `eval` simulate at 8x3:
    488 and 788 masses, checked, probed where their outputs are."""
    from springc.bench import networks as bn
    from springc.kws.features import massspring as msp

    features, classifier = bn.pipeline_features(), bn.pipeline_classifier()
    assert features.n == 488 and classifier.n == 788
    assert check(features).net is features and check(classifier).net is classifier
    assert msp.feature_network(msp.MassSpringSettings(bins=8, delays=3)).n == features.n
    assert [p.label for p in classifier.probes] == ["x(r0)", "x(r6)", "x(r11)"]
