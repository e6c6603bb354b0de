"""End-to-end tuning of a mass-spring keyword spotter through its simulated network
(`springc tune`): a trained, SVM-transferred model folder in, a tuned model folder out.

First (unless `refit` is off) every head's weights and intercept are refitted on the
transferred network's exact response (`springc.kws.tuning.refit`: forward simulations and a convex
fit); the gradient epochs below start from the refitted heads.

The loss is the softmax cross-entropy of the physical decisions d_k = x(r_k) / scale_k + b_k
at a learnt temperature T (of T d: a binary model, the logistic loss on its one row),
averaged over the clips, plus `il_weight` times the mean insertion loss in dB. T only
calibrates the loss (it changes no decision's sign or order): without it the SVM's decisions,
which were not fitted as log-odds, would be rescaled through the couplings instead. Its gradient is
sum_k dL/dr_k dr_k/dtheta (+ the insertion loss's terms): a forward simulation gives the
readouts and so the per-clip weights dL/dr_k, one discrete adjoint
(`springc.grad.coefficient_gradient`, RK4 x8 float64, the paper's integration: the
exponential integrator eval runs has no adjoint) gives d loss / d every element coefficient,
and each group maps its factors onto coefficients exactly:

    filter       per bin f: the Mel filter's fa and alpha times f (masses' b x f, springs x f^2,
                 input gains x f^3: the same response moved along the frequency axis)
    compression  per bin f: the compressor's Duffing stiffness l x f
    couplings    per head and coupled eigen-component f: g x f, a / f (the readout's
                 stiffness g a stays; the squaring strength moves)
    readout      per head the intercept b_k (digital, unbounded)
    (always)     log T, the loss's temperature (not part of the network)

Every factor is f = lo (hi/lo)^sigmoid(z) in a box (`BOXES`, `springc.grad.legal.Range`) whose
corners pass the checks (verified before the first step), so every tuned netlist is legal by
construction. The tuned values live in the model's settings (features: `filter_scale`,
`compression_scale`; transfer: `couplings`, `intercepts`), from which every command
re-derives the same network (`springc.kws.training.transfer.model_heads`). The folder gets the
parameters of the epoch (the start included) with the lowest loss on `val_clips` clips of the
validation split, so tuning on few clips cannot leave a worse network than it found there.

With a population (`devices` N at a relative `spread`) the loss is the mean over N devices
fabricated from the network at z (`springc.kws.evaluation.device.fabricate`: every
coefficient times a draw of gauss(1, spread)), new devices at every step and one fixed
population for the validation loss: the parameters a population does best with, not one
exact network.
"""

from __future__ import annotations

import hashlib
import json
import math
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from springc.check import check
from springc.errors import DataError, UsageError
from springc.grad.legal import Range
from springc.kws.features import massspring as msp
from springc.kws.training import transfer as tr

GROUPS = ("filter", "compression", "couplings", "readout")
BOXES = {
    # +-10% in frequency: a filter stays inside its Mel band's neighbourhood
    "filter": Range(1 / 1.1, 1.1, True),
    # the compressor mass is sized for the untuned l (STABLE_WH = 2 at full scale): x2 raises
    # the stiffest mode by 2^(1/3) in stiffness, w h 2.0 -> 2.25 < RK4's 2.83
    "compression": Range(0.5, 2.0, True),
    "couplings": Range(0.25, 4.0, True),
}
UNBOXED = ("readout", "temperature")  # variables used as they are, not factors in a box
METHOD, SUBSTEPS = "rk4", msp.SUBSTEPS  # the paper's integration; Runge-Kutta for the adjoint
DB = 10 / math.log(10)


@dataclass
class TuneOptions:
    """What `springc tune` was asked: the model, data, output folder and the optimiser."""

    model: Path
    data: Path | None
    out: Path
    params: tuple[str, ...] = ("filter", "compression", "couplings", "readout")
    epochs: int = 2
    batch: int = 16
    clips: int = 64
    val_clips: int = 64
    lr: float = 0.05
    il_weight: float = 0.0
    seed: int = 0
    jobs: int = 0
    scheduler: str | None = None
    evaluate: bool = True
    refit: bool = True  # refit the heads' weights on the exact response first
    refit_clips: int = 0  # training clips the refit simulates (0: all)
    devices: int = 0  # fabricated devices per step and in validation (0: the nominal network)
    spread: float = 0.0  # their relative spread on every coefficient


@dataclass
class Layout:
    """How the optimiser's vector maps to the groups: name -> slice, and each group's shape."""

    slices: dict[str, slice] = field(default_factory=dict)
    keep: list[int] = field(default_factory=list)  # coupled components per head

    @property
    def size(self) -> int:
        return max((s.stop for s in self.slices.values()), default=0)


def layout(params: tuple[str, ...], bins: int, heads: list[tr.Head]) -> Layout:
    """The vector's layout for the groups `params` (in `GROUPS` order), then log T."""
    sizes = {"filter": bins, "compression": bins, "couplings": sum(len(h.keep) for h in heads),
             "readout": len(heads), "temperature": 1}
    out, start = Layout(keep=[len(h.keep) for h in heads]), 0
    for name in GROUPS + ("temperature",):
        if name in params or name == "temperature":
            out.slices[name] = slice(start, start + sizes[name])
            start += sizes[name]
    return out


