"""`springc train` and `springc eval`: the keyword spotter of the paper, trained and tested."""

from __future__ import annotations

import json
from pathlib import Path

import click
from springc_cli.common import on_device, run_user_errors

from springc.kws.data.dataset import PROTOCOLS
from springc.kws.evaluation.device import SPREAD_KINDS, STAGES
from springc.kws.features.digital import FILTERBANKS
from springc.kws.training.report import counts_table, majority_rate
from springc.kws.data.task import TASKS
from springc.kws.data.task import REALISATIONS

_REALISATION = click.Choice(REALISATIONS)
_SCHEDULER = click.option("--scheduler", default=None, metavar="ADDRESS",
                          help="Mass-spring: Dask scheduler to send the simulations to "
                               "(default: a local cluster on all cores; `eval` and "
                               "`classify` of under 512 clips: threads in this process).")
_DATA = click.option("--data", "data", required=True, type=click.Path(path_type=Path),
                     help="Data set folder in the GSCD layout (e.g. from `springc data synth`).")
_BINS = click.option("--bins", "-n", default=8, show_default=True, help="Mel filter bins n.")
_DELAYS = click.option("--delays", "-m", default=3, show_default=True, help="Delays per bin m.")
_JOBS = click.option("--jobs", "-j", default=0,
                     help="Worker processes, or threads where no cluster starts "
                          "(0: all cores).")
_NO_CACHE = click.option("--no-cache", is_flag=True,
                         help="Recompute features, ignore the cache.")
_THRESHOLD = click.option("--threshold", type=float, default=None,
                          help="Mass-spring: compression threshold A_c (m of filter output) "
                               "of the feature compressors [default: 0.001]; smaller "
                               "compresses more.")


_TOLERANCE = click.option(
    "--tolerance", type=click.FloatRange(min=0.0, min_open=True), default=1e-3,
    show_default=True, help="Mass-spring: error allowed on Phi and the readouts (relative to "
    "each clip's largest value, against RK4 x16 float64 on 16 training clips); it chooses "
    "the integrator and substeps of the networks.")
_PAPER_STEPS = click.option(
    "--paper-steps", is_flag=True,
    help="Mass-spring: integrate as the paper does (RK4, 8 substeps, float32), no choice.")


@click.command("train")
@_DATA
@_BINS
@_DELAYS
@click.option("--realisation", type=click.Choice(REALISATIONS + ("device",)), default="digital",
              show_default=True,
              help="device: a mass-spring network built for a fabricated device (summing "
                   "heads, no cancelling stiffness), its physical scale recorded.")
@click.option("--baseline", is_flag=True, help="Same as --realisation baseline.")
@click.option("--filterbank", type=click.Choice(FILTERBANKS), default="two-mode",
              show_default=True)
@click.option("--task", type=click.Choice(TASKS), default="kws12", show_default=True,
              help="kws12: GSCD's 12 classes; digits-pairs: one/two/three/four pairwise.")
@click.option("--td", default=0.032, show_default=True, help="Delay between taps (s).")
@click.option("--tau", default=80.0, show_default=True, help="Readout time constant (s).")
@click.option("--fc", default=50.0, show_default=True, help="Low-pass cut-off (Hz).")
@click.option("--feature-rate", default=1000.0, show_default=True, help="Rate of x_i(t) (Hz).")
@click.option("--protocol", type=click.Choice(PROTOCOLS), default=None,
              help="Held-out splits: the split lists as they are, or (kws12) the paper's equal "
                   "number of clips per class.  [default: balanced for kws12, else lists]")
@click.option("--class-weights", type=click.Choice(("balanced", "none")), default=None,
              help="SVM class weights: inversely proportional to the training counts, or "
                   "equal.  [default: balanced for kws12, else none]")
@_JOBS
@click.option("--seed", default=0, show_default=True,
              help="Seed of augmentation, silence windows and the unknown-word subsample.")
@_NO_CACHE
@click.option("-o", "--out", required=True, type=click.Path(path_type=Path),
              help="Model folder to write.")
