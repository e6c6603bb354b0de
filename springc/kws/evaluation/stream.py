"""Keyword spotting over a whole recording (`springc classify --stream`): decisions through
time, the detections they make, and a plot of every class's readout over the waveform.

The recording is high-passed as the clips are (`preprocess.remove_background`) but not
centred: a device listening to a stream cannot know where a word will sit. Each decision
belongs to a one-clip window, timed by the window's centre (where training put the words).

- Digital models: the window slides over the recording, HOP apart, padded with half a clip
  of silence at each end; each window is scored like a clip. (The log-Mel baseline cannot
  stream: `check_streamable`.)
- Mass-spring models: the whole classifier network (`classifier.spr`) is simulated once over
  the whole recording from rest, as the device would hear it, and the readouts x(r_k) are
  recorded. A readout is a leaky integrator: past its fast pole,
  x_r(t) = e^(-W p) x_r(t - W) + int_{t-W}^t e^(-(t-s) p) F(s) ds / D (p its slow pole, 1/tau
  with tau = 80 s), so its increase over the last clip horizon W, x_r(t) - e^(-W p) x_r(t-W),
  is what a network started at rest W ago would read at t: the decision of the window
  [t - W, t], compared with the head's scale and intercept as `transfer.decisions` does at
  the end of a clip (W is `massspring.horizon` of one clip, so at t = W it is exactly the
  clip's decision; later the network may not have returned to rest from earlier sound when
  a window opens, as in the device: for a word one clip horizon of silence after another,
  the decision was 7e-4 of the largest decision off the word's own, tests/test_kws_stream.py).
  A device reads it with one sample-and-hold per readout. Without the subtraction the 80 s
  memory piles every earlier word into the decision (1.6 times the largest decision off in
  the same test).

A detection: a run of consecutive windows, at least MIN_RUN long, whose predicted class
(argmax of the rows) is the same command with a positive decision (one-versus-rest: "this
class, not the rest"). `_unknown_` and `_silence_` are never detections. A word shorter than
a clip is whole inside every window centred within (clip - word) / 2 of it, and there the
features hardly change (the Gram integral of a whole word does not depend on where in the
window it sits, up to the e^(-t/tau) weight): the decision is a plateau with the word at its
centre, entered and left through windows that hold part of the word. So a detection is timed
by the decision-weighted mean of its windows' centres (the plateau's middle, not its first
maximum), and runs shorter than MIN_RUN, made by a part of a word that resembles another
word at a plateau's edge, are dropped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from springc.errors import UsageError
from springc.kws.evaluation.classify import (CLIP_SECONDS, Recording, decision_rows,
                                             feature_settings, model_for, read_recordings,
                                             row_names, sound_files)
from springc.kws.data.dataset import CLIP_SAMPLES, COMMANDS, SAMPLE_RATE
from springc.kws.training.model import TrainedModel
from springc.kws.data.preprocess import remove_background

HOP = 0.1  # s between the digital windows
WINDOWS_PER_BATCH = 64  # digital windows whose features are computed together (memory)
READOUT_RATE = 1000.0  # Hz: the readouts' record; the clip horizons are whole milliseconds
TRACE_RATE = 100.0  # Hz: the mass-spring decisions reported and plotted
# s: the shortest run of windows that is a detection; a word of up to 0.85 s (GSCD's are
# shorter) answers for at least this long, the edge of a plateau for one or two hops
MIN_RUN = 0.15


@dataclass
class Trace:
    """Decisions through a recording: `times` (T,) the centres of their one-clip windows (s),
    `rows` (T, rows) the decision values, `names` the rows' names."""

    times: np.ndarray
    rows: np.ndarray
    names: list[str]


def check_streamable(model: TrainedModel) -> None:
    """UsageError for a model that cannot stream: the log-Mel baseline (its flattened
    spectrogram changes with where the word sits in the window, and it was trained on
    centred words only), or one that cannot tell a word from the rest: detection needs one
    multiclass model (kws12) whose classes include other sound than commands."""
    if model.settings["realisation"] == "baseline":
        raise UsageError(f"{model.folder} is the log-Mel baseline: its features depend on "
                         "where a word sits in the window, so --stream would answer every "
                         "window with a word anywhere in it",
                         hint="stream with a digital or mass-spring model")
    classes, m = model.models[0]
    if len(model.models) != 1 or len(m.coef) < 2:
        raise UsageError(f"{model.folder} is a {model.settings['task']} model of binary "
                         "classifiers: they have no class for silence or other words, so "
                         "--stream cannot tell when a keyword occurs",
                         hint="stream with a kws12 model")


# -- digital: sliding windows -------------------------------------------------------------------


