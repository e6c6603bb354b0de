"""The benchmark suite: speed against error of every integrator and the peers on the reference
networks, in one run.

`cases()` lists the networks and their workloads (`Case`); `run_case` measures one: a tight
reference for run 0 (Richardson-extrapolated, checked by scipy DOP853), the peers on a stretch
of it, every (method, substeps, precision) row timed on a batch with its error, finer rows
(`ladder`) until one matches the best peer, and the machine's ceiling and FMA peak for the
network's size; `claims` and `verdicts` turn the rows into the must-show figures, which
`springc.bench.report` writes out. Throughput is run-seconds per wall-second; the procedure
in full: docs/performance.md#how-the-bench-measures.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from functools import cached_property
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from springc.bench import networks as bn
from springc.bench import ceiling
from springc.bench import grad as gradbench
from springc.check import CheckedNetlist, check
from springc.kernels import expint
from springc.errors import SimulationError
from springc.lang.ir import FlatNetlist, IRBuilder, Source, Tran
from springc.sim.execute import record_shape
from springc.sim.simulate import method_order, simulate

REF_CHECK_RTOL = 1e-12  # the independent check of the reference: scipy DOP853 at this rtol
REF_CHECK_MAX_STEP = 32  # ... with max_step tstep / 32 (kinks of the interpolated input)
DUFFING_HARD = 1.2e5  # sine amplitude driving the Duffing case to ~0.55: stiffness up 10x
PEER_RTOL = 1e-6
# the targets: x faster at equal or better error; "DOP853" is the targets' own configuration
MUST_SPEEDUP = {"DOP853": 300.0, "DOP853 tstep/8": 300.0, "ngspice": 50.0}
# scipy peers: name -> (method, max_step in input samples; None: scipy's free step size, as
# the targets were set against; 1/8: springc.bench.reference's default, 8+ steps per sample)
SCIPY_PEERS = {"DOP853": ("DOP853", None), "DOP853 tstep/8": ("DOP853", 1 / 8),
               "RK45": ("RK45", 1 / 8)}
LADDER_GAIN = 0.5  # a ladder rung must at least halve the error, else round-off has won
# Timings: the least wall time of repeated calls (the machine is shared), kernels and peers
# alike: at least MIN_CALLS (kernels) or 1 (peers), then more while the calls so far took
# under REPEAT_FOR seconds, at most MAX_CALLS, never past REPEAT_BUDGET seconds.
MIN_CALLS, MAX_CALLS = 3, 25
REPEAT_FOR, REPEAT_BUDGET = 1.0, 8.0
PAIRED_ROUNDS = 15  # rounds of alternating re-timing of a case's `paired` rows (load bursts)
CEILING_TRIES = 3  # the ceiling is a best case: the most of its measurements (a case with
# `paired` rows measures it once per round of their re-timing as well, in alternation)
CEILING_SECONDS = 0.3  # each ceiling measurement runs its loop at least this long
BATCH = 64  # runs of a batched case: two chunks of 32 lanes, one per core (simulate's default)


@dataclass
class Case:
    """One reference network and its workload."""

    name: str
    title: str
    net: FlatNetlist
    inputs: np.ndarray | None  # (runs, channels, samples) at 1/tstep; None: one run, no input
    tstep: float
    tstop: float
    configs: list[tuple[str, int, str]]  # (method, substeps, precision)
    peer_tstop: float  # stretch of run 0 the peers simulate
    peers: tuple[str, ...] = ("DOP853", "DOP853 tstep/8", "RK45", "numpy-rk4", "ngspice")
    paired: tuple[tuple[str, int, str], ...] = ()  # rows re-timed in alternation (fair ratios)
    # rows run again recording no probe (re-timed with the paired ones): what the recording
    # of the probes costs, which the ceiling, writing nothing, does not do
    unrecorded: tuple[tuple[str, int, str], ...] = ()
    # finer rows, measured in turn until one is as accurate as every peer on their stretch
    ladder: tuple[tuple[str, int, str], ...] = ()
    ref_method: str = "rk4"  # the reference: this method at ref_substeps and half as many
    ref_substeps: int = 64
    check_tstop: float | None = None  # stretch of the DOP853 check (default: peer_tstop)
    skipped: dict[str, str] = field(default_factory=dict)  # peer -> why it does not run here
    rounds: int = PAIRED_ROUNDS  # rounds of the `paired` re-timing
    # record buffers the timed kernel calls reuse, per (inputs shape, tstop, precision,
    # probes recorded): as the ceiling reuses its memory (`_sim`)
    buffers: dict[tuple, np.ndarray] = field(default_factory=dict)

    @cached_property
    def checked(self) -> CheckedNetlist:
        """The checked network. Its rows run above the stability limit too (the divergence
        guard stops them, and the report says so): the bench passes `check_step=False`."""
        return check(self.net, judge_step=False)


@dataclass
class Row:
    """One measured configuration (a kernel or a peer)."""

    name: str
    method: str
    substeps: int
    precision: str
    errors: dict[str, float]  # per probe, over the whole run (peers: their stretch)
    wall_s: float
    compile_s: float
    simulated_s: float  # runs x seconds simulated in `wall_s`
    throughput: float  # run-seconds per wall-second
    ceiling_fraction: float | None = None
    peak_fraction: float | None = None  # of the machine's FMA peak (`ceiling.measure_peak`)
    note: str = ""
    stretch_errors: dict[str, float] = field(default_factory=dict)  # on the peers' stretch
    recorded: bool = True  # False: run without probes (no errors; timing only)

    @property
    def max_error(self) -> float:
        return max(self.errors.values()) if self.errors else math.nan

    @property
    def max_stretch_error(self) -> float:
        return max(self.stretch_errors.values()) if self.stretch_errors else math.nan

    @property
    def wall_per_run_second(self) -> float:
        return self.wall_s / self.simulated_s


@dataclass
class Reference:
    """Run 0 of a case, Richardson-extrapolated from `method` at `substeps` and half as many,
    with its error estimates (relative L2 per probe)."""

    method: str
    substeps: int
    t: np.ndarray
    probes: dict[str, np.ndarray]  # label -> (T,)
    estimate: dict[str, float]  # |fine - coarse| / (2^p - 1) over the whole run (fine run's)
    stretch_estimate: dict[str, float]  # the same on the peers' stretch
    check: dict[str, float]  # scipy DOP853 at REF_CHECK_RTOL against it, on check_tstop
    check_tstop: float
    wall_s: float  # the two runs that make it
    check_wall_s: float

    @property
    def floor(self) -> float:
        """The least error the comparison on the peers' stretch can resolve."""
        return max(max(self.stretch_estimate.values(), default=0.0),
                   max(self.check.values(), default=0.0))

    def summary(self) -> dict:
        """Everything but the traces (for bench.json and the report)."""
        return {"method": self.method, "substeps": self.substeps,
                "estimate": self.estimate, "stretch_estimate": self.stretch_estimate,
                "check": self.check, "check_tstop": self.check_tstop,
                "check_rtol": REF_CHECK_RTOL, "wall_s": self.wall_s,
                "check_wall_s": self.check_wall_s, "floor": self.floor}


