"""The bench's report: bench.md, and beside it in bench/ the bench.json it is made from and one
speed-against-error PNG per case (`write_report`), from the suite's results or from a stored
bench.json (`render`: the page again without measuring again).

The page opens with one table per case and the must-show verdicts; how it was measured, every
figure in full and every column of every row come after.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from dataclasses import asdict, fields
from pathlib import Path

from springc.bench.suite import (MAX_CALLS, of_cpu, MIN_CALLS, MUST_SPEEDUP, REF_CHECK_MAX_STEP,
                                 REF_CHECK_RTOL, REPEAT_FOR, CaseResult, Row, claims, measured,
                                 row_label, speedup, worst_error)
from springc.design.emit import write_atomic
from springc.errors import DataError
from springc.sim.simulate import method_order

SUBDIR = "bench"  # the folder beside bench.md that holds bench.json and the PNGs
RENDER_COMMAND = "springc bench --render docs/bench/bench.json --out docs"
MARKERS = {"rk4": "o", "exp-rk4": "^", "exp-heun3": "D", "strang-rk4": "s"}
COLOURS = {"rk4": "C0", "exp-rk4": "C1", "exp-heun3": "C2", "strang-rk4": "C4"}


def write_report(results: list[CaseResult], outdir: Path, machine: dict) -> dict[str, Path]:
    """OUT/bench.md, OUT/bench/bench.json and OUT/bench/<case>.png (each written atomically).
    Returns their paths by "md", "json" and case name."""
    found = claims(results)
    text = markdown(results, found, machine)
    (outdir / SUBDIR).mkdir(parents=True, exist_ok=True)
    paths = {"md": outdir / "bench.md", "json": outdir / SUBDIR / "bench.json"}
    data = {"machine": machine, "claims": found, "cases": [_case_json(r) for r in results]}
    write_atomic(paths["json"], json.dumps(data, indent=1, default=_json_default) + "\n")
    write_atomic(paths["md"], text)
    for r in results:
        paths[r.name] = outdir / SUBDIR / f"{r.name}.png"
        plot(r, paths[r.name])
    return paths


def render(source: Path, outdir: Path) -> dict[str, Path]:
    """The report again from a stored bench.json (`load`), measuring nothing."""
    results, machine = load(source)
    return write_report(results, outdir, machine)


def load(path: Path) -> tuple[list[CaseResult], dict]:
    """The cases and machine of a bench.json that `write_report` wrote. A missing, unreadable
    or garbled file is a `DataError` naming it, raised before anything is written."""
    try:
        data = json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise DataError(str(path), "no such file", hint="`springc bench --out DIR` writes "
                        "DIR/bench/bench.json") from None
    except IsADirectoryError:
        raise DataError(str(path), "is a folder; give the bench.json file") from None
    except UnicodeDecodeError:
        raise DataError(str(path), "not a text file, so not a bench.json") from None
    except json.JSONDecodeError as err:
        raise DataError(str(path), f"not valid JSON ({err.msg} at line {err.lineno}, column "
                        f"{err.colno})") from None
    try:
        results = [_case_from_json(case) for case in data["cases"]]
        machine = dict(data["machine"])
        markdown(results, claims(results), machine)  # every field the page reads is there
    except (KeyError, TypeError, ValueError, AttributeError, IndexError) as err:
        what = f"no {err}" if isinstance(err, KeyError) else str(err)
        raise DataError(str(path), f"not a bench.json of `springc bench` ({what})") from None
    return results, machine


def _case_from_json(d: dict) -> CaseResult:
    rows = [Row(**_known(Row, row)) for row in d["rows"]]
    return CaseResult(**(_known(CaseResult, d) | {"rows": rows}))


def _known(cls, d: dict) -> dict:
    """The entries of `d` that are fields of the dataclass `cls` (bench.json adds others)."""
    return {f.name: d[f.name] for f in fields(cls) if f.name in d}


def _json_default(value):
    """numpy scalars as the Python numbers they hold; anything else as its text."""
    if hasattr(value, "item"):
        return value.item()
    return str(value)


def _case_json(r: CaseResult) -> dict:
    d = asdict(r)
    for row, src in zip(d["rows"], r.rows):
        row["max_error"] = src.max_error
    return d


def _fmt(v: float | None, spec: str = ".3g") -> str:
    return "-" if v is None or not math.isfinite(v) else format(v, spec)


def _percent(fraction: float | None) -> str:
    return f"{_fmt(100 * fraction, '.0f')}%" if fraction else "-"


def _times(v: float) -> str:
    return f"{v:.0f}x" if v >= 100 else f"{v:.3g}x"


def _ms(seconds: float) -> str:
    return f"{1e3 * seconds:g} ms"


# --- the first screen: one table per case, the verdicts ----------------------------------

def markdown(results: list[CaseResult], found: dict, machine: dict) -> str:
    """docs/bench.md: one table per case with its plot, the must-show verdicts, then how it
    was measured, every figure in full and every column of every row."""
    lines = ["# springc bench: speed against error", "", _lead(results, machine), "",
             _legend(), ""]
    for r in results:
        lines += _case_table(r)
    lines += _verdicts_md(found["verdicts"])
    lines += _method_md(machine)
    lines += _claims_md(found)
    for r in results:
        lines += _case_detail(r)
    return "\n".join(lines) + "\n"


def _lead(results: list[CaseResult], machine: dict) -> str:
    took = machine.get("suite_wall_s")
    return (f"springc's kernels against their peers (scipy, numpy, ngspice) on {len(results)} "
            "reference networks: one table per network with its speed-against-error plot, "
            "then the targets, met or missed, then [how it was measured](#how-it-was-measured). "
            f"Measured {machine.get('when')} on {machine.get('cpus')} CPUs{of_cpu(machine)} "
            f"(load average {machine.get('load')} at the start"
            + (f" and {machine['load_end']} at the end" if "load_end" in machine else "")
            + (f"; the suite took {took / 60:.1f} min" if took else "") + ")"
            + _device_md(machine) + ". "
            f"Render this page again from its stored numbers: `{RENDER_COMMAND}`; measure "
            "again: `make bench`. The CUDA kernel form on a GPU, against these CPU kernels and "
            "JAX: [bench-gpu.md](bench-gpu.md); a netlist's first result, whole processes "
            "beside ngspice: [bench-startup.md](bench-startup.md); a Monte Carlo population "
            "in the lanes: [bench-population.md](bench-population.md).")


def _device_md(machine: dict) -> str:
    """Where springc's kernels ran, where not the CPU (`springc bench --device`)."""
    device = machine.get("device", "cpu")
    if device == "cpu":
        return ""
    return (f", springc's kernels in the CUDA form on {device} (the peers, the arithmetic "
            "ceiling and the FMA peak on the CPU)")