def digital_trace(model: TrainedModel, signal: np.ndarray, hop: float = HOP) -> Trace:
    """Decisions of a digital model on one-clip windows `hop` apart over `signal`
    (high-passed), centred from 0 to the end of the recording."""
    half = CLIP_SAMPLES // 2
    padded = np.concatenate([np.zeros(half), signal, np.zeros(half)])
    step = round(hop * SAMPLE_RATE)
    starts = np.arange(0, len(padded) - CLIP_SAMPLES + 1, step)
    rows = []
    for k in range(0, len(starts), WINDOWS_PER_BATCH):
        part = starts[k:k + WINDOWS_PER_BATCH]
        windows = np.stack([padded[a:a + CLIP_SAMPLES] for a in part])
        rows.append(decision_rows(model, windows))
    return Trace(starts / SAMPLE_RATE, np.concatenate(rows), row_names(model))


# -- mass-spring: the network over the whole recording ------------------------------------------


def slow_pole() -> float:
    """p: the readouts' slow decay rate (1/s), b - sqrt(b^2 - 4 m k) over 2 m."""
    from springc.design.blocks import readout_params
    from springc.kws.training.transfer import Q_READOUT, TAU_READOUT

    r = readout_params(TAU_READOUT, Q_READOUT)
    return (r.b - math.sqrt(r.b**2 - 4 * r.m * r.k_total)) / (2 * r.m)