def check_params(params: tuple[str, ...]) -> tuple[str, ...]:
    """The groups asked for, validated; UsageError naming an unknown one."""
    bad = [p for p in params if p not in GROUPS]
    if bad or not params:
        raise UsageError(f"unknown parameter group(s) {', '.join(bad) or '(none given)'}",
                         hint=f"--params takes a comma-separated subset of {','.join(GROUPS)}")
    return tuple(p for p in GROUPS if p in params)


# -- the tuned network -------------------------------------------------------------------------

@dataclass
class Start:
    """The untuned model's settings, heads and the design they were built with (what every z
    is measured from)."""

    s: msp.MassSpringSettings
    heads: list[tr.Head]
    design: tr.Design = field(default_factory=tr.Design)


def factors(z: np.ndarray, lay: Layout, name: str, n: int) -> np.ndarray:
    """The group's factors (or intercepts) at z; 1 (or None) where the group is not tuned."""
    if name not in lay.slices:
        return np.ones(n)
    zz = z[lay.slices[name]]
    if name in UNBOXED:
        return zz.copy()
    box = BOXES[name]
    return np.array([box.value(float(v)) for v in zz])


def slopes(z: np.ndarray, lay: Layout) -> np.ndarray:
    """d log(factor) / dz for the boxed entries, 1 for the intercepts and log T (chain to z)."""
    out = np.ones_like(z)
    for name, sl in lay.slices.items():
        if name not in UNBOXED:
            box = BOXES[name]
            sig = 1 / (1 + np.exp(-np.clip(z[sl], -500, 500)))
            out[sl] = math.log(box.hi / box.lo) * sig * (1 - sig)
    return out


def tuned(start: Start, z: np.ndarray, lay: Layout) -> tuple[msp.MassSpringSettings,
                                                             list[tr.Head]]:
    """The settings and heads at z."""
    s = start.s
    if "filter" in lay.slices:
        s = replace(s, filter_scale=tuple(factors(z, lay, "filter", s.bins)))
    if "compression" in lay.slices:
        s = replace(s, compression_scale=tuple(factors(z, lay, "compression", s.bins)))
    couplings = intercepts = None
    if "couplings" in lay.slices:
        f = factors(z, lay, "couplings", 0)
        couplings = np.split(f, np.cumsum(lay.keep)[:-1])
    if "readout" in lay.slices:
        intercepts = factors(z, lay, "readout", 0)
    return s, tr.tuned_heads(start.heads, couplings, intercepts)


def initial_z(start: Start, lay: Layout) -> np.ndarray:
    """z of the untuned model: every factor 1, the intercepts the SVM's, T = 1."""
    z = np.zeros(lay.size)
    for name, sl in lay.slices.items():
        if name == "readout":
            z[sl] = [h.intercept for h in start.heads]
        elif name != "temperature":
            z[sl] = BOXES[name].variable(1.0)
    return z


def network(s: msp.MassSpringSettings, heads: list[tr.Head], epsilon: float,
            design: tr.Design = tr.Design()):
    """The checked classifier built as `design` says, at RK4 x8 (CheckError for an illegal
    one)."""
    from springc.lang import load_text

    net = load_text(tr.classifier_text(heads, s, epsilon=epsilon, design=design),
                    "<tuned classifier>")
    return check(net, METHOD, substeps=SUBSTEPS)


def check_corners(start: Start, lay: Layout, epsilon: float) -> int:
    """Check the networks at the box's two extreme corners (every factor at lo, every one at
    hi): stiffness, mass and damping move monotonically with each factor, so these bound the
    fastest mode and the signs (`springc.grad.legal`). CheckError if one fails."""
    for end in (-60.0, 60.0):
        z = initial_z(start, lay)
        for name, sl in lay.slices.items():
            if name not in UNBOXED:
                z[sl] = end
        network(*tuned(start, z, lay), epsilon, start.design)
    return 2


# -- loss and gradient of one batch (a Dask task) ----------------------------------------------

@dataclass(frozen=True)
class Targets:
    """Per model of the task: its rows of the decision matrix and each clip's target (the
    row index for a multi-class model, 0/1 for a binary one, -1: not this model's clip)."""

    rows: tuple[tuple[int, int], ...]
    target: tuple[np.ndarray, ...]


def make_targets(models, labels: np.ndarray) -> Targets:
    """Targets of clips with true classes `labels` (as `springc.kws.data.task.targets` gives)."""
    rows, target, start = [], [], 0
    for classes, m in models:
        n = len(m.coef)
        rows.append((start, start + n))
        classes = list(m.classes)
        target.append(np.array([classes.index(y) if y in classes else -1 for y in labels]))
        start += n
    return Targets(tuple(rows), tuple(target))