@click.option("--epsilon", type=float, default=None,
              help="Mass-spring: squaring error of the classifier heads [default: 1e-5]; "
                   "above 1e-5 the taps are buffered and the multipliers stiffened "
                   "(docs/results-eps.md) unless --buffer/--mvm-stiffness say otherwise.")
@click.option("--heads", type=click.Choice(("zero-mode", "summing")), default=None,
              help="Mass-spring: the heads' multiplier, the paper's zero modes or a weighted "
                   "sum by springs per component.  [default: zero-mode; device: summing]")
@click.option("--buffer", type=(float, float), default=None, metavar="KB KG",
              help="Mass-spring: buffer the taps (springs KB kc to a buffer node, KG kc from "
                   "it to ground).")
@click.option("--mvm-stiffness", type=float, default=None,
              help="Mass-spring: factor on the zero-mode multipliers' stiffness.")
@click.option("--spl", type=float, default=None, help="Device, router: sound level (dB SPL) [60].")
@click.option("--area", type=float, default=None,
              help="Device, router: membrane area (m^2) [1e-6].")
@click.option("--temp", type=float, default=None, help="Device, router: temperature (K) [300].")
@click.option("--device-mass", type=float, default=None,
              help="Device, router: the whole device's mass (kg) [2e-9].")
@click.option("--stage-stiffness", type=float, default=None, metavar="S",
              help="Mass-spring/device: every stage after the Mel filters S times stiffer, "
                   "up to S times more of the energy reaches them [1].")
@click.option("--squarer-range", type=float, default=None, metavar="R",
              help="Mass-spring/device: filter amplitude (m) at which the squarers detune the "
                   "filters fully; smaller passes more energy on [10].")
@_THRESHOLD
@_TOLERANCE
@_PAPER_STEPS
@_SCHEDULER
@run_user_errors
@on_device
def train_cmd(data, bins, delays, realisation, baseline, filterbank, task, td, tau, fc,
              feature_rate, protocol, class_weights, jobs, seed, no_cache, out, epsilon,
              heads, buffer, mvm_stiffness, spl, area, temp, device_mass, stage_stiffness,
              squarer_range, threshold, tolerance, paper_steps, scheduler) -> None:
    """Train the keyword spotter and write a model folder with weights and a test report."""
    from springc.kws.evaluation.api import train

    report = train(data, out, bins=bins, delays=delays,
                   realisation="baseline" if baseline else realisation, filterbank=filterbank,
                   task=task, td=td, tau=tau, fc=fc, feature_rate=feature_rate,
                   protocol=protocol, class_weights=class_weights, jobs=jobs, seed=seed,
                   use_cache=not no_cache, epsilon=epsilon, threshold=threshold,
                   tolerance=tolerance, paper_steps=paper_steps, scheduler=scheduler,
                   heads=heads, buffer=buffer, mvm_stiffness=mvm_stiffness, spl=spl,
                   area=area, temp=temp, device_mass=device_mass,
                   stage_stiffness=stage_stiffness, squarer_range=squarer_range)
    click.echo(_summary(report))
    if "integration" in report:
        from springc.kws.features.integration import from_dict

        click.echo(f"integration of the features: "
                   f"{from_dict(report['integration']['features']).describe()}")
    click.echo(f"model written to {out}")


@click.command("eval")
@click.argument("model_dir", type=click.Path(path_type=Path))
@click.option("--data", type=click.Path(path_type=Path), default=None,
              help="Data set folder (default: the one the model was trained on).")
@click.option("--realisation", type=_REALISATION, default=None,
              help="Must match the model's (default: the model's).")
@click.option("--protocol", type=click.Choice(PROTOCOLS), default=None,
              help="Test split: as listed (or every clip of a folder without split lists), "
                   "or (kws12) the paper's equal number of clips per class.  [default: the "
                   "model's]")
@click.option("--json", "as_json", is_flag=True, help="Print accuracy, n, per_class as JSON.")
@_JOBS
@_NO_CACHE
@click.option("--budget", type=click.IntRange(min=1), default=None, metavar="N",
              help="Mass-spring models: instead, print where the input work goes (energy "
                   "dissipated per stage) over the first N test clips, in the network's "
                   "units and at physical scale (--spl, --area, --temp, --device-mass or "
                   "--mass; defaults 60 dB, 1e-6 m^2, 300 K, 2e-9 kg) in J and k_B T, "
                   "beside the most a decision may lose of the sound.")