@dataclass
class CaseResult:
    name: str
    title: str
    dofs: int
    runs: int
    tstep: float
    tstop: float
    rows: list[Row] = field(default_factory=list)
    ceiling: dict[str, float] = field(default_factory=dict)  # precision -> run-s/wall-s @1/tstep
    peak: dict[str, float] = field(default_factory=dict)  # the FMA peak, rated as the ceiling
    peer_tstop: float = 0.0
    reference: dict = field(default_factory=dict)  # Reference.summary()
    ladder_note: str = ""  # why the ladder stopped
    skipped: dict[str, str] = field(default_factory=dict)  # peer -> why it did not run
    # precision -> {"mb", "s", "threads"}: the OS's first touch of as much fresh memory as a
    # recorded call writes (cases with rows recording no probe; `ceiling.first_touch_seconds`)
    first_touch: dict[str, dict[str, float]] = field(default_factory=dict)
    # precision -> least wall time of the recorded RK4 x1 call into fresh memory (cases with
    # rows recording no probe)
    fresh_wall: dict[str, float] = field(default_factory=dict)


def speech_like(seconds: float, rate: float, runs: int, seed: int = 0) -> np.ndarray:
    """Deterministic test inputs (runs, 1, samples): a 100 Hz to 8 kHz chirp with pitch-like
    amplitude modulation plus white noise, a different noise and sweep phase per run."""
    t = np.arange(round(seconds * rate) + 1) / rate
    rng = np.random.default_rng(seed)
    out = np.empty((runs, 1, len(t)))
    for r in range(runs):
        sweep = 2 * np.pi * (100 * t + 0.5 * 7900 / seconds * t**2) + rng.uniform(0, 2 * np.pi)
        envelope = 0.6 + 0.4 * np.sin(2 * np.pi * 4 * t + r)
        out[r, 0] = envelope * np.sin(sweep) + 0.3 * rng.standard_normal(len(t))
    return out


def feature_extractor(bands: int = 8, fmin: float = 100.0, fmax: float = 8000.0) -> FlatNetlist:
    """The feature extractor: `bands` two-mode Mel filter pairs (mel-spaced, fmin..fmax, the
    paper's alpha = 400 rad/s, so Q ~ 126 at 8 kHz) driven by in(0), each squared by a
    quadratic coupling into a 30 Hz low-pass. Probes: every filter output and low-pass."""
    from springc.design.filters import hz_to_mel, mel_to_hz

    b = IRBuilder("feature extractor", "<benchsuite.feature_extractor>")
    centres = mel_to_hz(np.linspace(hz_to_mel(fmin), hz_to_mel(fmax), bands))
    wl = 2 * np.pi * 30.0
    for k, fa in enumerate(centres):
        out = bn.filter_pair(b, f"f{k}", fa)
        b.mass(f"Mlp{k}", f"lp{k}", 1.0, 1.4 * wl)
        b.spring(f"Klp{k}", f"lp{k}", wl**2)
        b.quad(f"Qlp{k}", out, f"lp{k}", 1e3)
        b.probe("x", out)
        b.probe("x", f"lp{k}")
    b.tran = Tran(1.0 / bn.KWS_RATE, 1.0, None)
    return b.finish()


def stiff_block(nodes: int = 24, k_constraint: float = 2e8) -> FlatNetlist:
    """A stiff all-to-all block: `nodes` unit masses (40 Hz local springs, damping 50/s), every
    pair joined by a constraint spring `k_constraint` (fastest mode sqrt(nodes k) rad/s),
    driven at node 0 from in(0); probes at both ends."""
    b = IRBuilder("stiff all-to-all block", "<benchsuite.stiff_block>")
    w = 2 * np.pi * 40.0
    for p in range(nodes):
        b.mass(f"M{p}", f"s{p}", 1.0, 50.0)
        b.spring(f"K{p}", f"s{p}", w**2)
    for p in range(nodes):
        for q in range(p + 1, nodes):
            b.coupling(f"C{p}_{q}", f"s{p}", f"s{q}", k_constraint)
    b.force("F0", "s0", Source("in", channel=0), 1e4)
    b.probe("x", "s0")
    b.probe("x", f"s{nodes - 1}")
    b.tran = Tran(1.0 / bn.KWS_RATE, 0.25, None)
    return b.finish()


def _rk_configs(subs=(1, 2, 4), precisions=("float64",), method="rk4"
                ) -> list[tuple[str, int, str]]:
    return [(method, s, p) for p in precisions for s in subs]