def loss_terms(d: np.ndarray, t: Targets) -> tuple[np.ndarray, np.ndarray]:
    """Per clip the classification loss, and its gradient with respect to the decisions."""
    loss, grad = np.zeros(len(d)), np.zeros_like(d)
    for (lo, hi), y in zip(t.rows, t.target):
        mine = y >= 0
        if hi - lo == 1:  # binary: logistic loss on the sign, classes[1] where d > 0
            z = d[:, lo] * np.where(y == 1, 1.0, -1.0)
            loss += np.where(mine, np.logaddexp(0, -z), 0)
            grad[:, lo] += np.where(mine, -np.where(y == 1, 1.0, -1.0) / (1 + np.exp(z)), 0)
            continue
        dd = d[:, lo:hi] - d[:, lo:hi].max(axis=1, keepdims=True)
        e = np.exp(dd)
        total = e.sum(axis=1)
        p = e / total[:, None]
        idx = np.maximum(y, 0)  # -log p[idx] as log(total) - dd[idx]: finite however far off
        loss += np.where(mine, np.log(total) - dd[np.arange(len(d)), idx], 0)
        onehot = np.eye(hi - lo)[idx]
        grad[:, lo:hi] += np.where(mine[:, None], p - onehot, 0)
    return loss, grad


@dataclass(frozen=True)
class Batch:
    """Everything a worker needs besides the clips: the network, the heads' scales and
    intercepts, the targets' encoding, the loss weights and where each group's coefficients
    sit."""

    checked: object
    scales: np.ndarray
    intercepts: np.ndarray
    targets: Targets
    il_weight: float
    tstop: float
    bins: int
    heads: int
    keep: tuple[int, ...]
    temperature: float = 1.0
    population: tuple[int, ...] = ()  # Monte Carlo sample indices of the devices (): nominal
    spread: float = 0.0
    seed: int = 0
    judged: bool = True  # the step judged stable (not on a fabricated device: `on_devices`)


# the validation population's first sample index: far from every step's (step x devices + k)
VALIDATION_DEVICES = 1 << 40


def step_population(opts: TuneOptions, step: int) -> tuple[int, ...]:
    """The devices of optimiser step `step`: new ones at every step."""
    return tuple(range(step * opts.devices, (step + 1) * opts.devices))


def validation_population(opts: TuneOptions) -> tuple[int, ...]:
    """The devices every validation loss is scored on: the same each epoch."""
    return tuple(range(VALIDATION_DEVICES, VALIDATION_DEVICES + opts.devices))


def on_devices(b: Batch) -> list[Batch]:
    """The batch on each device of its population (the nominal network fabricated with
    relative spread `b.spread`, `springc.kws.evaluation.device.fabricate`), or the batch
    itself without one. A device is checked as `springc eval --mc` checks it (its step not
    judged: mismatch turns designed zero modes into slowly growing ones), and one the checks
    find statically unstable is left out, as eval scores it apart."""
    if not b.population:
        return [b]
    from springc.kws.evaluation.device import Spread, checked_device

    spread = Spread(b.spread, seed=b.seed)
    devices = [checked_device(b.checked.net, spread, d) for d in b.population]
    return [replace(b, checked=d, population=(), judged=False) for d in devices
            if not isinstance(d, str)]


def readouts(b: Batch, sig: np.ndarray) -> dict:
    """The readout reductions of clips `sig` (clips, samples) at RK4 x8 float64."""
    from springc.sim.simulate import simulate

    specs = [f"final:x(r{k})" for k in range(b.heads)]
    if b.il_weight:
        specs += [f"dissipated:r{k}" for k in range(b.heads)] + ["work:in"]
    return simulate(b.checked, sig[:, None, :], msp.INPUT_RATE, probes=[], reductions=specs,
                    tstop=b.tstop, method=METHOD, substeps=SUBSTEPS, precision="float64",
                    batch=len(sig), check_step=b.judged).reductions


def batch_loss(b: Batch, reds: dict, y: np.ndarray) -> tuple[np.ndarray, dict]:
    """Per clip the loss, and the weights (d loss / d reduction per clip) of the adjoint."""
    r = np.stack([reds[f"final:x(r{k})"] for k in range(b.heads)], axis=1)
    d = b.temperature * (r / b.scales + b.intercepts)
    t = Targets(b.targets.rows, tuple(tt[y] for tt in b.targets.target))
    loss, dd = loss_terms(d, t)
    weights = {f"final:x(r{k})": b.temperature * dd[:, k] / b.scales[k]
               for k in range(b.heads)}
    weights["intercepts"] = b.temperature * dd
    weights["temperature"] = (dd * d).sum(axis=1)  # d loss / d log T
    if b.il_weight:
        diss = sum(reds[f"dissipated:r{k}"] for k in range(b.heads))
        work = reds["work:in"]
        loss = loss - b.il_weight * DB * np.log(diss / work)
        for k in range(b.heads):
            weights[f"dissipated:r{k}"] = -b.il_weight * DB / diss
        weights["work:in"] = b.il_weight * DB / work
    return loss, weights