@click.option("--mc", "devices", type=int, default=None, metavar="N",
              help="Mass-spring models: instead, the accuracy of N fabricated devices, every "
                   "element coefficient of the whole network times (1 + S gauss).")
@click.option("--spread", type=float, default=None, metavar="S",
              help="With --mc: relative standard deviation of the coefficients (0.01: 1%).")
@click.option("--spread-kind", type=click.Choice(SPREAD_KINDS), default=None,
              help="With --mc: local mismatch (a draw per element) or global (one draw per "
                   "kind of coefficient).  [default: local]")
@click.option("--stage", type=click.Choice(STAGES + ("all",)), default=None,
              help="With --mc: spread only this stage's coefficients.  [default: all]")
@click.option("--trim", type=int, default=None, metavar="K",
              help="With --mc: also trim each device on K labelled validation clips (the "
                   "gain and offset each readout is read with, refitted) and print the "
                   "trimmed accuracy beside the untrimmed.")
@click.option("--temp", type=float, default=None, metavar="K",
              help="Mass-spring models: instead, the network at physical scale (with --mass, "
                   "--spl, --area) with thermal noise on every damper at K kelvin.")
@click.option("--mass", type=float, default=None, metavar="KG",
              help="With --temp or --budget: kg per normalised mass unit.")
@click.option("--device-mass", type=float, default=None, metavar="KG",
              help="With --temp or --budget: the whole device's mass in kg (instead of "
                   "--mass).")
@click.option("--spl", type=float, default=None, metavar="DB",
              help="With --temp or --budget: sound level of the clips, dB SPL re 20 uPa.")
@click.option("--area", type=float, default=None, metavar="M2",
              help="With --temp or --budget: membrane area in m^2 (input force = pressure x "
                   "area).")
@click.option("--seed", type=int, default=None,
              help="Seed of the --mc devices or the --temp noise.  [default: 0]")
@click.option("--clips", type=click.IntRange(min=1), default=None, metavar="N",
              help="With --mc or --temp: N test clips spread evenly over the split.")
@_SCHEDULER
@run_user_errors
@on_device
def eval_cmd(model_dir, data, realisation, protocol, as_json, jobs, no_cache, scheduler,
             budget, devices, spread, spread_kind, stage, trim, temp, mass, device_mass, spl,
             area, seed, clips) -> None:
    """Evaluate a trained model on the test split of a labelled folder in the GSCD layout:
    the clips testing_list.txt names, or every clip where the folder has no such list.
    --mc/--spread: a population of fabricated devices; --temp/--mass/--spl/--area: the
    device at physical scale with thermal noise."""
    from springc.kws.evaluation import device
    from springc.kws.evaluation.api import evaluate

    report = evaluate(model_dir, data, realisation=realisation, protocol=protocol, jobs=jobs,
                      use_cache=not no_cache, scheduler=scheduler, budget=budget, mc=devices,
                      spread=spread, spread_kind=spread_kind, stage=stage, temp=temp,
                      mass=mass, spl=spl, area=area, seed=seed, clips=clips,
                      device_mass=device_mass, trim=trim,
                      progress=lambda s: click.echo(s, err=True))
    # the scale the study ran at: what was given, else what a device or router model recorded
    which = None if budget else device.study(
        devices, spread, spread_kind, stage, seed, temp,
        report.get("mass", mass), report.get("spl", spl), report.get("area", area))
    click.echo(_eval_text(report, which, budget, as_json))


