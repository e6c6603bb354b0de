"""Where the 8x3 classifier network departs from the squaring unit: the distortion of every
stage's output against its ideal as the heads' squaring error eps grows.

    python scripts/results_stages.py --data CORPUS [--model MODEL] [--clips 4] [--out DIR]

The whole classifier (`springc.kws.training.transfer.classifier_text`: feature extraction and
every head, as `springc train --realisation mass-spring` writes it) is simulated on a few test
clips of CORPUS (`springc data synth CORPUS`) at each eps, with probes on every stage. The
heads are MODEL's (a trained mass-spring model) or, without --model, 12 heads of random
weights built the same way (`transfer.stand_in_heads`) at the feature amplitude A measured on
the clips (the median peak terminal displacement, as training takes it). The ideal of each
stage is its signal in the limit eps -> 0 (the same network at eps = 1e-9; only the heads
change with eps). Stages and signals: filter x(y_i); squarer y_i^2 (what drives the low-pass);
low-pass x(lp_i); compressor x(c_i); delay taps x(f_i_j); mvm outputs x(Xh_k.y_e); head
squares sum_e lambda_e y_e^2 (readout k's drive over its scale); readout x(r_k) / scale_k (c . Phi).
Distortion: RMS over time of (signal - ideal), over the ideal's peak, the largest over the
stage's channels, the median over the clips. A stage breaks at the first eps where it passes
BREAK. Prints a markdown table (eps rows, stage columns) and writes it with the JSON to --out.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from springc.check import check
from springc.kws.evaluation.studies import EPS_IDEAL, distortion, first_command_clips
from springc.kws.features import massspring as msp
from springc.kws.training import transfer as tr
from springc.lang import load_text
from springc.sim.simulate import simulate

EPSILONS = (1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1, 1.0)
BREAK = 0.01  # a stage is broken when its distortion passes 1% of its ideal's peak
STAGES = ("filter", "squarer", "low-pass", "compressor", "delay taps", "mvm outputs",
          "head squares", "readout")
OUTRATE = 16000.0  # the filters ring at up to 8 kHz: every input sample is kept
HEADS_PROBED = 2  # mvm outputs are probed on the first heads only (memory: 24 each)


def probes(s: msp.MassSpringSettings, heads: list[tr.Head]) -> dict[str, list[str]]:
    """The probed node of every channel, per stage (the squarer's and the head squares'
    signals are computed from the filter's and the mvm's)."""
    n = s.bins * s.delays
    return {"filter": [f"x(y{i})" for i in range(s.bins)],
            "low-pass": [f"x(lp{i})" for i in range(s.bins)],
            "compressor": [f"x(c{i})" for i in range(s.bins)],
            "delay taps": [f"x({node})" for node in msp.terminals(s)],
            "mvm outputs": [f"x(Xh{k}.y{e})" for k in range(min(HEADS_PROBED, len(heads)))
                            for e in range(n)],
            "readout": [f"x(r{k})" for k in range(len(heads))]}


def run(s: msp.MassSpringSettings, heads: list[tr.Head], signals: np.ndarray,
        eps: float, amplitude: float, models) -> dict[str, np.ndarray]:
    """Every stage's signals (channels, clips, T) of the network at `eps`."""
    heads = (tr.heads_for(models, s, amplitude, eps) if models
             else tr.redesigned_heads(heads, s, amplitude, eps))
    net = check(load_text(tr.classifier_text(heads, s, epsilon=eps), f"<eps {eps:g}>"))
    names = probes(s, heads)
    flat = [p for stage in names.values() for p in stage]
    tstop = msp.horizon(s, signals.shape[1] / msp.INPUT_RATE)
    res = simulate(net, signals[:, None, :], msp.INPUT_RATE, tstop=tstop, method="exp-rk4",
                   substeps=4, precision="float64", outrate=OUTRATE, probes=flat,
                   batch=len(signals))
    out = {stage: np.stack([res.probes[p] for p in plist]) for stage, plist in names.items()}
    out["squarer"] = out["filter"] ** 2
    y = out["mvm outputs"].reshape(-1, s.bins * s.delays, *out["mvm outputs"].shape[1:])
    out["head squares"] = np.stack([np.einsum("e,ect->ct", _weights(h, s), y[k] ** 2)
                                    for k, h in enumerate(heads[:HEADS_PROBED])])
    out["readout"] = out["readout"] / np.array([h.scale for h in heads])[:, None, None]
    if not all(np.all(np.isfinite(v)) for v in out.values()):
        raise RuntimeError(f"the network diverged at eps {eps:g}")
    return out


def _weights(head: tr.Head, s: msp.MassSpringSettings) -> np.ndarray:
    """lambda of every mvm output of a head (0 for the uncoupled components): the couplings'
    gamma over the head's scale, so that sum lambda y^2 is the readout's drive in units of
    c . Phi whatever eps and A."""
    w = np.zeros(s.bins * s.delays)
    w[head.keep] = head.lam[head.keep]
    return w


def table(rows: dict[float, dict[str, float]]) -> str:
    """Markdown: eps rows, stage columns, the first broken stage last."""
    lines = ["| eps | " + " | ".join(STAGES) + " | first past 1% |",
             "|---" * (len(STAGES) + 2) + "|"]
    for eps, d in rows.items():
        broken = [st for st in STAGES if d[st] > BREAK]
        lines.append(f"| {eps:g} | " + " | ".join(f"{d[st]:.2g}" for st in STAGES)
                     + f" | {broken[0] if broken else '-'} |")
    return "\n".join(lines)


def _parser() -> argparse.ArgumentParser:
    """The command line: the corpus, the model (default: stand-in heads), clips and output."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--model", type=Path)
    ap.add_argument("--clips", type=int, default=4)
    ap.add_argument("--out", type=Path, default=Path("stages-out"))
    return ap


def _heads(model_path: Path | None, s: msp.MassSpringSettings) -> tuple:
    """(settings, heads, models): a trained model's, or stand-in heads at `s` (models None)."""
    if not model_path:
        return s, tr.stand_in_heads(s), None
    from springc.kws.training.model import load_model

    model = load_model(model_path)
    s, heads = tr.model_heads(model)
    return s, heads, model.models


def main() -> None:
    args = _parser().parse_args()
    start = time.time()
    s = msp.MassSpringSettings(bins=8, delays=3)
    signals = first_command_clips(args.data, args.clips)
    s, heads, models = _heads(args.model, s)
    # at eps -> 0 no stage depends on A (the readout and head squares are in units of c . Phi)
    ideal = run(s, heads, signals, EPS_IDEAL, 1.0, models)
    # A as training measures it: the median over the clips of the peak terminal displacement
    amplitude = float(np.median(np.abs(ideal["delay taps"]).max(axis=(0, 2))))
    rows = {}
    for eps in EPSILONS:
        got = run(s, heads, signals, eps, amplitude, models)
        rows[eps] = {st: distortion(got[st], ideal[st]) for st in STAGES}
        print(f"eps {eps:g}: " + ", ".join(f"{st} {v:.3g}" for st, v in rows[eps].items()),
              flush=True)
    text = table(rows)
    print(text)
    print(f"A = {amplitude:.4g} m, {len(signals)} clips, {time.time() - start:.0f} s")
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "stages.md").write_text(text + "\n")
    (args.out / "stages.json").write_text(json.dumps(
        {"amplitude": amplitude, "clips": len(signals), "model": str(args.model or ""),
         "rows": {f"{e:g}": d for e, d in rows.items()}}, indent=2) + "\n")


if __name__ == "__main__":
    main()