def cases(quick: bool = False) -> list[Case]:
    """The suite; `quick` shortens every workload (for tests of the machinery). Each case's
    reference runs at twice the substeps of its ladder's last rung, so that the reference's
    own error estimate stays below what the ladder can reach."""
    rate = bn.KWS_RATE
    scale = 0.05 if quick else 1.0
    runs = 2 if quick else BATCH
    fe_t, kws_t = 1.0 * scale, 0.25 * scale
    both = ("float64", "float32")
    rk4_x1 = (("rk4", 1, "float64"), ("rk4", 1, "float32"))  # the throughput rows
    exp = [(m, 1, p) for m in ("exp-rk4", "exp-heun3") for p in both] + [
        ("exp-rk4", 2, "float64"), ("exp-heun3", 2, "float64")]
    line = bn.long_delay_line()
    # 0.25 s of input, like the 564-dof network and the stiff block, rather than the line's
    # own 0.04 s .tran: a call's start-up is a large share of a batch that short
    line_t = 0.25 * scale
    duff = bn.duffing_resonator(amp=DUFFING_HARD)
    out = [
        Case("feature", "feature extractor (8 Mel filter pairs 0.1-8 kHz, squarers, low-pass)",
             feature_extractor(), speech_like(fe_t, rate, runs), 1 / rate, fe_t,
             _rk_configs((1, 2, 4, 8)) + [("rk4", 1, "float32")] + exp
             + _rk_configs((4, 8, 16), method="exp-rk4")
             + [("strang-rk4", 1, "float64")], 0.005 * scale,
             paired=rk4_x1 + (("exp-rk4", 1, "float64"), ("exp-rk4", 2, "float64"),
                              ("exp-rk4", 1, "float32"), ("exp-heun3", 1, "float64"),
                              ("exp-heun3", 1, "float32")),
             unrecorded=rk4_x1,  # it records 16 probes at every step (262 MB a call)
             ladder=tuple(_rk_configs((32, 64), method="exp-rk4")),
             ref_method="exp-rk4", ref_substeps=128, check_tstop=0.0025 * scale),
        Case("kws", "8x3 keyword-spotting network (564 dofs)", bn.kws_network(),
             speech_like(kws_t, rate, runs, seed=1), 1 / rate, kws_t,
             _rk_configs((1, 2, 4)) + [("rk4", 1, "float32")]
             + _rk_configs((1, 2), method="exp-rk4") + _rk_configs((1, 2), method="exp-heun3"),
             0.01 * scale,
             peers=("DOP853", "DOP853 tstep/8", "RK45", "numpy-rk4"), paired=rk4_x1,
             skipped={"ngspice": "not run on the 564-dof network: ngspice took 57 s for 5 ms "
                      "of the 24-dof feature extractor at its reltol 1e-9"},
             ladder=tuple(_rk_configs((4, 8, 16, 32), method="exp-rk4")),
             ref_method="exp-rk4", ref_substeps=64, check_tstop=0.005 * scale),
        Case("delay", "long delay line (200 sites)", line,
             speech_like(line_t, 1 / line.tran.tstep, runs, seed=2), line.tran.tstep, line_t,
             _rk_configs((1, 2, 4, 8, 16)) + [("rk4", 1, "float32")],
             line.tran.tstop * (0.25 if quick else 0.75), paired=rk4_x1,
             ladder=tuple(_rk_configs((32, 64, 128, 256))), ref_substeps=512),
        Case("stiff", "stiff all-to-all block (24 masses, constraint springs 2e8)",
             stiff_block(), speech_like(0.25 * scale, rate, runs, seed=3), 1 / rate,
             0.25 * scale, _rk_configs((1, 2, 4, 8, 16, 32)) + [("rk4", 1, "float32")],
             0.02 * scale, paired=rk4_x1,
             ladder=tuple(_rk_configs((64, 128, 256))), ref_substeps=1024,
             check_tstop=0.01 * scale),
        Case("duffing", "Duffing resonator driven hard (stiffness up 10x at the peak)", duff,
             None, duff.tran.tstep, duff.tran.tstop * scale, _rk_configs((1, 2, 4)),
             0.05 * scale, ladder=tuple(_rk_configs((8, 16, 32, 64, 128, 256))),
             ref_substeps=512),
    ] + _pipeline_cases(scale, runs)
    if quick:
        for case in out:
            case.rounds = 2
    return out


SPEECH_LEVEL = 0.3  # the speech-like inputs scaled to the level of the corpus's clips


# substeps of each device case where RK4 at the case's step is not enough
DEVICE_SUBSTEPS = {"stiff block": 32, "pipeline features 8x3": 8,
                   "pipeline classifier 8x3": 8, "duffing resonator": 2}


def device_cases(seconds: float, runs: int) -> list[tuple[str, FlatNetlist, np.ndarray | None,
                                                        float]]:
    """(name, network, inputs, tstep) of every bench network, `seconds` long on `runs`
    speech-like inputs (None: the Duffing resonator drives itself): the workloads of the
    GPU measuring scripts (`scripts/cuda_compare.py bench`, `scripts/cpu_reference.py`)."""
    rate = bn.KWS_RATE
    line = bn.long_delay_line()
    return [
        ("feature extractor", feature_extractor(), speech_like(seconds, rate, runs), 1 / rate),
        ("564-dof kws network", bn.kws_network(), speech_like(seconds, rate, runs, 1),
         1 / rate),
        ("long delay line", line, speech_like(seconds, 1 / line.tran.tstep, runs, 2),
         line.tran.tstep),
        ("stiff block", stiff_block(), speech_like(seconds, rate, runs, 3), 1 / rate),
        ("duffing resonator", bn.duffing_resonator(amp=DUFFING_HARD), None,
         bn.duffing_resonator().tran.tstep),
        ("pipeline features 8x3", bn.pipeline_features(),
         SPEECH_LEVEL * speech_like(seconds, 16000.0, runs, 4), 1 / 16000.0),
        ("pipeline classifier 8x3", bn.pipeline_classifier(),
         SPEECH_LEVEL * speech_like(seconds, 16000.0, runs, 5), 1 / 16000.0),
    ]


