"""Accuracy against energy (paper Fig. 8e-f): the squaring error eps of the classifier heads
and the feature compression threshold, each with the insertion loss of the whole network
(energy dissipated in the readouts over the work done by the input, on the test split).

- `epsilon_sweep`: one trained mass-spring model, its heads re-designed for every eps (the
  front end and the SVM stay; only gamma, alpha and the readout scale change).
- `compression_sweep`: the model trained again for every compression threshold A_c (the
  features change, so the SVM does), then simulated at the default eps.
`plot_sweeps` draws both as accuracy against insertion loss.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from springc.kws.features import massspring as msp
from springc.kws.training import transfer as tr


def epsilon_sweep(model_dir: Path, data: Path, epsilons, *, scheduler: str | None = None,
                  jobs: int = 0) -> list[dict]:
    """[{epsilon, accuracy, ideal_accuracy, insertion_loss_db, readout_error}] for a trained
    mass-spring model, one whole-network simulation of the test split per eps."""
    from springc.kws.evaluation.evaluate import evaluate_network
    from springc.kws.training.model import load_model
    from springc.kws.data.task import open_task_data
    from springc.lang import load_text

    model = load_model(model_dir)
    ds = open_task_data(data, model.settings["task"], int(model.settings.get("seed", 0)),
                        model.settings.get("protocol"))
    s, _ = tr.model_heads(model)
    amp = float(model.settings["transfer"]["amplitude"])
    rows = []
    for eps in epsilons:
        heads = tr.heads_for(model.models, s, amp, float(eps))
        net = load_text(tr.classifier_text(heads, s, epsilon=eps), f"<classifier eps={eps:g}>")
        rep = evaluate_network(model, ds, scheduler=scheduler, jobs=jobs, heads=heads, net=net)
        rows.append(_row(rep, epsilon=float(eps)))
    return rows


def compression_sweep(data: Path, thresholds, out: Path, *, bins: int = 4, delays: int = 2,
                      task: str = "kws12", scheduler: str | None = None,
                      jobs: int = 0) -> list[dict]:
    """[{threshold, compressor Duffing range, accuracy, ...}]: a mass-spring model trained and
    simulated for every compression threshold A_c (models in `out/threshold-<A_c>`)."""
    from springc.kws.features.digital import FeatureSettings
    from springc.kws.evaluation.evaluate import evaluate
    from springc.kws.training.train import TrainOptions, train

    fs = FeatureSettings(bins=bins, delays=delays)
    rows = []
    for a_c in thresholds:
        s = msp.from_features(fs, threshold=float(a_c))
        folder = Path(out) / f"threshold-{a_c:g}"
        train(TrainOptions(data=data, out=folder, settings=fs, realisation="mass-spring",
                           task=task, jobs=jobs, massspring=s, scheduler=scheduler))
        rep = evaluate(folder, jobs=jobs, scheduler=scheduler)
        duffing = msp.compressor_duffing(s)
        rows.append(_row(rep, threshold=float(a_c), duffing_min=float(duffing.min()),
                         duffing_max=float(duffing.max())))
    return rows


def _row(rep: dict, **keys) -> dict:
    return {**keys, "accuracy": rep["accuracy"],
            "ideal_accuracy": rep["digital_same_model"]["accuracy"],
            "insertion_loss_db": rep["insertion_loss_db"]["median"],
            "readout_error": rep["readout_error"],
            "clips_per_s": rep["throughput"]["clips_per_s"]}


def plot_sweeps(path: Path, eps_rows: list[dict], comp_rows: list[dict], title: str) -> None:
    """Two panels, accuracy against insertion loss: (e) over eps, (f) over compression."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for ax, rows, key, label in ((axes[0], eps_rows, "epsilon", "eps"),
                                 (axes[1], comp_rows, "threshold", "A_c")):
        il = [r["insertion_loss_db"] for r in rows]
        acc = [100 * r["accuracy"] for r in rows]
        ax.plot(il, acc, "o-", color="tab:purple", label="mass-spring network")
        ax.plot(il, [100 * r["ideal_accuracy"] for r in rows], "s--", color="tab:gray",
                label="ideal readout c.Phi, same features")
        for x, y, r in zip(il, acc, rows):
            ax.annotate(f"{label}={r[key]:g}", (x, y), textcoords="offset points", xytext=(4, 4),
                        fontsize=8)
        ax.set_xlabel("insertion loss (dB)")
        ax.set_ylabel("test accuracy (%)")
        ax.grid(alpha=0.3)
    axes[0].set_title("(e) squaring error eps")
    axes[1].set_title("(f) feature compression threshold")
    axes[0].legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    tmp = Path(path).with_suffix(".tmp.png")
    fig.savefig(tmp, dpi=120)
    plt.close(fig)
    tmp.replace(path)


def settings_table(s: msp.MassSpringSettings) -> list[tuple[str, str]]:
    """The physical parameters of the feature network, for the results page."""
    return [(f.name, f"{getattr(s, f.name)!r}") for f in dataclasses.fields(s)] + [
        ("squarer leverages a_i", np.array2string(msp.leverages(s), precision=3,
                                                 max_line_width=1000)),
        ("compressor Duffing coefficients l_i (N/m^3)", np.array2string(
            msp.compressor_duffing(s), precision=3, max_line_width=1000)),
        ("compressor masses (kg)", np.array2string(msp.compressor_mass(s), precision=3,
                                                   max_line_width=1000))]