def _eval_text(report: dict, which, budget: int | None, as_json: bool) -> str:
    """What `springc eval` prints: a device study's report, the energy budget, or the
    evaluation's summary (`--json`: the study's whole report, the evaluation's figures)."""
    from springc.kws.evaluation import device

    if which is not None:
        if as_json:
            return json.dumps(report)
        lines = device.spread_lines if isinstance(which, device.Spread) else device.physical_lines
        return "\n".join(lines(report, which))
    if budget:
        from springc.kws.evaluation import energy

        return json.dumps(energy.budget_json(report)) if as_json else _budget_text(report)
    if not as_json:
        return _summary(report)
    keys = ("accuracy", "majority_rate", "n", "per_class")
    keys += ("pairs",) if "pairs" in report else ()
    keys += tuple(k for k in _NETWORK_KEYS if k in report)
    return json.dumps({k: report[k] for k in keys})


def _budget_text(report: dict) -> str:
    """`springc eval --budget`: where the input work goes, per stage, in the network's units
    and at physical scale."""
    from springc.kws.evaluation import energy

    parts, sc = report["normalised"], report["scale"]
    scale = energy.Scale(sc["spl"], sc["area"], sc["temp"], mass=sc["mass"])
    return "\n".join([f"energy budget of the whole classifier, {len(parts['work in'])} test "
                      f"clips (balance error {energy.check_balance(parts).max():.1e}):",
                      *energy.budget_table(parts), "",
                      f"at physical scale: a device of {sc['device_mass']:.3g} kg, "
                      f"{sc['spl']:g} dB SPL ({sc['pressure']:.3g} Pa) on {sc['area']:.3g} m^2, "
                      f"{sc['temp']:g} K:",
                      *energy.physical_table(parts, report["joules_per_unit"], scale,
                                             report["seconds"], report["readouts"])])


_NETWORK_KEYS = ("digital_same_model", "insertion_loss_db", "readout_error", "throughput")


def _summary(report: dict) -> str:
    lines = []
    if "counts" in report:  # a fresh training: the data it saw
        weights = report["class_weight"] or "equal"
        lines.append(f"protocol {report['protocol']}, class weights {weights}; clips:")
        lines += ["  " + row for row in counts_table(report["counts"]).splitlines()]
    lines.append(f"test accuracy {100 * report['accuracy']:.2f}% on {report['n']} clips "
                 f"(majority class {100 * _majority(report):.2f}%)")
    if "digital_same_model" in report:  # a simulated network: mass-spring or router
        t, il = report["throughput"], report["insertion_loss_db"]
        lines[0] += (f" ({report['realisation']}); digital readout of the same model "
                     f"{100 * report['digital_same_model']['accuracy']:.2f}%")
        lines.append(f"  insertion loss {il['median']:.1f} dB (median), readout error "
                     f"{100 * report['readout_error']:.2f}%, {t['clips_per_s']:.2f} clips/s "
                     f"on {t['cores'] or 'the cluster'} cores")
    for name, r in report.get("pairs", {}).items():
        paper = f" (paper: {100 * r['paper']:.1f}%)" if r.get("paper") else ""
        lines.append(f"  {name:12s} {100 * r['accuracy']:6.2f}% of {r['n']}{paper}")
    for cls, tpr in report["per_class"].items():
        lines.append(f"  {cls:12s} TPR {'n/a' if tpr is None else f'{100 * tpr:6.2f}%'}")
    return "\n".join(lines)


def _majority(report: dict) -> float:
    """The majority-class rate: from the report, or its confusion matrix (older reports)."""
    if "majority_rate" in report:
        return report["majority_rate"]
    return majority_rate(report["confusion"])


@click.command("cv")
@_DATA
@_BINS
@_DELAYS
@click.option("--realisation", "realisations", type=click.Choice(("digital", "mass-spring")),
              multiple=True, help="Realisations to compare, the first as the reference "
                                  "(repeat the option).  [default: digital, mass-spring]")
@click.option("--folds", "-k", default=5, show_default=True,
              help="Speaker-disjoint folds (each tests its clips once).")
@_THRESHOLD
@_JOBS
@click.option("--seed", default=0, show_default=True,
              help="Seed of the silence windows and of the bootstrap.")
@_NO_CACHE
@click.option("-o", "--out", required=True, type=click.Path(path_type=Path),
              help="Folder for cv.json and cv.png.")
