"""Evaluating a router model (`springc.kws.features.router`): its network, router.spr,
simulated from sound to decision on the test clips, as designed, at physical scale with
thermal noise (`springc eval MODEL --temp K ...`), or as a population of fabricated devices
(`--mc N --spread S`). The decision of a clip is the readout that dissipates most."""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from springc.check import check
from springc.errors import DivergedRuns
from springc.kws.evaluation import device as dv
from springc.kws.features import router as rt
from springc.kws.training.report import score
from springc.kws.training.svm import LinearModel
from springc.lang.ir import FlatNetlist

BATCH = 256  # clips a kernel call: the readouts' reductions only, so memory stays small
# silent clips a fabricated router is measured on for its readouts' thermal offsets: the
# mean a readout dissipates with no sound, which the calibrated decision subtracts
DARK_CLIPS = 8
DARK_SEED = 1 << 40  # the silent clips' thermal draws: apart from every test clip's


def router_net(model) -> FlatNetlist:
    """The model folder's router.spr, elaborated."""
    from springc.lang import load_file

    return load_file(Path(model.folder) / "router.spr")


def readouts(net: FlatNetlist, signals: np.ndarray, rows: int, *,
             temp: float | None = None, seed: int = 0,
             extra: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    """{"E": the energies (clips, rows) of readouts 0 .. rows - 1 (0 for one without
    dashpots: its class never wins), and each reduction of `extra`} of `signals` (clips,
    samples) at 16 kHz through `net`, with thermal noise at `temp` kelvin (seeded per batch
    of BATCH clips)."""
    from springc.sim.simulate import simulate

    checked = check(net)
    specs = rt.readout_reductions(net) + list(extra)
    parts: dict[str, list] = {}
    for start in range(0, len(signals), BATCH):
        sig = np.asarray(signals[start:start + BATCH], dtype=np.float64)[:, None, :]
        res = simulate(checked, sig, rt.INPUT_RATE, probes=[], reductions=specs,
                       tstop=sig.shape[-1] / rt.INPUT_RATE + rt.RING_OUT, batch=len(sig),
                       temp=temp, seed=(seed + start) if temp else None)
        parts.setdefault("E", []).append(rt.readout_energies(res.reductions, rows))
        for key in extra:
            parts.setdefault(key, []).append(res.reductions[key])
    return {k: np.concatenate(v) for k, v in parts.items()}


def readout_model(classes) -> list:
    """The models `score` reads the readouts with: readout r is class r's decision."""
    rows = len(classes)
    return [(tuple(classes), LinearModel(np.eye(rows), np.zeros(rows), np.asarray(classes)))]


def evaluate_model(model_dir: Path, data: Path | None = None, protocol: str | None = None,
                   jobs: int = 0, use_cache: bool = True) -> dict:
    """`springc eval` of a router model on the test split of `data` (default: the data it
    was trained on): `evaluate_router` beside the classifier on the cached features."""
    from springc.kws.data.task import open_task_data, targets
    from springc.kws.evaluation.evaluate import _feature_settings, trained_data
    from springc.kws.training.model import load_model
    from springc.kws.training.train import feature_matrices

    model = load_model(model_dir)
    task = model.settings["task"]
    ds = open_task_data(Path(data) if data else trained_data(model), task,
                        int(model.settings.get("seed", 0)),
                        protocol or model.settings.get("protocol"), splits=("test",))
    clips = ds.split("test")
    x = feature_matrices(clips, "test", "router", [_feature_settings(model)], noise_files=[],
                         jobs=jobs, use_cache=use_cache)[0]
    return evaluate_router(model, clips, targets(clips, task), task, features=x)


def evaluate_router(model, clips: list, y: np.ndarray, task: str, *, features=None) -> dict:
    """The router network's accuracy on `clips` (labels `y`), beside the same classifier on
    its simulated features (`features`: the test split's D, None: not compared), with its
    insertion loss (readouts over the input's work, dB per clip)."""
    from springc.kws.features import massspring as msp

    net = router_net(model)
    classes = model.models[0][1].classes
    start = time.perf_counter()
    out = readouts(net, msp.load_signals(clips, False, 0, []), len(classes),
                   extra=("work:in",))
    seconds = time.perf_counter() - start
    report = score(readout_model(classes), out["E"], y, task)
    loss = -10 * np.log10(out["E"].sum(axis=1) / out["work:in"])
    report.update(realisation="router network",
                  insertion_loss_db={"median": float(np.median(loss)),
                                     "mean": float(np.mean(loss))},
                  throughput={"clips": len(clips), "seconds": seconds,
                              "clips_per_s": len(clips) / seconds,
                              "cores": os.cpu_count()})
    if features is not None:  # the same classifier on the features: W . D
        digital = score(model.models, features, y, task)
        report["digital_same_model"] = {k: digital[k] for k in ("accuracy", "n", "per_class")}
        ideal = features @ rt.router_weights(model.models[0][1].coef).T
        report["readout_error"] = float(np.median(np.abs(out["E"] - ideal))
                                        / np.median(np.abs(ideal)))
    return report


def physical(model, signals: np.ndarray, y: np.ndarray, phys: dv.Physical) -> dict:
    """The router at physical scale with thermal noise (`device.evaluate_physical`'s report:
    accuracy with noise and noiseless, the readouts' SNR, the decision error)."""
    phys.validate()
    net = router_net(model)
    classes = model.models[0][1].classes
    pnet, lam = dv.physical_network(net, phys)
    clean = readouts(net, signals, len(classes))["E"]
    base = {**dv.physical_report(phys, lam, net, len(y), _accuracy(classes, clean, y)),
            "snr_of": "the readouts"}
    units = phys.mass * lam**2  # energies scale as mu lambda^2 (`springc.design.scale`)
    try:
        noisy = readouts(pnet, signals, len(classes), temp=phys.temp,
                         seed=phys.seed)["E"] / units
        dark = dark_offsets(pnet, len(classes), signals.shape[1], phys.temp,
                            phys.seed) / units
    except DivergedRuns as err:
        return {"accuracy": 0.0, "diverged": err.message, "phi_snr_db": None,
                "decision_error": float("inf"), **base}
    return {"accuracy": _accuracy(classes, noisy, y), "diverged": None,
            "phi_snr_db": dv.phi_snr_db(clean, noisy),
            "decision_error": dv.decision_error(noisy, clean),
            "calibrated": {"accuracy": _accuracy(classes, noisy - dark, y),
                           "decision_error": dv.decision_error(noisy - dark, clean),
                           "dark_clips": DARK_CLIPS, "offsets": dark.tolist()}, **base}


def dark_offsets(pnet: FlatNetlist, rows: int, samples: int, temp: float,
                 seed: int = 0) -> np.ndarray:
    """Each readout's mean energy (rows,) over `DARK_CLIPS` silent clips of `samples`
    samples with thermal noise at `temp` kelvin: what a fabricated router dissipates with no
    sound, measured once per device (a readout's offset, as its reading circuit would
    subtract it)."""
    from springc.lang.draws import MAX_SEED

    silent = np.zeros((DARK_CLIPS, samples))
    return readouts(pnet, silent, rows, temp=temp,
                    seed=(seed + DARK_SEED) % MAX_SEED)["E"].mean(axis=0)


def population(model, signals: np.ndarray, y: np.ndarray, devices: int,
               spread: dv.Spread, progress=None) -> dict:
    """`devices` fabricated routers (`device.fabricate`) on the clips: the report of
    `device.evaluate_spread`."""
    spread.validate()
    net = router_net(model)
    classes = model.models[0][1].classes
    nominal = readouts(net, signals, len(classes))["E"]
    rows, start = [], time.perf_counter()
    for k in range(devices):
        dk = readouts(dv.fabricate(net, spread, k), signals, len(classes))["E"]
        rows.append({"device": k, "accuracy": _accuracy(classes, dk, y), "diverged": False,
                     "decision_error": dv.decision_error(dk, nominal)})
        if progress:
            progress(dv.progress_line(rows, devices, time.perf_counter() - start))
    acc = np.array([r["accuracy"] for r in rows])
    return {"devices": rows, "nominal": _accuracy(classes, nominal, y),
            "accuracy": dv.summary(acc), "n": len(y), "spread": spread.sigma,
            "kind": spread.kind, "stage": spread.stage, "seed": spread.seed}


def _accuracy(classes, energies: np.ndarray, y: np.ndarray) -> float:
    return float(np.mean(np.asarray(classes)[np.argmax(energies, axis=1)] == y))
