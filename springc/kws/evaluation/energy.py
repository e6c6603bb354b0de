"""Where the input work goes in a mass-spring keyword spotter: the energy dissipated in each
stage of the classifier network (Mel filters, low-pass masses, delay lines, terminals, mvm
heads, readouts) against the work done by the input force, per clip.

The insertion loss of the paper's Fig. 8e-f (readouts over input work) is the last row; the
rows before it say which stage costs what. The balance closes: work in = energy dissipated in
all stages + mechanical energy left at the end (`check_balance`, a test).
"""

from __future__ import annotations

import re

import numpy as np

from springc.lang.ir import FlatNetlist
from springc.check import check

# Stage of a mass element, by its flattened name (`springc.kws.features.massspring.front_end` and
# `springc.kws.training.transfer.head_text` name them).
STAGES: tuple[tuple[str, str], ...] = (
    ("Mel filters", r"^Xf\d+\."),
    ("low-pass masses", r"^Xlp\d+\."),
    ("compressors", r"^Xc\d+\."),
    ("delay lines", r"^Xd\d+_\d+\."),
    ("terminals", r"^Mf\d+_\d+$"),
    ("mvm heads", r"^Xh\d+\.Xm\."),
    ("readouts", r"^Xh\d+\.Xr\."),
)


def stage_of(mass_name: str) -> str:
    """The stage a mass element belongs to ("other" if none matches)."""
    for stage, pattern in STAGES:
        if re.match(pattern, mass_name):
            return stage
    return "other"


def stage_dampers(net: FlatNetlist) -> dict[str, list[str]]:
    """{stage: names of its damped mass elements} in STAGES order (empty stages left out)."""
    m = net.masses
    groups: dict[str, list[str]] = {}
    for e in range(len(m)):
        if m.b[e] != 0:
            groups.setdefault(stage_of(m.names[e]), []).append(m.names[e])
    order = [s for s, _ in STAGES] + ["other"]
    return {s: groups[s] for s in order if s in groups}


def budget_reductions(net: FlatNetlist) -> list[str]:
    """The reductions `budget` needs: input work, each damped mass, final energy."""
    names = [n for group in stage_dampers(net).values() for n in group]
    return ["work:in", "energy"] + [f"dissipated:{n}" for n in names]


def budget(net: FlatNetlist, reds: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """{stage: energy dissipated (J) per clip} plus "work in" and "left at the end"."""
    out = {"work in": reds["work:in"]}
    for stage, names in stage_dampers(net).items():
        out[stage] = sum(reds[f"dissipated:{n}"] for n in names)
    out["left at the end"] = reds["energy"]
    return out


def check_balance(parts: dict[str, np.ndarray]) -> np.ndarray:
    """Per clip: |work in - dissipated - left| / work in (zero up to the integrator's error)."""
    spent = sum(v for k, v in parts.items() if k != "work in")
    return np.abs(parts["work in"] - spent) / parts["work in"]


def budget_table(parts: dict[str, np.ndarray]) -> list[str]:
    """Markdown rows: stage, median energy (J), median share of the input work (dB)."""
    work = parts["work in"]
    rows = ["| stage | energy (J, median) | of the input work (dB, median) |", "|---|---|---|"]
    for stage, e in parts.items():
        with np.errstate(divide="ignore"):
            db = 10 * np.log10(np.median(e / work))
        rows.append(f"| {stage} | {np.median(e):.3g} | {db:.1f} |")
    return rows


def run_budget(net: FlatNetlist, signals: np.ndarray, tstop: float, *,
               substeps: int | None = None) -> dict[str, np.ndarray]:
    """Simulate `signals` (clips, samples) at the clips' 16 kHz through `net` (in float64)
    and return `budget`."""
    from springc.kws.features.massspring import INPUT_RATE
    from springc.sim.simulate import simulate

    sig = np.atleast_2d(np.asarray(signals, dtype=np.float64))[:, None, :]
    res = simulate(check(net), sig, INPUT_RATE, probes=[], reductions=budget_reductions(net),
                   tstop=tstop, batch=len(sig), substeps=substeps)
    return budget(net, res.reductions)


def model_budget(model_dir, signals: np.ndarray) -> dict[str, np.ndarray]:
    """The budget of a trained mass-spring model's whole classifier on `signals`."""
    from springc.kws.features import massspring as msp
    from springc.kws.training import transfer as tr
    from springc.kws.training.model import load_model
    from springc.lang import load_text

    model = load_model(model_dir)
    s, heads = tr.model_heads(model)
    net = load_text(tr.classifier_text(heads, s), f"{model_dir}/classifier (with heads)")
    return run_budget(net, signals, msp.horizon(s, signals.shape[-1] / msp.INPUT_RATE))


def test_split_budget(model_dir, data=None, clips: int = 8) -> dict[str, np.ndarray]:
    """`model_budget` on the first `clips` test clips of the model's data set (or `data`)."""
    from pathlib import Path

    from springc.errors import UsageError
    from springc.kws.features import massspring as msp
    from springc.kws.evaluation.evaluate import trained_data
    from springc.kws.training.model import load_model
    from springc.kws.data.task import open_task_data

    model = load_model(model_dir)
    if model.settings.get("realisation") != "mass-spring":
        raise UsageError("the energy budget needs a mass-spring model",
                         hint="train one with --realisation mass-spring")
    data = Path(data) if data else trained_data(model)
    ds = open_task_data(data, model.settings["task"], int(model.settings.get("seed", 0)),
                        model.settings.get("protocol"))
    signals = msp.load_signals(ds.split("test")[:clips], False, 0, [])
    return model_budget(model_dir, signals)