@_TOLERANCE
@_PAPER_STEPS
@_SCHEDULER
@run_user_errors
@on_device
def cv_cmd(data, bins, delays, realisations, folds, threshold, jobs, seed, no_cache, out,
           tolerance, paper_steps, scheduler) -> None:
    """Speaker-grouped cross-validation (12 classes) on every clip of a data set: the
    class-balanced accuracy of each realisation and their paired difference, with bootstrap
    standard errors over speakers."""
    from springc.kws.evaluation import crossval
    from springc.kws.evaluation.api import cross_validate

    report = cross_validate(data, None, bins=bins, delays=delays, realisations=realisations,
                            folds=folds, threshold=threshold, jobs=jobs, seed=seed,
                            use_cache=not no_cache, tolerance=tolerance,
                            paper_steps=paper_steps, scheduler=scheduler,
                            progress=lambda s: click.echo(s, err=True))
    click.echo("\n".join(crossval.summary_lines(report)))
    paths = crossval.write(report, out)
    click.echo(f"wrote {paths[0]} and {paths[1]}")


@click.command("classify")
@click.argument("model_dir", type=click.Path(path_type=Path))
@click.argument("inputs", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("--realisation", type=_REALISATION, default=None,
              help="Must match the model's (default: the model's); a mass-spring model's "
                   "whole classifier network is simulated.")
@click.option("--json", "as_json", is_flag=True,
              help="Print a JSON list: per file its label and scores (--stream: detections).")
@click.option("--stream", is_flag=True,
              help="Run over each whole recording, as the physical device would, and report "
                   "when keywords occur.")
@click.option("--plots", type=click.Path(path_type=Path), default=None, metavar="DIR",
              help="With --stream: write DIR/<file>.png, every class's decision through time "
                   "under the waveform (DIR is made if missing).")
@_JOBS
@_SCHEDULER
@run_user_errors
@on_device
def classify_cmd(model_dir, inputs, realisation, as_json, stream, plots, jobs,
                 scheduler) -> None:
    """Classify sound files (or the sound files under folders) with a trained model: per file
    the predicted label and every class's score (the decision values eval scores). Files
    longer than a clip: --stream for detections through the whole recording."""
    if plots is not None:
        _check_plot_folder(plots, stream)
    if stream:
        from springc.kws.evaluation.stream import stream as run_stream

        results = run_stream(model_dir, inputs, realisation, plots,
                             progress=lambda s: click.echo(s, err=True))
        click.echo(json.dumps(results) if as_json else _stream_lines(results))
        return
    from springc.kws.evaluation.classify import classify

    results = classify(model_dir, inputs, realisation, jobs=jobs, scheduler=scheduler)
    click.echo(json.dumps(results) if as_json else _classify_lines(results))


def _check_plot_folder(plots: Path, stream: bool) -> None:
    """--plots: only with --stream, a folder that can be made or written (checked before
    the work; made only when the plots are written)."""
    from springc.errors import DataError, UsageError
    from springc_cli.common import check_output_file

    if not stream:
        raise UsageError("--plots draws the decisions through a streamed recording",
                         hint="add --stream")
    if plots.exists() and not plots.is_dir():
        raise DataError(str(plots), "is a file, not a folder for the plots")
    check_output_file(plots / "plot.png", make_parents=True)


def _classify_lines(results: list[dict]) -> str:
    """`FILE: label` and the scores, highest first."""
    lines = []
    for r in results:
        ranked = sorted(r["scores"].items(), key=lambda kv: -kv[1])
        lines.append(f"{r['file']}: {r['label']}")
        lines.append("  " + "  ".join(f"{c} {v:+.3f}" for c, v in ranked))
    return "\n".join(lines)


def _stream_lines(results: list[dict]) -> str:
    """Per recording its length, then one line per detection."""
    lines = []
    for r in results:
        found = r["detections"]
        lines.append(f"{r['file']} ({r['seconds']:.2f} s): {len(found)} detection(s)"
                     + (f", plot {r['plot']}" if r["plot"] else ""))
        for d in found:
            lines.append(f"  {d['time']:7.2f} s  {d['label']:<6} score {d['score']:+.3f} "
                         f"(windows centred {d['start']:.2f}-{d['end']:.2f} s)")
    return "\n".join(lines)