def network_readouts(model: TrainedModel, signal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(t, x) with x (heads, T): the readouts x(r_k) of the model's whole classifier network
    simulated over `signal` (16 kHz) and one clip horizon of silence after it, recorded at
    READOUT_RATE, integrated as the model's settings say (finer steps if it diverges)."""
    from springc.check import check
    from springc.kws.features import integration
    from springc.kws.features import massspring as msp
    from springc.kws.evaluation.evaluate import model_integration
    from springc.kws.training.transfer import model_heads
    from springc.lang import load_file
    from springc.sim.simulate import simulate

    s, heads = model_heads(model)
    checked = check(load_file(model.folder / "classifier.spr"))
    plan = model_integration(model)
    labels = [f"x(r{k})" for k in range(len(heads))]
    # float32 input, as the data sets' clips reach the network (`massspring.load_signals`)
    sig = np.asarray(signal, dtype=np.float32).astype(np.float64)[None, None, :]
    tstop = len(signal) / SAMPLE_RATE + msp.horizon(s, CLIP_SECONDS)
    times: list[np.ndarray] = []

    def run(method: str, substeps: int, idx: np.ndarray) -> dict:
        res = simulate(checked, sig[idx], msp.INPUT_RATE, probes=labels, outrate=READOUT_RATE,
                       tstop=tstop, method=method, substeps=substeps,
                       precision=plan.precision)
        times.append(res.t)
        return {"x": np.stack([res.probes[k] for k in labels], axis=1)}

    stiff = msp.stiffness(sig[:, 0], s)  # a recording too loud for the step: finer ones
    x = integration.run_with_retries(plan, run, 1, stiffness=stiff)["x"][0]
    return times[-1], x


def readout_decisions(x: np.ndarray, lag: int, decay: float, heads) -> np.ndarray:
    """(T, heads) decisions of the windows ending at each sample: the readouts' increase
    x[t] - decay x[t - lag] (x before the start: 0, the network at rest), over each head's
    scale, plus its intercept."""
    before = np.zeros_like(x)
    before[:, lag:] = x[:, :x.shape[1] - lag]
    rise = x - decay * before
    return np.stack([rise[k] / h.scale + h.intercept for k, h in enumerate(heads)], axis=1)


def network_trace(model: TrainedModel, signal: np.ndarray) -> Trace:
    """Decisions of a mass-spring model's simulated network over `signal` (module
    docstring), at TRACE_RATE, windows centred from 0 to the end of the recording."""
    from springc.kws.features import massspring as msp
    from springc.kws.training.transfer import model_heads

    s, heads = model_heads(model)
    t, x = network_readouts(model, signal)
    horizon = msp.horizon(s, CLIP_SECONDS)
    lag = round(horizon * READOUT_RATE)
    rows = readout_decisions(x, lag, math.exp(-slow_pole() * lag / READOUT_RATE), heads)
    centres = t - lag / READOUT_RATE + CLIP_SECONDS / 2
    every = round(READOUT_RATE / TRACE_RATE)
    keep = (centres >= -1e-9) & (centres <= len(signal) / SAMPLE_RATE + 1e-9)
    keep &= (np.arange(len(t)) - lag) % every == 0  # centres on the TRACE_RATE grid, 0.5 s too
    return Trace(centres[keep], rows[keep], row_names(model))


# -- detections ---------------------------------------------------------------------------------


def detections(trace: Trace, min_run: float = MIN_RUN) -> list[dict]:
    """[{"label", "time", "start", "end", "score"}]: runs of at least `min_run` s of windows
    answering one command with a positive decision, timed by the decision-weighted mean of
    their centres, scored by the largest decision (module docstring)."""
    best = np.argmax(trace.rows, axis=1)
    top = trace.rows[np.arange(len(best)), best]
    hit = np.array([trace.names[b] in COMMANDS for b in best]) & (top > 0)
    out = []
    for a, b in _runs(hit, best):
        t, w = trace.times[a:b + 1], top[a:b + 1]
        if t[-1] - t[0] < min_run - 1e-9:
            continue
        out.append({"label": trace.names[best[a]], "time": float(np.sum(w * t) / np.sum(w)),
                    "start": float(t[0]), "end": float(t[-1]), "score": float(w.max())})
    return out


def _runs(hit: np.ndarray, label: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) index of each run of consecutive hits with one label."""
    runs, k = [], 0
    while k < len(hit):
        if hit[k]:
            end = k
            while end + 1 < len(hit) and hit[end + 1] and label[end + 1] == label[k]:
                end += 1
            runs.append((k, end))
            k = end
        k += 1
    return runs


# -- the command --------------------------------------------------------------------------------


def stream_signal(recording: Recording) -> np.ndarray:
    """The recording as the stream hears it: high-passed as the clips are, not centred."""
    return remove_background(recording.signal, SAMPLE_RATE)


def trace_of(model: TrainedModel, signal: np.ndarray) -> Trace:
    """The decisions through `signal` in the model's realisation."""
    if model.settings["realisation"] == "mass-spring":
        return network_trace(model, signal)
    feature_settings(model)  # a garbled settings.json is named before the windows run
    return digital_trace(model, signal)


def stream(model_dir: Path, inputs, realisation: str | None = None, plots: Path | None = None,
           progress=lambda message: None) -> list[dict]:
    """[{"file", "seconds", "detections", "plot"}] for every sound file of `inputs`, each
    streamed whole; with `plots`, a PNG per recording there (`plot_trace`)."""
    model = model_for(model_dir, realisation, "streamed")
    check_streamable(model)
    recordings, traces = [], []
    for path in sound_files(inputs):
        recordings += read_recordings([path])
        progress(f"streaming {path} ({recordings[-1].seconds:.2f} s)")
        traces.append(trace_of(model, stream_signal(recordings[-1])))
    out = [{"file": str(rec.path), "seconds": rec.seconds, "detections": detections(trace),
            "plot": None} for rec, trace in zip(recordings, traces)]
    if plots:  # only once every recording has run: a failure leaves no plots behind
        Path(plots).mkdir(parents=True, exist_ok=True)
        for item, rec, trace, name in zip(out, recordings, traces, plot_names(recordings)):
            item["plot"] = str(Path(plots) / name)
            plot_trace(Path(item["plot"]), rec, trace, item["detections"], _title(model, rec))
    return out


def plot_names(recordings: list[Recording]) -> list[str]:
    """`<stem>.png` per recording, `<stem>-2.png` ... where stems repeat."""
    seen: dict[str, int] = {}
    names = []
    for rec in recordings:
        stem = rec.path.stem
        seen[stem] = seen.get(stem, 0) + 1
        names.append(f"{stem}.png" if seen[stem] == 1 else f"{stem}-{seen[stem]}.png")
    return names


def _title(model: TrainedModel, rec: Recording) -> str:
    f = model.settings["features"]
    size = f"{f['bins']}x{f['delays']}" if "bins" in f else "log-Mel"
    return f"{rec.path.name}: {model.settings['realisation']} {size} model"


def plot_trace(path: Path, rec: Recording, trace: Trace, found: list[dict],
               title: str) -> None:
    """The waveform above every class's decision through time (one line per row, zero
    marked), detections as labelled lines on both; written atomically (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, bx) = plt.subplots(2, 1, figsize=(11, 6), sharex=True,
                                 gridspec_kw={"height_ratios": [1, 2]})
    ax.plot(np.arange(len(rec.signal)) / SAMPLE_RATE, rec.signal, color="0.4", lw=0.5)
    ax.set_ylabel("input")
    ax.set_title(title)
    for k, name in enumerate(trace.names):
        style = "-" if name in COMMANDS else "--"
        # a leading space: matplotlib leaves labels starting with "_" out of the legend
        bx.plot(trace.times, trace.rows[:, k], style, lw=1.2, label=f" {name}")
    bx.axhline(0.0, color="black", lw=0.6)
    for d in found:
        for axis in (ax, bx):
            axis.axvline(d["time"], color="tab:red", lw=0.8, alpha=0.7)
        ax.annotate(d["label"], (d["time"], 1.0), xycoords=("data", "axes fraction"),
                    ha="center", va="bottom", color="tab:red", fontsize=9)
    bx.set_xlabel("time (s): centre of the one-clip window")
    bx.set_ylabel("decision c . Phi + b")
    bx.legend(loc="upper right", fontsize=7, ncol=max(1, len(trace.names) // 6))
    fig.tight_layout()
    tmp = path.with_name(f".{path.name}.tmp.png")
    try:
        fig.savefig(tmp, dpi=110)
        tmp.replace(path)
    finally:
        plt.close(fig)
        tmp.unlink(missing_ok=True)