def _pipeline_cases(scale: float, runs: int) -> list[Case]:
    """The keyword-spotting pipeline's own networks at 8x3 on its 16 kHz grid: the feature
    network `train` simulates and the whole classifier `eval` simulates (float64 only: its
    multipliers' cancellation moves float32 readouts by 2e-2)."""
    rate, t = 16000.0, 0.25 * scale
    features = bn.pipeline_features()
    classifier = bn.pipeline_classifier()
    no_ngspice = {"ngspice": "not run on the pipeline's networks (see the 564-dof case)"}
    return [
        Case("kws-features", f"keyword-spotting feature network, 8x3 ({features.n} masses)",
             features, SPEECH_LEVEL * speech_like(t, rate, runs, seed=4), 1 / rate, t,
             _rk_configs((1, 2, 4, 8)) + [("rk4", 8, "float32")]
             + _rk_configs((1, 2, 4), ("float64", "float32"), method="exp-rk4"),
             0.01 * scale, peers=("DOP853", "DOP853 tstep/8", "RK45", "numpy-rk4"),
             paired=(("rk4", 8, "float32"), ("exp-rk4", 2, "float32")), skipped=no_ngspice,
             ladder=tuple(_rk_configs((8, 16), method="exp-rk4")),
             ref_method="exp-rk4", ref_substeps=32, check_tstop=0.005 * scale),
        Case("kws-classifier", f"keyword-spotting classifier, 8x3, 12 heads "
             f"({classifier.n} masses)", classifier,
             SPEECH_LEVEL * speech_like(t, rate, runs, seed=5), 1 / rate, t,
             _rk_configs((4, 8)) + [("rk4", 8, "float32")]
             + _rk_configs((1, 2, 4), method="exp-rk4"),
             0.005 * scale, peers=("DOP853",),
             paired=(("rk4", 8, "float64"), ("exp-rk4", 2, "float64")), skipped=no_ngspice,
             ladder=tuple(_rk_configs((8,), method="exp-rk4")), rounds=5,
             # DOP853 at rtol 1e-12 on 788 stiff dofs: 15 s per 0.125 ms (measured, --quick)
             ref_method="exp-rk4", ref_substeps=32, check_tstop=0.001 * scale),
    ]


def run_case(case: Case, progress: Callable[[str], None] = print) -> CaseResult:
    """Measure one case (module docstring)."""
    runs = 1 if case.inputs is None else len(case.inputs)
    res = CaseResult(case.name, case.title, case.net.n, runs, case.tstep, case.tstop,
                     peer_tstop=case.peer_tstop, skipped=dict(case.skipped))
    first = None if case.inputs is None else case.inputs[:1]
    progress(f"[{case.name}] reference: {case.ref_method} x{case.ref_substeps} and "
             f"x{case.ref_substeps // 2}, run 0; check by DOP853 rtol {REF_CHECK_RTOL:g}")
    ref = reference(case, first)
    res.reference = ref.summary()
    peers = []
    for peer in case.peers:
        progress(f"[{case.name}] peer {peer}")
        row = _peer_row(case, ref, peer)
        if row is not None:
            peers.append(row)
    for method, sub, precision in case.configs:
        if _applies(case, method):
            progress(f"[{case.name}] {method} x{sub} {precision}")
            res.rows.append(_kernel_row(case, ref, method, sub, precision, runs))
    for method, sub, precision in case.unrecorded:
        progress(f"[{case.name}] {method} x{sub} {precision}, no probes recorded")
        res.rows.append(_unrecorded_row(case, method, sub, precision, runs))
    res.ladder_note = _climb_ladder(case, ref, res.rows, peers, runs, progress)
    progress(f"[{case.name}] ceiling" + (f", and {len(case.paired)} rows re-timed with it in "
                                         f"alternation" if case.paired else "")
             + (", with the first touch of the record" if case.paired and case.unrecorded
                else ""))
    res.ceiling = _ceilings(case, runs)
    res.peak = _ceilings(case, runs, peak=True)
    if case.paired:
        _retime_paired(case, res.rows, runs, (res.ceiling, res.peak), res.first_touch,
                       res.fresh_wall)
    case.buffers.clear()
    res.rows += peers
    for row in res.rows:
        if row.precision in res.ceiling and row.name.startswith("kernel"):
            # the ceiling scales as 1 / rate: rate it at the row's own step
            row.ceiling_fraction = row.throughput / (res.ceiling[row.precision] / row.substeps)
            row.peak_fraction = row.throughput / (res.peak[row.precision] / row.substeps)
    return res


def _applies(case: Case, method: str) -> bool:
    """Split methods only where the network has blocks to split off (else they are RK4)."""
    return not expint.is_split(method) or bool(len(expint.find_blocks(case.net)))


def _climb_ladder(case: Case, ref: Reference, rows: list[Row], peers: list[Row], runs: int,
                  progress: Callable[[str], None]) -> str:
    """Measure the case's finer rows in turn while a peer's error on the peers' stretch (or
    the reference's floor, if larger) is not yet reached by any row and is within reach of
    the ladder's last rung by its method's order of convergence from the most accurate row
    so far; stop early when a rung fails to halve the error of the one before (round-off).
    Returns what it did and why it stopped."""
    targets = {p.method: max(p.max_stretch_error, ref.floor) for p in peers if p.stretch_errors}
    last = math.inf
    for method, sub, precision in case.ladder:
        if not _applies(case, method):
            continue
        pending = {k: t for k, t in targets.items() if _best_stretch(rows) > t}
        if not pending:
            return f"every peer's error reached ({_reached(targets, rows)})"
        if not any(_predicted(rows, method, case.ladder[-1][1]) <= 4 * t
                   for t in pending.values()):
            return _out_of_reach(pending, rows, method, case.ladder[-1][1], targets)
        progress(f"[{case.name}] ladder: {method} x{sub} {precision}")
        row = _kernel_row(case, ref, method, sub, precision, runs)
        row.note = (row.note + "; " if row.note else "") + "ladder"
        rows.append(row)
        if not row.stretch_errors:
            continue  # stopped by the divergence guard: a finer rung may not be
        if not row.max_stretch_error < LADDER_GAIN * last:
            return (f"stopped at {row_label(row)} ({row.max_stretch_error:.3g}): no gain on the "
                    f"rung before (round-off); " + _reached(targets, rows))
        last = row.max_stretch_error
    pending = {k: t for k, t in targets.items() if _best_stretch(rows) > t}
    if not pending:
        return f"every peer's error reached ({_reached(targets, rows)})"
    return _out_of_reach(pending, rows, case.ladder[-1][0] if case.ladder else "rk4",
                         case.ladder[-1][1] if case.ladder else 1, targets)


def _predicted(rows: list[Row], method: str, substeps: int) -> float:
    """The stretch error of `method` at `substeps` by its order of convergence from its most
    accurate measured float64 row (0 when there is none: nothing to predict from)."""
    mine = [r for r in rows if r.method == method and r.precision == "float64"
            and r.stretch_errors]
    if not mine:
        return 0.0
    base = min(mine, key=lambda r: r.max_stretch_error)
    return base.max_stretch_error * (base.substeps / substeps) ** method_order(method)