def _legend() -> str:
    return ("*error*: the worst probe's relative L2 error against the network's reference, "
            "over the whole run and over the peers' stretch (all the peers simulate). *wall s*: "
            "one call, the least of repeated calls (a kernel: every run of the batch over the "
            "whole run; a peer: one run over the stretch). *throughput*: simulated "
            "run-seconds per wall-second. *vs PEER*: the peer's wall time per run-second over "
            "the row's, where the row is as accurate as the peer on the stretch; **bold**: the "
            "cheapest such row, the figure the verdicts quote; -: less accurate than the peer.")


def _peers(r: CaseResult) -> list[Row]:
    return [row for row in r.rows if row.name.startswith("peer")]


def _kernels(r: CaseResult) -> list[Row]:
    """The recording kernel rows, grouped by method and precision in order of first
    appearance, each group by substeps."""
    rows = [row for row in r.rows if row.name.startswith("kernel") and row.recorded]
    first = {}
    for row in rows:
        first.setdefault((row.method, row.precision), len(first))
    return sorted(rows, key=lambda row: (first[(row.method, row.precision)], row.substeps))


def _case_table(r: CaseResult) -> list[str]:
    peers = _peers(r)
    floor = float(r.reference.get("floor", 0.0))
    cheapest = {p.method: min((k for k in _kernels(r) if speedup(k, p, floor)),
                              key=lambda k: k.wall_per_run_second, default=None) for p in peers}
    stretch = f"error, first {_ms(r.peer_tstop)}"
    head = ["method", "substeps", "precision", "error, whole run", stretch, "wall s",
            "throughput run-s/s"] + [f"vs {p.method}" for p in peers]
    lines = [f"## {r.name}: {r.title}", "", _workload(r) + f" Plot: [speed against error]"
             f"({SUBDIR}/{r.name}.png).", "", "| " + " | ".join(head) + " |",
             "|" + "---|" * len(head)]
    for row in _kernels(r):
        ratios = []
        for p in peers:
            s = speedup(row, p, floor)
            cell = _times(s) if s else "-"
            ratios.append(f"**{cell}**" if s and cheapest[p.method] is row else cell)
        lines.append(_table_row([row.method, str(row.substeps), row.precision]
                                + _main_cells(row, _fmt(row.max_error)) + ratios))
    for p in peers:
        lines.append(_table_row([f"{p.method} (peer)", "-", p.precision]
                                + _main_cells(p, "-") + ["-"] * len(peers)))
    return lines + [""]