def group_gradient(b: Batch, coef: dict, names: list) -> dict[str, np.ndarray]:
    """Sum over the clips of d loss / d log(factor) for each group, from the coefficient
    gradient `coef` (keyed (table, field)) and the element names of each table `names`."""
    net = b.checked.net

    def col(table: str, fld: str, name: str) -> np.ndarray:  # d/dc * c of one element
        e = names[table].index(name)
        return coef[(table, fld)][:, e].sum() * getattr(getattr(net, table), fld)[e]

    out = {"filter": np.zeros(b.bins), "compression": np.zeros(b.bins),
           "couplings": np.zeros(sum(b.keep))}
    for i in range(b.bins):
        f = f"Xf{i}."
        out["filter"][i] = (col("masses", "b", f + "Ma") + col("masses", "b", f + "Mb")
                            + 2 * (col("springs", "k", f + "Ka") + col("springs", "k", f + "Kb")
                                   + col("couplings", "k", f + "Cab"))
                            + 3 * (col("forces", "gain", f + "Fa")
                                   + col("forces", "gain", f + "Fb")))
        out["compression"][i] = col("duffings", "l", f"Xc{i}.Dq")
    quads = {n: e for e, n in enumerate(names["quads"])}
    k0 = 0
    for k, n in enumerate(b.keep):
        comps = sorted((int(q.split(".Qy")[1]), e) for q, e in quads.items()
                       if q.startswith(f"Xh{k}.Qy"))
        for j, (_, e) in enumerate(comps[:n]):
            g, a = net.quads.g[e], net.quads.a[e]
            out["couplings"][k0 + j] = (coef[("quads", "g")][:, e].sum() * g
                                        - coef[("quads", "a")][:, e].sum() * a)
        k0 += n
    return out


def batch_gradient(sig_y: tuple[np.ndarray, np.ndarray], b: Batch) -> dict:
    """One worker's share of a batch: (clips, their indices into the targets) in; the loss
    and the group gradients summed over its clips (and over the devices of `b.population`:
    a device's coefficients are its fixed factors times the nominal ones, so its derivative
    by a group's log factor is the same sum over its own coefficients), the clips counted
    (once per device) and those dropped out (every clip of a device left out as unstable)."""
    sig, y = sig_y
    devices = on_devices(b)
    parts = [network_gradient(sig_y, d) for d in devices] or [
        network_gradient((sig[:0], y[:0]), b)]  # every device unstable: nothing to add
    out = {k: sum(p[k] for p in parts) for k in parts[0]}
    out["dropped"] += len(sig) * (len(b.population) - len(devices) if b.population else 0)
    return out


def network_gradient(sig_y: tuple[np.ndarray, np.ndarray], b: Batch) -> dict:
    """`batch_gradient` on the network `b.checked` alone. A clip whose readouts are not
    finite at RK4 x8 (louder than the compressors' planned full scale) is dropped from the
    step rather than stopping the run."""
    from springc.grad import coefficient_gradient

    sig, y = sig_y
    sig = sig.astype(np.float64)
    reds = readouts(b, sig)
    ok = np.all([np.isfinite(v) for v in reds.values()], axis=0)
    sig, y, reds = sig[ok], y[ok], {k: v[ok] for k, v in reds.items()}
    out = {"filter": np.zeros(b.bins), "compression": np.zeros(b.bins),
           "couplings": np.zeros(sum(b.keep)), "readout": np.zeros(b.heads),
           "temperature": np.zeros(1), "loss": 0.0, "clips": len(sig),
           "dropped": int((~ok).sum())}
    if not len(sig):
        return out
    loss, weights = batch_loss(b, reds, y)
    dd, dlogt = weights.pop("intercepts"), weights.pop("temperature")
    cg = coefficient_gradient(b.checked, list(weights), sig[:, None, :], msp.INPUT_RATE,
                              weights=weights, tstop=b.tstop, method=METHOD,
                              substeps=SUBSTEPS, check_step=b.judged)
    names = {t: getattr(b.checked.net, t).names for t in ("masses", "springs", "couplings",
                                                           "duffings", "forces", "quads")}
    out.update(group_gradient(b, cg.coefficients, names))
    out.update(readout=dd.sum(axis=0), temperature=np.array([dlogt.sum()]),
               loss=float(loss.sum()))
    return out


# -- the optimiser -----------------------------------------------------------------------------

@dataclass
class Adam:
    """Adam on z (Kingma & Ba defaults): a step per batch, state saved in checkpoints."""

    lr: float
    m: np.ndarray
    v: np.ndarray
    t: int = 0

    def step(self, z: np.ndarray, g: np.ndarray) -> np.ndarray:
        """z after one step along -g."""
        self.t += 1
        self.m = 0.9 * self.m + 0.1 * g
        self.v = 0.999 * self.v + 0.001 * g * g
        mh, vh = self.m / (1 - 0.9**self.t), self.v / (1 - 0.999**self.t)
        return z - self.lr * mh / (np.sqrt(vh) + 1e-8)


def z_gradient(parts: list[dict], lay: Layout, z: np.ndarray) -> tuple[np.ndarray, float]:
    """The mean loss of a batch and its gradient in z, from the workers' parts."""
    n = max(1, sum(p["clips"] for p in parts))
    g = np.zeros(lay.size)
    for name, sl in lay.slices.items():
        g[sl] = sum(p[name] for p in parts) / n
    return g * slopes(z, lay), sum(p["loss"] for p in parts) / n