def _out_of_reach(pending: dict[str, float], rows: list[Row], method: str, top: int,
                  targets: dict[str, float]) -> str:
    mine = [r for r in rows if r.method == method and r.precision == "float64"
            and r.stretch_errors]
    if not mine:
        return f"no {method} row to climb from; " + _reached(targets, rows)
    base = min(mine, key=lambda r: r.max_stretch_error)
    parts = []
    for peer, t in pending.items():
        need = base.substeps * (base.max_stretch_error / t) ** (1 / method_order(method))
        parts.append(f"{peer}'s {t:.3g} needs about {method} x{2 ** math.ceil(math.log2(need))}")
    return (f"out of reach of the affordable ladder (up to x{top}): " + "; ".join(parts)
            + f" by {_ordinal(method_order(method))}-order convergence from "
            f"{row_label(base)} "
            f"({base.max_stretch_error:.3g}); " + _reached(targets, rows))


def _reached(targets: dict[str, float], rows: list[Row]) -> str:
    best = _best_stretch(rows)
    got = [k for k, t in targets.items() if best <= t]
    return "reached: " + (", ".join(got) if got else "none")


def _best_stretch(rows: list[Row]) -> float:
    return min((r.max_stretch_error for r in rows if r.stretch_errors), default=math.inf)


def worst_error(errors: dict[str, float]) -> float:
    """The largest of per-probe errors (NaN for none)."""
    return max(errors.values(), default=math.nan)