def _main_cells(row: Row, whole: str) -> list[str]:
    """Errors, wall and throughput, or why there are none (stopped, failed)."""
    if not row.errors:
        why = "diverged" if "divergence guard" in row.note else "failed"
        return [why, why, "-", "-"]
    return [whole, _fmt(row.max_stretch_error), _fmt(row.wall_s), _fmt(row.throughput)]


def _table_row(cells: list[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def _workload(r: CaseResult) -> str:
    runs = f"{r.runs} runs" if r.runs > 1 else "1 run"
    not_run = "".join(f" Not run here: {peer} ({why})." for peer, why in r.skipped.items())
    return (f"{r.dofs} dofs. Kernels: {runs} of {r.tstop:g} s at tstep {r.tstep:.4g} s "
            f"({1e-3 / r.tstep:g} kHz) in one call; peers: run 0 over the first "
            f"{_ms(r.peer_tstop)}." + not_run)


_CLAIM_TEXT = {
    "feature_1e-3": ("Feature extractor: every probe within 1e-3 of the reference at no more "
                     "than 1.5x the wall time of classic RK4 at 32 kHz"),
    "ceiling_70": "Throughput of the batched RK4 x1 kernels at least 70% of the measured ceiling",
    "speedup_DOP853": (f"At least {MUST_SPEEDUP['DOP853']:.0f}x faster than scipy DOP853 "
                       "(rtol 1e-6, scipy's free step size, as the target was set) at equal "
                       "or better error"),
    "speedup_DOP853 tstep/8": (f"At least {MUST_SPEEDUP['DOP853 tstep/8']:.0f}x faster than "
                               "DOP853 rtol 1e-6 held to max_step tstep/8 (far more accurate "
                               "than rtol 1e-6 asks) at equal or better error"),
    "speedup_ngspice": (f"At least {MUST_SPEEDUP['ngspice']:.0f}x faster than ngspice at equal "
                        "or better error"),
}


def _verdicts_md(found: list[dict]) -> list[str]:
    """One line per must-show: met, missed or partly met, and the figure per scope."""
    lines = ["## The targets: met or missed", ""]
    for claim, text in _CLAIM_TEXT.items():
        mine = [v for v in found if v["claim"] == claim]
        if not mine:
            continue
        judged = [v for v in mine if v["met"] is not None]
        met = sum(bool(v["met"]) for v in judged)
        word = ("NOT MEASURED" if not judged else "MET" if met == len(judged)
                else "MISSED" if met == 0 else f"PARTLY MET ({met} of {len(judged)})")
        lines.append(f"- **{word}**: {text}: " + "; ".join(_verdict_part(v) for v in mine)
                     + ".")
    return lines + [""]


def _verdict_part(v: dict) -> str:
    """The scope and its figure, saying where it misses or was not judged."""
    missed = " (missed)" if v["met"] is False else ""
    d = v["detail"]
    if v["claim"] == "feature_1e-3":
        if d["cheapest"] is None:
            return f"{v['scope']}: no row within 1e-3 (missed)"
        return f"{v['scope']} {_fmt(v['value'], '.2f')}x with {d['cheapest']}{missed}"
    if v["claim"] == "ceiling_70":
        why = " (one run, not a batch: not judged)" if d else missed
        return f"{v['scope']} {_fmt(100 * v['value'], '.0f')}%{why}"
    if isinstance(d, str):  # the peer did not run there (the case's table says why) or failed
        return f"{v['scope']} {'peer failed' if d == 'peer failed' else 'not run'}"
    if d["speedup"] is not None:
        return f"{v['scope']} {_times(d['speedup'])}{missed}"
    return (f"{v['scope']} missed: no measured row as accurate (predicted, not measured: "
            f"{_times(d['predicted_speedup'])} at {d['needed']})")


# --- how it was measured ------------------------------------------------------------------

def _method_md(machine: dict) -> list[str]:
    return ["## How it was measured", "", _machine_md(machine), "", *_method_items(), ""]


def _machine_md(machine: dict) -> str:
    took = machine.get("suite_wall_s")
    cpus, loads = machine.get("cpus"), [machine.get("load"), machine.get("load_end")]
    busy = isinstance(cpus, int) and any(isinstance(x, (int, float)) and x >= 0.5 * cpus
                                         for x in loads)
    return (f"Machine: {cpus} CPU(s) available, load average {loads[0]} at the start"
            + (f" and {loads[1]} at the end" if loads[1] is not None else "")
            + f", {machine.get('when')}"
            + (f"; the whole suite took {took / 60:.1f} min" if took else "") + "."
            + (" The machine was busy with other work while the suite ran (a load average "
               "of half its CPUs or more): every wall time is the least of repeated calls, "
               "which removes much of that load but not all of it. Throughputs are, if "
               "anything, on the low side; ratios of timings taken at different moments "
               "(speed-ups against the peers, fractions of the ceiling and of the FMA peak, "
               "whose own measurements the load slows too) can be off either way: compare "
               "with a run on a quiet machine before relying on them." if busy else ""))


def _method_items() -> list[str]:
    return [
        "- **Reference**: run 0 of each network by its method at its substeps and half as "
        "many, Richardson-extrapolated; per network below, its own error estimate and a check "
        f"by scipy DOP853 at rtol {REF_CHECK_RTOL:g}. Its *floor* is the larger of the two.",
        "- **Error**: relative L2 error of each probe (run 0) against the reference; the tables "
        "give the worst probe (bench.json has every probe). *Whole run* for the kernels; "
        "*stretch* over the peers' shorter stretch, which is all the peers simulate.",
        "- **Equal error**: a kernel row is as accurate as a peer when its stretch error is no "
        "worse than the peer's; a peer below the reference's floor counts as at the floor.",
        f"- **Wall**: the least of repeated calls, kernels and the scipy and numpy peers alike "
        f"({MIN_CALLS} or more for a kernel, 1 or more for a peer, repeated while they took "
        f"under {REPEAT_FOR:g} s in all, at most {MAX_CALLS}; ngspice once). A kernel's "
        "repeated calls record into the buffer of the call before (`simulate`'s "
        "`record_into`), as the ceiling reuses its memory, so they do not wait for the OS to "
        "zero fresh pages (what that costs is stated per network). Rows re-timed in "
        "alternation with the ceiling say so.",
        "- **Compile**: the first call's time (a load from numba's cache when the kernel was "
        "built before).",
        "- **Throughput**: run-seconds per wall-second (a batch's runs in lockstep; the peers "
        "run one).",
        "- **Ceiling**: the measured arithmetic ceiling (`springc.bench.ceiling`) for the "
        "network's size and batch at the row's step and precision, rated with the RK4 flop "
        "count, the best of its measurements (taken in alternation with the re-timed rows). "
        "It is that of a kernel moving its stage rows through memory at every stage, as the "
        "shared kernel does; a register kernel, its stage values in registers, can pass it. "
        "The claim is about batched kernels: a network of one run is reported, not judged.",
        "- **FMA peak**: the machine's (`ceiling.measure_peak`: chains of FMAs in registers, "
        "vectorised over the batch's lanes), rated the same way; no kernel doing the counted "
        "flops can pass it (informative, decides nothing).",
        "- **No probes**: rows run by the same kernel recording nothing (timing only): what "
        "recording the probes costs, memory traffic the ceiling does not do.",
        "- **Peers**: scipy DOP853 twice, as the target was set (rtol 1e-6, atol 1e-12, "
        "scipy's free step size) and held to max_step tstep/8 (`springc.bench.reference`'s "
        "default: the linearly interpolated input has a kink at every sample, which step "
        "control alone steps over with a visible error); RK45 held to tstep/8; plain numpy "
        "RK4 at one step per sample; ngspice (trap, reltol 1e-9) where it is installed.",
        "- **Ladder**: finer rows measured while a peer's error was within reach of the "
        "network's affordable substeps.",
    ]


def _first_touch_md(touch: dict[str, dict[str, float]]) -> str:
    """One line: how much of a recorded call is the OS handing out fresh pages."""
    parts = [f"{_fmt(t['mb'])} MB in {p}: {_fmt(1e3 * t['s'], '.3g')} ms"
             + (f", {_fmt(100 * t['share'], '.0f')}% of the RK4 x1 call" if t["share"] else "")
             + (f"; its lines written into memory handed out already (non-temporal stores, "
                f"as the kernels write): {_fmt(1e3 * t['store_s'], '.3g')} ms, which after "
                "the ceiling's own time would leave the row at most "
                f"{_fmt(100 * t['store_bound'], '.0f')}% of the ceiling if the stores "
                "overlapped none of the arithmetic" if "store_bound" in t else "")
             for p, t in touch.items()]
    threads = max(t["threads"] for t in touch.values())
    return ("a recorded call into fresh memory pays first the OS's zeroing of its pages (the "
            "timed calls reuse their record buffer, as the ceiling reuses its memory); the "
            f"first touch of that much alone (a zeroed array, one write per 4 KiB page, "
            f"{threads} thread{'s' if threads > 1 else ''} each on its own runs, least of the "
            "re-timing rounds): " + "; ".join(parts) + ".")


def _claims_md(found: dict) -> list[str]:
    lines = ["### Every figure in full", ""]
    for precision in ("float64", "float32"):
        fe = found.get(f"feature_1e-3_{precision}")
        if fe:
            lines.append(
                f"- Feature extractor, {precision}: RK4 at 32 kHz has worst probe error "
                f"{_fmt(fe['rk4_x1_error'])}; the cheapest configuration with every probe "
                f"within 1e-3 is **{fe['cheapest']}** (worst {_fmt(fe['cheapest_error'])}) at "
                f"**{_fmt(fe['wall_ratio_to_rk4_x1'], '.2f')}x** the wall time of RK4 at "
                "32 kHz in the same precision (target: at most 1.5x).")
    for name in found["ceiling_fraction"]:
        lines += _ceiling_lines(found, name)
    for name, rows in found["speedups"].items():
        lines += [_speedup_line(name, s) for s in rows]
    return lines + [""]


def _ceiling_lines(found: dict, name: str) -> list[str]:
    """The RK4 x1 rows of case `name` against the ceiling and the FMA peak, and the first
    touch of their record."""
    lines = []
    parts = [f"{p} {_fmt(100 * v, '.0f')}%" for p, v in found["ceiling_fraction"][name].items()
             if v]
    if parts:
        target = ("target: 70%" if found["runs"].get(name, 2) > 1
                  else "a single run: reported, the target is for batches")
        bare = [f"{p} {_fmt(100 * v, '.0f')}%" for p, v in
                found["ceiling_fraction_unrecorded"].get(name, {}).items() if v]
        fresh = [f"{p} {_fmt(100 * v, '.0f')}%" for p, v in
                 found.get("ceiling_fraction_fresh", {}).get(name, {}).items()]
        lines.append(f"- {name}: RK4 x1 throughput as a fraction of the ceiling: "
                     + ", ".join(parts) + f" ({target})"
                     + ("; the same kernels recording no probe (the ceiling writes "
                        "nothing): " + ", ".join(bare) if bare else "")
                     + ("; recording into fresh memory every call (the OS zeroes each "
                        "page before the kernel writes it): " + ", ".join(fresh)
                        if fresh else "") + ".")
        peak = [f"{p} {_percent(v)}" for p, v in found["peak_fraction"].get(name, {}).items()]
        if peak:
            lines.append(f"- {name}: RK4 x1 throughput as a fraction of the machine's FMA "
                         "peak (informative): " + ", ".join(peak) + ".")
    touch = found.get("first_touch", {}).get(name)
    if touch:
        lines.append(f"- {name}: " + _first_touch_md(touch))
    return lines


def _speedup_line(name: str, s: dict) -> str:
    at = (f" (below the reference's floor {_fmt(s['floor'])}: compared at the floor)"
          if s["floor_limited"] else "")
    if s["speedup"] is not None:
        return (f"- {name}: {s['kernel']} (stretch error {_fmt(s['kernel_error'])}) is "
                f"**{_fmt(s['speedup'], '.0f')}x** faster per run-second than {s['peer']} "
                f"(error {_fmt(s['peer_error'])}{at}).")
    return (f"- {name}: no measured kernel row reaches {s['peer']}'s error "
            f"{_fmt(s['peer_error'])}{at}; the most accurate, {s['closest']} "
            f"({_fmt(s['closest_error'])}), is {_fmt(s['closest_speedup'], '.0f')}x faster per "
            f"run-second; by {s['order']}-order convergence {s['needed']} would reach it, "
            f"about {_fmt(s['predicted_speedup'], '.0f')}x faster if its cost grows linearly "
            "with the substeps (predicted, not measured).")


def _case_detail(r: CaseResult) -> list[str]:
    """The case's ceiling, reference and ladder, and every column of every row in the order
    measured (rows recording no probe included)."""
    bounds = (f"{r.dofs} dofs, {r.runs} run(s) of {r.tstop:g} s at tstep {r.tstep:.4g} s; "
              f"peers' stretch {r.peer_tstop:g} s; ceiling (RK4-rated, 1 step per sample): "
              + ", ".join(f"{p} {v:.3g} run-s/s" for p, v in r.ceiling.items())
              + ("; FMA peak, rated the same: "
                 + ", ".join(f"{p} {v:.3g} run-s/s" for p, v in r.peak.items())
                 if r.peak else ""))
    lines = [f"### {r.name} in full", "", bounds, "", _reference_md(r), "",
             f"Ladder: {r.ladder_note}.", "",
             ("| integrator | worst error, whole run (probe) | worst error, stretch | "
              "wall s | compile s | wall s per run-s | throughput run-s/s | of ceiling | "
              "of FMA peak | note |"),
             "|---|---|---|---|---|---|---|---|---|---|"]
    for row in r.rows:
        worst = max(row.errors, key=row.errors.get) if row.errors else ""
        whole = (f"{_fmt(row.max_error)} ({worst})" if row.name.startswith("kernel")
                 else f"- ({worst})") if row.errors else "-"
        lines.append(
            f"| {row_label(row)} | {whole} | {_fmt(row.max_stretch_error)} | "
            f"{_fmt(row.wall_s)} | {_fmt(row.compile_s, '.2f')} | "
            f"{_fmt(row.wall_per_run_second if row.simulated_s else None)} | "
            f"{_fmt(row.throughput)} | "
            f"{_percent(row.ceiling_fraction)} | {_percent(row.peak_fraction)} | "
            f"{row.note} |")
    return lines + [""]


def _reference_md(r: CaseResult) -> str:
    ref = r.reference
    if not ref:
        return "Reference: none recorded."
    return (f"Reference: {ref['method']} x{ref['substeps']} and x{ref['substeps'] // 2}, "
            f"Richardson-extrapolated ({_fmt(ref['wall_s'], '.1f')} s). Its error estimate "
            f"(|fine - coarse| / {2 ** method_order(ref['method']) - 1}, the fine run's own "
            "error; worst probe): "
            f"{_fmt(worst_error(ref['estimate']))} over the run, "
            f"{_fmt(worst_error(ref['stretch_estimate']))} over the peers' stretch. Check: scipy "
            f"DOP853 at rtol {ref['check_rtol']:g} (max_step tstep/{REF_CHECK_MAX_STEP}) "
            f"differs from it by {_fmt(worst_error(ref['check']))} over the first "
            f"{ref['check_tstop']:g} s ({_fmt(ref['check_wall_s'], '.1f')} s). Floor: "
            f"{_fmt(ref['floor'])}.")


# --- the plot -----------------------------------------------------------------------------

def plot(r: CaseResult, path: Path) -> None:
    """Speed against error: wall seconds per simulated run-second against the worst probe
    error on the peers' stretch (the errors the equal-error comparison uses), one line per
    method and precision through its substeps, the peers as crosses, the reference's floor
    dashed. Written atomically, with no metadata that changes between renderings."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.6))
    groups: dict[tuple[str, str], list[Row]] = {}
    for row in _kernels(r):
        if measured(row, "kernel") and row.simulated_s:
            groups.setdefault((row.method, row.precision), []).append(row)
    for (method, precision), rows in groups.items():
        xs = [row.wall_per_run_second for row in rows]
        ys = [max(row.max_stretch_error, 1e-16) for row in rows]
        single = precision == "float32"
        ax.loglog(xs, ys, marker=MARKERS.get(method, "v"), ls="--" if single else "-",
                  color=COLOURS.get(method, "C5"), mfc="white" if single else None,
                  label=f"{method} {precision}")
        for row, x, y in zip(rows, xs, ys):
            ax.annotate(f"x{row.substeps}", (x, y), fontsize=6, xytext=(3, 2),
                        textcoords="offset points")
    for peer in (p for p in _peers(r) if measured(p, "peer")):
        err = max(peer.max_stretch_error, 1e-16)
        ax.loglog(peer.wall_per_run_second, err, "X", color="black", ms=7)
        ax.annotate(peer.method, (peer.wall_per_run_second, err), fontsize=7, xytext=(4, 3),
                    textcoords="offset points")
    floor = r.reference.get("floor")
    if floor:
        ax.axhline(floor, color="grey", ls=":", lw=0.8)
        ax.annotate("reference floor", (ax.get_xlim()[0], floor), fontsize=7, color="grey",
                    xytext=(3, 2), textcoords="offset points")
    ax.set_xlabel("wall seconds per simulated run-second (left is faster; crosses: peers)")
    ax.set_ylabel(f"worst probe error, first {_ms(r.peer_tstop)}")
    ax.set_title(f"{r.name}: {r.title}", fontsize=9)
    ax.grid(True, which="major", alpha=0.3)
    if groups:
        ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)


def _save(fig, path: Path) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".png")
    os.close(fd)
    try:
        fig.savefig(tmp, dpi=90, metadata={"Software": None})
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    finally:
        Path(tmp).unlink(missing_ok=True)