class Progress:
    """Batches done, rate, time left and the last loss, on stderr."""

    def __init__(self, total: int, done: int = 0) -> None:
        self.total, self.done, self.start, self.first = total, done, time.perf_counter(), done

    def tick(self, epoch: int, clips: int, loss: float) -> None:
        """One batch done."""
        self.done += 1
        spent = time.perf_counter() - self.start
        rate = (self.done - self.first) / spent
        left = (self.total - self.done) / rate if rate else float("nan")
        print(f"tune: epoch {epoch + 1} batch {self.done}/{self.total}  loss {loss:.4f}  "
              f"{clips * rate:.2f} clips/s  {left / 60:.1f} min left", file=sys.stderr,
              flush=True)


# -- checkpoints -------------------------------------------------------------------------------

def checkpoint_path(out: Path) -> Path:
    """Where the parameters are saved after every epoch: beside OUT, hidden."""
    out = Path(out)
    return out.parent / f".{out.name}.tune-checkpoint.json"


def run_key(opts: TuneOptions, model_settings: dict) -> str:
    """What a checkpoint must match to be resumed: the start model and the options."""
    what = {"model": model_settings, "params": opts.params, "batch": opts.batch,
            "clips": opts.clips, "val_clips": opts.val_clips, "lr": opts.lr,
            "il_weight": opts.il_weight, "seed": opts.seed, "data": str(opts.data),
            "refit": [opts.refit, opts.refit_clips], "devices": [opts.devices, opts.spread]}
    return hashlib.sha256(json.dumps(what, sort_keys=True, default=str).encode()).hexdigest()


def load_checkpoint(path: Path, key: str, size: int) -> dict | None:
    """The saved state of a run with the same key, or None (no file, or another run's)."""
    try:
        state = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if state.get("key") != key or len(state.get("z", ())) != size:
        return None
    return state


def save_checkpoint(path: Path, key: str, epoch: int, z: np.ndarray, adam: Adam,
                    history: list, best: np.ndarray) -> None:
    """Write the state after `epoch` epochs, with the best z so far (whole file replaced at
    once)."""
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps({"key": key, "epochs_done": epoch, "z": z.tolist(),
                               "best": best.tolist(),
                               "adam": {"m": adam.m.tolist(), "v": adam.v.tolist(),
                                        "t": adam.t}, "history": history}))
    tmp.replace(path)


# -- the command -------------------------------------------------------------------------------

def load_start(model_dir: Path):
    """The model to tune: (TrainedModel, Start). DataError for anything but a mass-spring
    model with its transfer (a digital or baseline model has no network to tune)."""
    from springc.kws.training.model import load_model

    model = load_model(model_dir)
    if model.settings.get("realisation") not in ("mass-spring", "device") \
            or "transfer" not in model.settings:
        raise DataError(str(Path(model_dir) / "settings.json"),
                        f"is a {model.settings.get('realisation')} model; tune needs a "
                        "mass-spring or device model",
                        hint="train one with --realisation mass-spring or device")
    if model.settings.get("tune"):
        raise DataError(str(Path(model_dir) / "settings.json"), "is already a tuned model",
                        hint="tune the SVM-transferred model it came from")
    s, heads = tr.model_heads(model)
    return model, Start(s, heads, tr.model_design(model))


def training_clips(opts: TuneOptions, model):
    """The data set, the training clips tuned on (`opts.clips` of them, 0: all) and the
    validation clips the epochs are chosen by (`opts.val_clips`, 0: none), drawn with the
    seed."""
    from springc.kws.evaluation.evaluate import trained_data
    from springc.kws.data.task import open_task_data

    data = Path(opts.data) if opts.data else trained_data(model)
    splits = ("train",) + (("validation",) if opts.val_clips or opts.refit else ()) + (
        ("test",) if opts.evaluate else ())
    ds = open_task_data(data, model.settings["task"], int(model.settings.get("seed", 0)),
                        model.settings.get("protocol"), splits=splits)
    return ds, _draw(ds.split("train"), opts.clips, opts.seed), (
        _draw(ds.split("validation"), opts.val_clips, opts.seed) if opts.val_clips else [])


def _draw(clips: list, n: int, seed: int) -> list:
    """n of the clips (0: all) in an order drawn with the seed."""
    order = np.random.default_rng(seed).permutation(len(clips))
    return [clips[i] for i in (order[:n] if n else order)]


def validate(opts: TuneOptions) -> None:
    """UsageError / DataError for options that cannot work, before any simulation."""
    from springc.kws.training.model import check_out_folder

    if Path(opts.out).resolve() == Path(opts.model).resolve():
        raise UsageError("the output folder is the model being tuned",
                         hint="give -o a new folder")
    if opts.epochs < 0 or opts.batch < 1 or opts.clips < 0 or opts.val_clips < 0 \
            or opts.refit_clips < 0 or not opts.lr > 0:
        raise UsageError("--batch must be >= 1, --epochs, --clips, --val-clips and "
                         "--refit-clips >= 0 and --lr > 0")
    if opts.epochs == 0 and not opts.refit:
        raise UsageError("nothing to tune: --epochs 0 with --no-refit",
                         hint="give --epochs 1 or more, or leave the refit on")
    if opts.il_weight < 0:
        raise UsageError("--il-weight must be >= 0")
    validate_population(opts)
    check_out_folder(opts.out)