def reference(case: Case, first) -> Reference:
    """Run 0 by `case.ref_method` at `case.ref_substeps` and half as many substeps,
    Richardson-extrapolated for its order p: y = y_fine + (y_fine - y_coarse) / (2^p - 1) (15
    for the fourth-order rk4 and exp-rk4), with the fine run's own error
    |y_fine - y_coarse| / (2^p - 1) as the estimate (the extrapolated values are better
    still) and scipy DOP853 at REF_CHECK_RTOL as an independent check."""
    start = time.perf_counter()
    fine = _sim(case, first, case.ref_method, case.ref_substeps, "float64")
    coarse = _sim(case, first, case.ref_method, case.ref_substeps // 2, "float64")
    wall = time.perf_counter() - start
    gain = 2.0 ** method_order(case.ref_method) - 1.0
    probes = {label: y[0] + (y[0] - coarse.probes[label][0]) / gain
              for label, y in fine.probes.items()}
    ref = Reference(case.ref_method, case.ref_substeps, fine.t, probes, {}, {}, {},
                    case.check_tstop or case.peer_tstop, wall, 0.0)
    for label, want in probes.items():
        for upto, into in ((case.tstop, ref.estimate), (case.peer_tstop, ref.stretch_estimate)):
            keep = ref.t <= upto * (1 + 1e-9)
            into[label] = _rel(fine.probes[label][0][keep], want[keep])
    ref.check, ref.check_wall_s = _check(case, first, ref)
    return ref


def _check(case: Case, first, ref: Reference) -> tuple[dict[str, float], float]:
    """scipy DOP853 at REF_CHECK_RTOL (atol 1e-15 of the largest probe value, max_step
    tstep / REF_CHECK_MAX_STEP) against the reference on its check stretch, and its wall."""
    from springc.bench import reference as peers

    scale = max(float(np.max(np.abs(y))) for y in ref.probes.values()) or 1.0
    start = time.perf_counter()
    t, probes, _ = peers.solve_ivp_reference(
        case.net, first, tstep=case.tstep, tstop=ref.check_tstop, method="DOP853",
        rtol=REF_CHECK_RTOL, atol=1e-15 * scale, max_step=case.tstep / REF_CHECK_MAX_STEP)
    wall = time.perf_counter() - start
    return _errors({k: v[0] for k, v in probes.items()}, t, ref, ref.check_tstop), wall


def _sim(case: Case, inputs, method: str, substeps: int, precision: str, tstop=None,
         probes=None, reuse: bool = False):
    """A simulation of the case; with `reuse`, recording into the buffer of the last such
    call of the same shape (`simulate`'s `record_into`), as the ceiling reuses its memory:
    the calls a row is timed by pay the OS's zeroing of fresh pages once, not every time.
    Only for calls whose result is read before the next one (the timed rows')."""
    key = (None if inputs is None else inputs.shape, tstop or case.tstop, precision,
           probes is None)
    out = simulate(case.checked, inputs, tstep=case.tstep, tstop=tstop or case.tstop,
                   substeps=substeps, method=method, precision=precision, probes=probes,
                   record_into=case.buffers.get(key) if reuse else None, check_step=False)
    if reuse:
        case.buffers[key] = out.info["records"]
    return out


def _rel(got: np.ndarray, want: np.ndarray) -> float:
    """Relative L2 error (absolute where the reference is zero)."""
    norm = np.linalg.norm(want)
    diff = float(np.linalg.norm(got - want))
    return diff / norm if norm > 0 else diff


def _errors(got: dict[str, np.ndarray], t: np.ndarray, ref: Reference,
            upto: float) -> dict[str, float]:
    """Relative L2 error of every probe (run 0) against the reference, on t <= upto."""
    keep = ref.t <= upto * (1 + 1e-9)
    return {label: _rel(np.interp(ref.t[keep], t, got[label]), want[keep])
            for label, want in ref.probes.items()}


def _kernel_row(case: Case, ref: Reference, method: str, sub: int, precision: str,
                runs: int) -> Row:
    warm = simulate(case.checked, None if case.inputs is None else case.inputs[:, :, :4],
                    tstep=case.tstep, tstop=2 * case.tstep, substeps=sub, method=method,
                    precision=precision, check_step=False)
    compile_s = float(warm.info["compile_s"] or 0.0)
    try:
        out, wall = _timed(lambda: _sim(case, case.inputs, method, sub, precision, reuse=True),
                           lambda out: float(out.info["wall_s"]))
    except SimulationError as err:
        return Row(f"kernel {method}", method, sub, precision, {}, math.nan, compile_s, 0.0,
                   0.0, note=f"stopped by the divergence guard: {err.message}")
    got = {k: v[0] for k, v in out.probes.items()}
    return Row(f"kernel {method}", method, sub, precision, _errors(got, out.t, ref, case.tstop),
               wall, compile_s, runs * case.tstop, runs * case.tstop / wall,
               stretch_errors=_errors(got, out.t, ref, case.peer_tstop))


def _unrecorded_row(case: Case, method: str, sub: int, precision: str, runs: int) -> Row:
    """The kernel of `method` run recording no probe: its wall time only."""
    warm = _sim(case, None if case.inputs is None else case.inputs[:, :, :4], method, sub,
                precision, tstop=2 * case.tstep, probes=[])  # compiles: not in the timing
    try:
        out, wall = _timed(lambda: _sim(case, case.inputs, method, sub, precision, probes=[],
                                        reuse=True),
                           lambda out: float(out.info["wall_s"]))
    except SimulationError as err:
        return Row(f"kernel {method}", method, sub, precision, {}, math.nan, 0.0, 0.0, 0.0,
                   note=f"stopped by the divergence guard: {err.message}", recorded=False)
    return Row(f"kernel {method}", method, sub, precision, {}, wall,
               float(warm.info["compile_s"] or 0.0), runs * case.tstop, runs * case.tstop / wall,
               note="no probes recorded (timing only)", recorded=False)


def _retime_paired(case: Case, rows: list[Row], runs: int,
                   bounds: tuple[dict[str, float], dict[str, float]],
                   first_touch: dict[str, dict[str, float]],
                   fresh_wall: dict[str, float]) -> None:
    """Time the `paired` and `unrecorded` rows and the ceiling and FMA peak (`bounds`) in
    turn, `case.rounds` times, keeping each row's least wall time and the bounds' best (in
    place): on a shared machine a load burst then hits the rows and the bounds alike, not just
    one of them (the ceiling alone varied up to 5x between calls here). With unrecorded
    rows, also time the recorded RK4 x1 calls into fresh memory (least, in `fresh_wall`), the
    first touch of as much fresh memory as each precision's recorded row writes and the
    writing of its record's lines alone into memory already handed out (least, in
    `first_touch`, "s" and "store_s"): what of the recording's cost is the OS's and what the
    memory's."""
    chosen = _measured(rows, case.paired, True) + _measured(rows, case.unrecorded, False)
    shapes: dict[str, tuple] = {}
    stores: dict[str, float] = {}
    for _ in range(case.rounds):
        for row in chosen:
            out = _sim(case, case.inputs, row.method, row.substeps, row.precision,
                       probes=None if row.recorded else [], reuse=True)
            if row.recorded and case.unrecorded and out.probes:
                shapes[row.precision] = _record_shape(out)
                if (row.method, row.substeps) == ("rk4", 1):
                    wall = float(_sim(case, case.inputs, "rk4", 1, row.precision
                                      ).info["wall_s"])
                    fresh_wall[row.precision] = min(fresh_wall.get(row.precision, wall), wall)
                    took = ceiling.store_seconds(out.info["records"], min(_threads(), runs))
                    stores[row.precision] = min(stores.get(row.precision, took), took)
            row.wall_s = min(row.wall_s, float(out.info["wall_s"]))
            row.throughput = runs * case.tstop / row.wall_s
            row.note = ("" if row.recorded else "no probes recorded (timing only); ") + (
                f"least of {case.rounds} re-timings in alternation with the ceiling")
        for bound, peak in zip(bounds, (False, True)):
            for precision, best in _ceilings(case, runs, tries=1, peak=peak).items():
                bound[precision] = max(bound[precision], best)
        for precision, shape in shapes.items():
            threads = min(_threads(), runs)  # as many as the kernel calls use
            took = ceiling.first_touch_seconds(shape, precision, threads)
            seen = first_touch.setdefault(precision, {"mb": _megabytes(shape, precision),
                                                      "s": took, "threads": threads})
            seen["s"] = min(seen["s"], took)
            if precision in stores:
                seen["store_s"] = stores[precision]


def _record_shape(out) -> tuple[int, int, int]:
    """(probe, run, record) of the buffer a simulation recorded into."""
    first = next(iter(out.probes.values()))
    runs, records = first.shape
    return record_shape(len(out.probes), records, runs, first.dtype)


def _megabytes(shape: tuple[int, int, int], precision: str) -> float:
    return math.prod(shape) * np.dtype(precision).itemsize / 1e6


def _measured(rows: list[Row], configs, recorded: bool) -> list[Row]:
    """The kernel rows of `configs` (recording or not) that ran to the end (not stopped by
    the divergence guard)."""
    return [r for r in rows for m, s, p in configs
            if r.name == f"kernel {m}" and (r.substeps, r.precision) == (s, p)
            and r.recorded == recorded and math.isfinite(r.wall_s)]


def _timed(call: Callable[[], object], wall_of: Callable[[object], float] | None = None,
           min_calls: int = MIN_CALLS) -> tuple[object, float]:
    """The result and the least wall time of repeated calls (the rule at MIN_CALLS): the
    machine is shared, the minimum is the code's own time. `wall_of` reads a call's wall
    time from its result (default: timed around the call)."""
    best, spent, out = math.inf, 0.0, None
    for n in range(1, MAX_CALLS + 1):
        start = time.perf_counter()
        out = call()
        wall = wall_of(out) if wall_of else time.perf_counter() - start
        best, spent = min(best, wall), spent + wall
        if spent > REPEAT_BUDGET or (n >= min_calls and spent >= REPEAT_FOR):
            break
    return out, best


def _peer_row(case: Case, ref: Reference, peer: str) -> Row | None:
    from springc.bench import reference

    first = None if case.inputs is None else case.inputs[:1]
    tstop = case.peer_tstop
    wall = math.nan
    if peer in SCIPY_PEERS:
        method, per_sample = SCIPY_PEERS[peer]
        (t, probes, _), wall = _timed(lambda: reference.solve_ivp_reference(
            case.net, first, tstep=case.tstep, tstop=tstop, method=method, rtol=PEER_RTOL,
            atol=PEER_RTOL * 1e-6,
            max_step=math.inf if per_sample is None else case.tstep * per_sample), min_calls=1)
        note = (f"scipy solve_ivp rtol {PEER_RTOL:g}, atol {PEER_RTOL * 1e-6:g}, "
                + ("free step size" if per_sample is None else
                   f"max_step tstep/{round(1 / per_sample)}"))
    elif peer == "numpy-rk4":
        (t, probes, _), wall = _timed(lambda: reference.rk4_numpy(
            case.net, first, tstep=case.tstep, tstop=tstop), min_calls=1)
        note = "plain numpy RK4 at 1/tstep"
    elif peer == "ngspice":
        start = time.perf_counter()  # once: it runs for tens of seconds
        try:
            got = _ngspice(case, first, tstop)
        except SimulationError as err:  # a peer's failure is a result, not the end of the run
            return Row(f"peer {peer}", peer, 1, "float64", {}, math.nan, 0.0, tstop, 0.0,
                       note=f"failed: {err.message}")
        if got is None:
            return None
        t, probes, note = got
        wall = time.perf_counter() - start
    else:
        raise ValueError(f"unknown peer {peer!r}")
    errors = _errors({k: np.asarray(v)[0] if np.ndim(v) == 2 else v for k, v in probes.items()},
                     t, ref, tstop)
    return Row(f"peer {peer}", peer, 1, "float64", errors, wall, 0.0, tstop, tstop / wall,
               note=note, stretch_errors=dict(errors))


def _ngspice(case: Case, first, tstop):
    """ngspice on the exported netlist of run 0 (None when ngspice is not installed)."""
    import shutil

    from springc.export.spice import SpiceOptions
    from springc.export.ngspice import simulate_ngspice

    if shutil.which("ngspice") is None:
        return None
    inputs = {} if first is None else {0: (first[0, 0], 1.0 / case.tstep)}
    opts = SpiceOptions(tstop=tstop, tstep=case.tstep, inputs=inputs)
    t, traces = simulate_ngspice(case.checked, opts)
    return t, traces, "ngspice trap, reltol 1e-9 (sampled input), uic"


def _ceilings(case: Case, runs: int, tries: int | None = None, peak: bool = False
              ) -> dict[str, float]:
    """Ceiling run-seconds per wall-second at the input rate, per precision measured: the
    best of `tries` measurements; with `peak`, the FMA peak's (`ceiling.measure_peak`), rated
    with the same flop count. `tries` defaults to CEILING_TRIES."""
    tries = CEILING_TRIES if tries is None else tries
    flops = ceiling.rk4_flops_per_dof_step(case.net)
    rate = 1.0 / case.tstep

    def measure(precision: str) -> float:
        if peak:
            fps = ceiling.measure_peak(runs, precision, threads=_threads(),
                                       min_seconds=CEILING_SECONDS)["flops_per_second"]
            return ceiling.run_seconds_per_wall_second(fps, flops, case.net.n, rate)
        return float(ceiling.measure_ceiling(case.net.n, runs, precision, threads=_threads(),
                                             flops_per_step=flops, rate=rate,
                                             min_seconds=CEILING_SECONDS)
                     ["run_seconds_per_wall_second"])

    return {precision: max(measure(precision) for _ in range(tries))
            for precision in sorted({p for _, _, p in case.configs})}


def _threads() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


# --- report -----------------------------------------------------------------------------

def measured(r: Row, kind: str) -> bool:
    """Whether `r` is a `kind` ("kernel" or "peer") row with a finite stretch error: the rows
    an equal-error comparison can use."""
    return (r.name.startswith(kind) and bool(r.stretch_errors)
            and math.isfinite(r.max_stretch_error))


def speedup(kernel: Row, peer: Row, floor: float) -> float | None:
    """How many times less wall time per run-second `kernel` needs than `peer` where its
    stretch error is no worse than the peer's (or the reference's floor, if larger); None
    where it is worse, or either has no finite error."""
    if not (measured(kernel, "kernel") and measured(peer, "peer")):
        return None
    if kernel.max_stretch_error > max(peer.max_stretch_error, floor):
        return None
    return peer.wall_per_run_second / kernel.wall_per_run_second


def speedups(res: CaseResult) -> list[dict]:
    """Per peer: the cheapest kernel row whose worst probe error on the peers' stretch is no
    worse than the peer's (or than the reference's floor, when the peer is below it: equal
    within what the reference resolves), and how much less wall time per simulated
    run-second it needs; without such a row, the most accurate kernel row for comparison.
    Rows without a finite error (a run the divergence guard stopped, a peer that blew up)
    compete for nothing; their notes say why."""
    kernels = [r for r in res.rows if measured(r, "kernel")]
    floor = float(res.reference.get("floor", 0.0))
    out = []
    for peer in (r for r in res.rows if measured(r, "peer")):
        target = max(peer.max_stretch_error, floor)
        ok = [k for k in kernels if k.max_stretch_error <= target]
        best = min(ok, key=lambda k: k.wall_per_run_second, default=None)
        closest = min(kernels, key=lambda k: k.max_stretch_error, default=None)
        need = _needed_substeps(closest, target) if closest and not best else None
        out.append({"peer": peer.method, "peer_error": peer.max_stretch_error,
                    "floor": floor, "floor_limited": bool(floor > peer.max_stretch_error),
                    "kernel": row_label(best) if best else None,
                    "kernel_error": best.max_stretch_error if best else None,
                    "speedup": peer.wall_per_run_second / best.wall_per_run_second
                    if best else None,
                    "closest": row_label(closest) if closest else None,
                    "closest_error": closest.max_stretch_error if closest else None,
                    "closest_speedup": peer.wall_per_run_second / closest.wall_per_run_second
                    if closest else None,
                    # out of reach: the substeps its order of convergence says it would take,
                    # and the speed-up there if the cost grows linearly with the substeps
                    "needed": f"{closest.method} x{need} {closest.precision}" if need else None,
                    "order": _ordinal(method_order(closest.method)) if need else None,
                    "predicted_speedup": peer.wall_per_run_second
                    / (closest.wall_per_run_second * need / closest.substeps) if need else None})
    return out


def _ordinal(k: int) -> str:
    return {2: "second", 3: "third", 4: "fourth"}.get(k, f"{k}th")


def _needed_substeps(row: Row, target: float) -> int:
    """Substeps (a power of two) at which `row`'s method reaches `target` by its order of
    convergence from `row`'s stretch error."""
    need = row.substeps * (row.max_stretch_error / target) ** (1 / method_order(row.method))
    return 2 ** max(0, math.ceil(math.log2(need)))


def claims(results: list[CaseResult]) -> dict:
    """The must-show figures (the feature extractor within 1e-3, throughput against the
    ceiling, speed-ups against the peers), from the measured rows."""
    out: dict = {}
    fe = next((r for r in results if r.name == "feature"), None)
    if fe is not None:
        ok = [r for r in fe.rows if r.name.startswith("kernel") and r.errors
              and r.max_error <= 1e-3]
        for precision in ("float64", "float32"):
            base = _find(fe, "rk4", 1, precision)
            if base is None:
                continue
            mine = [r for r in ok if r.precision == precision]
            best = min(mine, key=lambda r: r.wall_s, default=None)
            out[f"feature_1e-3_{precision}"] = {
                "rk4_x1_error": base.max_error,
                "cheapest": row_label(best) if best else None,
                "cheapest_error": best.max_error if best else None,
                "wall_ratio_to_rk4_x1": best.wall_s / base.wall_s if best else None}
    out["ceiling_fraction"] = {
        r.name: {p: (_find(r, "rk4", 1, p).ceiling_fraction if _find(r, "rk4", 1, p) else None)
                 for p in ("float64", "float32")} for r in results}
    # informative, decides nothing: the same rows recording no probe, where measured
    out["ceiling_fraction_unrecorded"] = {
        r.name: {row.precision: row.ceiling_fraction for row in r.rows
                 if not row.recorded and row.method == "rk4" and row.substeps == 1}
        for r in results}
    # informative, decides nothing: the RK4 x1 rows against the machine's FMA peak
    out["peak_fraction"] = {
        r.name: {row.precision + ("" if row.recorded else ", no probes"): row.peak_fraction
                 for row in r.rows if row.method == "rk4" and row.substeps == 1
                 and row.peak_fraction is not None}
        for r in results}
    out["first_touch"] = {r.name: _first_touch_shares(r) for r in results if r.first_touch}
    # informative, decides nothing: the recorded RK4 x1 calls into fresh memory every call
    out["ceiling_fraction_fresh"] = {
        r.name: {p: r.runs * r.tstop / wall / r.ceiling[p] for p, wall in r.fresh_wall.items()}
        for r in results if r.fresh_wall}
    out["runs"] = {r.name: r.runs for r in results}
    out["speedups"] = {r.name: speedups(r) for r in results}
    out["verdicts"] = verdicts(out, results)
    return out


def _first_touch_shares(r: CaseResult) -> dict[str, dict[str, float]]:
    """Per precision: MB of fresh memory a recorded call writes, the OS's first touch of that
    much (s) and its share of the recorded RK4 x1 call's wall time."""
    out = {}
    for precision, ft in r.first_touch.items():
        row = _find(r, "rk4", 1, precision)
        share = ft["s"] / row.wall_s if row and math.isfinite(row.wall_s) else None
        out[precision] = {**ft, "share": share}
        if "store_s" in ft and precision in r.ceiling:
            # the row's wall at the ceiling, plus the stores if they overlapped nothing
            at_ceiling = r.runs * r.tstop / r.ceiling[precision]
            out[precision]["store_bound"] = at_ceiling / (at_ceiling + ft["store_s"])
    return out


def verdicts(found: dict, results: list[CaseResult]) -> list[dict]:
    """Each must-show figure, met or missed, with the numbers that decide it."""
    out = []
    for precision in ("float64", "float32"):
        fe = found.get(f"feature_1e-3_{precision}")
        if fe:
            ratio = fe["wall_ratio_to_rk4_x1"]
            out.append({"claim": "feature_1e-3", "scope": precision,
                        "met": ratio is not None and ratio <= 1.5, "value": ratio,
                        "target": 1.5, "detail": fe})
    for name, fr in found["ceiling_fraction"].items():
        batched = found["runs"].get(name, 2) > 1  # the claim is about batched kernels
        for precision, frac in fr.items():
            if frac is not None:
                out.append({"claim": "ceiling_70", "scope": f"{name} {precision}",
                            "met": frac >= 0.7 if batched else None, "value": frac,
                            "target": 0.7, "detail": None if batched else "single run"})
    ran = {r.name: {row.method for row in r.rows if row.name.startswith("peer")}
           for r in results}
    for peer, need in MUST_SPEEDUP.items():
        for name, rows in found["speedups"].items():
            s = next((x for x in rows if x["peer"] == peer), None)
            if s is None:
                why = next((r.skipped.get(peer) for r in results if r.name == name), None)
                out.append({"claim": f"speedup_{peer}", "scope": name, "met": None,
                            "value": None, "target": need,
                            "detail": why or ("peer not run" if peer not in ran[name]
                                              else "peer failed")})
                continue
            out.append({"claim": f"speedup_{peer}", "scope": name,
                        "met": s["speedup"] is not None and s["speedup"] >= need,
                        "value": s["speedup"], "target": need, "detail": s})
    return out


def _find(res: CaseResult, method: str, sub: int, precision: str) -> Row | None:
    return next((r for r in res.rows if r.name == f"kernel {method}" and r.substeps == sub
                 and r.precision == precision and r.errors), None)


def row_label(row: Row) -> str:
    """"rk4 x4 float64" for a kernel row, the peer's name for a peer."""
    if row.name.startswith("peer"):
        return row.method
    return f"{row.method} x{row.substeps} {row.precision}" + ("" if row.recorded else
                                                              ", no probes")


def machine_info() -> dict:
    """CPU model, CPUs, load and time of the run (the context of the timings)."""
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else math.nan
    return {"cpu": cpu_model(), "cpus": _threads(), "load": round(load, 2),
            "when": time.strftime("%Y-%m-%d %H:%M:%S")}


def of_cpu(machine: dict) -> str:
    """' of MODEL' where a run recorded its CPU model (runs from before it did: '')."""
    return f" of {machine['cpu']}" if machine.get("cpu") else ""


def cpu_model() -> str:
    """The CPU's model name (Linux), else the platform's processor string."""
    import platform

    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def run_suite(names: list[str] | None = None, quick: bool = False,
              progress: Callable[[str], None] = print) -> list[CaseResult]:
    """Run the named cases (default: all) in one process."""
    chosen = [c for c in cases(quick) if names is None or c.name in names]
    gradbench.report(names, quick, progress)
    return [run_case(c, progress) for c in chosen]