def validate_population(opts: TuneOptions) -> None:
    """UsageError unless --mc and --spread are both given (a count of devices >= 1 and a
    finite spread > 0) or neither."""
    from springc.kws.evaluation.device import Spread

    if opts.devices < 0:
        raise UsageError(f"--mc must be a number of devices >= 0, not {opts.devices}")
    Spread(opts.spread, seed=opts.seed).validate()
    if bool(opts.devices) != (opts.spread > 0):
        raise UsageError("--mc N and --spread S go together: the loss over N devices "
                         "fabricated with a relative spread S", hint="--mc 4 --spread 1e-3")


def tune(opts: TuneOptions) -> dict:
    """Tune the model `opts.model` on its training clips and write the tuned model folder
    `opts.out` (netlists, settings, report of the test split, README); returns the report."""
    from springc.kws.features.distributed import session

    validate(opts)
    opts.params = check_params(opts.params)
    model, start = load_start(opts.model)
    if opts.refit and start.design != tr.Design():
        raise UsageError("the refit redesigns the paper's heads only, not these (buffered "
                         "taps, stiffer multipliers or summing heads)",
                         hint="tune with --no-refit")
    ds, clips, val = training_clips(opts, model)
    started = time.perf_counter()
    with session(opts.scheduler, opts.jobs or None):
        refit = None
        if opts.refit:
            start, refit = refit_start(opts, model, start, ds)
        z, history = optimise(opts, model, start, clips, val)
        tuned_s, heads = tuned(start, z, layout(opts.params, start.s.bins, start.heads))
        report = finish(opts, model, ds, (tuned_s, heads, start.heads), history,
                        time.perf_counter() - started, refit)
    checkpoint_path(opts.out).unlink(missing_ok=True)
    return report


def refit_start(opts: TuneOptions, model, start: Start, ds) -> tuple[Start, dict]:
    """The start with every head's weights refitted on the transferred network's exact
    response (`springc.kws.tuning.refit`): `opts.refit_clips` training clips to fit, the validation
    split to choose C; kept only where its validation accuracy beats the transferred
    network's (as the epochs are chosen). Returns it and the record settings.json keeps."""
    from springc.kws.tuning import refit as rf
    from springc.kws.evaluation.evaluate import selection_models
    from springc.kws.training.report import score

    task, transfer = model.settings["task"], model.settings["transfer"]
    if not ds.split("validation"):
        raise DataError(str(opts.data or "the model's data set"), "the validation split holds "
                        "no clips, which choose the refit's C", hint="tune with --no-refit")
    (fit_resp, fit_y), (val_resp, val_y) = _responses(opts, model, start, ds)
    weight = model.settings.get("class_weight")
    fitted = rf.fit((fit_resp.j, fit_y), (val_resp.j, val_y), start.heads, model.models, task,
                    None if weight in (None, "none") else weight)
    before = score(selection_models(model.models), val_resp.decisions, val_y,
                   task)["accuracy"]
    kept = fitted.scores[fitted.c] > before
    print(f"tune: heads refitted on the exact response of {len(fit_y)} clips, C "
          f"{fitted.c:g}, validation accuracy {100 * fitted.scores[fitted.c]:.1f}% against "
          f"{100 * before:.1f}% transferred: {'kept' if kept else 'not kept'}",
          file=sys.stderr, flush=True)
    record = {**fitted.to_dict(), "clips": len(fit_y), "kept": bool(kept),
              "transferred_validation_accuracy": float(before)}
    if not kept:
        return start, record
    heads = tr.reweighted_heads(start.heads, fitted.weights, fitted.intercepts, start.s,
                                float(transfer["amplitude"]), float(transfer["epsilon"]))
    return replace(start, heads=heads), record


def _responses(opts: TuneOptions, model, start: Start, ds) -> list[tuple]:
    """The transferred network's exact response (`refit.response`) and the classes of the
    refit's training clips, then of the validation split's."""
    from springc.kws.tuning import refit as rf
    from springc.kws.evaluation.evaluate import model_integration
    from springc.kws.data.task import targets
    from springc.lang import load_text

    eps = float(model.settings["transfer"]["epsilon"])
    net = load_text(tr.classifier_text(start.heads, start.s, epsilon=eps, design=start.design),
                    "<classifier>")
    out = []
    for clips in (_draw(ds.split("train"), opts.refit_clips, opts.seed),
                  ds.split("validation")):
        resp = rf.response(net, start.heads, start.s, msp.load_signals(clips, False, 0, []),
                           model_integration(model), opts.scheduler, opts.jobs)
        out.append((resp, targets(clips, model.settings["task"])))
    return out


@dataclass
class Clips:
    """Clips as the loss reads them: signals and the targets of their classes."""

    signals: np.ndarray
    targets: Targets


def clip_set(clips: list, model) -> Clips:
    """The signals and targets of `clips` under the model's task."""
    from springc.kws.data.task import targets

    return Clips(msp.load_signals(clips, False, 0, []),
                 make_targets(model.models, targets(clips, model.settings["task"])))


def optimise(opts: TuneOptions, model, start: Start, clips: list, val: list
             ) -> tuple[np.ndarray, list]:
    """Adam over the epochs, resuming from a matching checkpoint: the z to keep (that of the
    epoch with the lowest validation loss, the start included; the last without validation
    clips) and the per-epoch history (mean training loss, validation loss, seconds)."""
    lay = layout(opts.params, start.s.bins, start.heads)
    eps = float(model.settings["transfer"]["epsilon"])
    check_corners(start, lay, eps)
    train, held = clip_set(clips, model), clip_set(val, model) if val else None
    key, path = run_key(opts, model.settings), checkpoint_path(opts.out)
    z, adam, first = initial_z(start, lay), Adam(opts.lr, *np.zeros((2, lay.size))), 0
    history = [{"epoch": 0, **_val_loss(opts, start, z, eps, held)}]
    best = z
    state = load_checkpoint(path, key, lay.size)
    if state:
        z, history, first = np.array(state["z"]), state["history"], state["epochs_done"]
        best = np.array(state["best"])
        adam = Adam(opts.lr, np.array(state["adam"]["m"]), np.array(state["adam"]["v"]),
                    state["adam"]["t"])
        print(f"tune: resuming from {path} after epoch {first}", file=sys.stderr, flush=True)
    tstop = msp.horizon(start.s, train.signals.shape[1] / msp.INPUT_RATE)
    per_epoch = -(-len(clips) // opts.batch)
    progress = Progress(opts.epochs * per_epoch, first * per_epoch)
    for epoch in range(first, opts.epochs):
        t0, losses, dropped = time.perf_counter(), [], 0
        order = np.random.default_rng([opts.seed, epoch]).permutation(len(clips))
        for lo in range(0, len(clips), opts.batch):
            devices = step_population(opts, epoch * per_epoch + lo // opts.batch)
            g, loss, lost = batch_step(opts, start, lay, z, eps, tstop, train,
                                       order[lo:lo + opts.batch], devices)
            dropped += lost
            z = adam.step(z, g)
            losses.append(loss)
            progress.tick(epoch, len(order[lo:lo + opts.batch]), loss)
        history.append({"epoch": epoch + 1, "train_loss": float(np.mean(losses)),
                        **_val_loss(opts, start, z, eps, held), "dropped_clips": dropped,
                        "seconds": time.perf_counter() - t0})
        best = z if chosen_epoch(history) == epoch + 1 else best
        save_checkpoint(path, key, epoch + 1, z, adam, history, best)
    return (best if held else z), history


def _val_loss(opts: TuneOptions, start: Start, z: np.ndarray, eps: float,
              held: Clips | None) -> dict:
    """{"validation_loss": the mean loss of the validation clips at z}, or {} without any."""
    if held is None:
        return {}
    value = loss_at(opts, start, z, eps, held.targets, held.signals,
                    np.arange(len(held.signals)), validation_population(opts))
    on = f" on {opts.devices} devices" if opts.devices else ""
    print(f"tune: validation loss {value:.4f} ({len(held.signals)} clips{on})",
          file=sys.stderr, flush=True)
    return {"validation_loss": value}


def chosen_epoch(history: list[dict]) -> int:
    """The epoch whose parameters are kept: the lowest validation loss (the first such; epoch
    0 is the start), or the last when there is none."""
    scored = [h for h in history if "validation_loss" in h]
    if not scored:
        return history[-1]["epoch"]
    return min(scored, key=lambda h: (h["validation_loss"], h["epoch"]))["epoch"]


def make_batch(opts: TuneOptions, start: Start, lay: Layout, z: np.ndarray, eps: float,
               tg: Targets, tstop: float, population: tuple[int, ...] = ()) -> Batch:
    """The checked network at z and what the loss needs (scales, intercepts, T), and the
    devices it is scored on (`population`, at `opts.spread`; none: the nominal network)."""
    s, heads = tuned(start, z, lay)
    return Batch(network(s, heads, eps, start.design), np.array([h.scale for h in heads]),
                 np.array([h.intercept for h in heads]), tg, opts.il_weight, tstop, s.bins,
                 len(heads), tuple(lay.keep),
                 float(np.exp(z[lay.slices["temperature"]][0])), tuple(population),
                 opts.spread, opts.seed)


def batch_step(opts: TuneOptions, start: Start, lay: Layout, z: np.ndarray, eps: float,
               tstop: float, train: Clips, idx: np.ndarray, population: tuple[int, ...] = ()
               ) -> tuple[np.ndarray, float, int]:
    """The gradient in z and the mean loss of the clips `idx` (over the devices of
    `population` too), split over the workers, and how many clips were dropped (not
    finite)."""
    from functools import partial

    from springc.kws.features.distributed import cores, map_batches

    b = make_batch(opts, start, lay, z, eps, train.targets, tstop, population)
    workers = opts.jobs or cores()
    parts = [(train.signals[p], p) for p in np.array_split(idx, min(workers, len(idx)))]
    out = map_batches(partial(batch_gradient, b=b), parts, opts.scheduler, workers=workers,
                      desc="tune batch")
    return (*z_gradient(out, lay, z), sum(p["dropped"] for p in out))


def loss_at(opts: TuneOptions, start: Start, z: np.ndarray, eps: float, tg: Targets,
            signals: np.ndarray, idx: np.ndarray, population: tuple[int, ...] = ()) -> float:
    """The mean loss of clips `idx` at z (over the devices of `population` too; forward
    simulations only: what the gradient is the gradient of); clips whose readouts are not
    finite are left out, as the steps leave them."""
    lay = layout(opts.params, start.s.bins, start.heads)
    b = make_batch(opts, start, lay, z, eps, tg,
                   msp.horizon(start.s, signals.shape[1] / msp.INPUT_RATE), population)
    losses = []
    for d in on_devices(b):
        reds = readouts(d, signals[idx].astype(np.float64))
        ok = np.all([np.isfinite(v) for v in reds.values()], axis=0)
        losses.append(batch_loss(d, {k: v[ok] for k, v in reds.items()}, idx[ok])[0])
    loss = np.concatenate(losses)
    return float(loss.mean()) if len(loss) else float("nan")


def finish(opts: TuneOptions, model, ds, net: tuple, history: list, seconds: float,
           refit: dict | None = None) -> dict:
    """Evaluate the tuned network `net` (settings, heads, the heads the gradient epochs
    started from) on the test split and write the model folder (with the refit's record)."""
    from springc.kws.evaluation.evaluate import evaluate_network
    from springc.kws.training.model import TrainedModel, write_model
    from springc.kws.training.train import feature_key
    from springc.lang import load_text

    s, heads, untuned = net
    eps, design = float(model.settings["transfer"]["epsilon"]), tr.model_design(model)
    settings = json.loads(json.dumps(model.settings))
    settings["features"] = feature_key("mass-spring", s)
    settings["transfer"]["couplings"] = [(h.gamma / g.gamma).tolist()
                                         for h, g in zip(heads, untuned)]
    settings["transfer"]["intercepts"] = [h.intercept for h in heads]
    if refit and refit["kept"]:
        settings["transfer"]["refit"] = refit
    settings["tune"] = {"from": str(Path(opts.model).resolve()),
                        "data": str(Path(opts.data).resolve()) if opts.data else None,
                        "params": list(opts.params),
                        "epochs": opts.epochs, "batch": opts.batch, "clips": opts.clips,
                        "val_clips": opts.val_clips, "chosen_epoch": chosen_epoch(history),
                        "refit": opts.refit, "refit_clips": opts.refit_clips,
                        "refit_kept": bool(refit and refit["kept"]),
                        "lr": opts.lr, "il_weight": opts.il_weight, "seed": opts.seed,
                        "devices": opts.devices, "spread": opts.spread,
                        "integration": f"{METHOD} x{SUBSTEPS} float64", "history": history,
                        "seconds": seconds}
    report: dict = {"tune": settings["tune"]}
    if opts.evaluate:
        tm = TrainedModel(Path(opts.out), settings, model.models)
        whole = load_text(tr.classifier_text(heads, s, epsilon=eps, design=design),
                          "<tuned classifier>")
        report = {**evaluate_network(tm, ds, scheduler=opts.scheduler, jobs=opts.jobs,
                                     heads=heads, net=whole), **report}
    files = {"features.spr": msp.feature_text(s),
             "classifier.spr": tr.classifier_text(heads, s, include_heads=False, epsilon=eps,
                                                  design=design)}
    files.update({f"head{k}.spr": tr.head_text(k, h, s, len(heads), design.mvm_stiffness)
                  for k, h in enumerate(heads)})
    c = settings.get("C")
    fits = [(classes, m, c.get("-".join(classes)) if isinstance(c, dict) else c)
            for classes, m in model.models]
    write_model(opts.out, settings, fits, report, extra=files)
    return report


def tune_model(model: str | Path, out: str | Path, *, data: str | Path | None = None,
               params: tuple[str, ...] | list[str] = GROUPS, epochs: int = 2,
               batch: int = 16, clips: int = 64, val_clips: int = 64, lr: float = 0.05,
               il_weight: float = 0.0, mc: int = 0, spread: float = 0.0, seed: int = 0,
               jobs: int = 0, scheduler: str | None = None, refit: bool = True,
               refit_clips: int = 0) -> dict:
    """Tune the mass-spring or device model folder `model` into the new folder `out`, as
    `springc tune` does with the same options and defaults (`mc` devices at relative
    `spread`: the loss over a fabricated population). Returns the report: the test split's
    accuracy and insertion loss with settings.json's "tune" (history, chosen epoch)."""
    return tune(TuneOptions(Path(model), Path(data) if data else None, Path(out),
                            tuple(params), epochs, batch, clips, val_clips, lr, il_weight,
                            seed, jobs, scheduler, refit=refit, refit_clips=refit_clips,
                            devices=mc, spread=spread))
