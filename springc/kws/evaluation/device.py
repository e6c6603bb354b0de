"""The keyword spotter as a fabricated device: a trained mass-spring model's whole classifier
network (`classifier.spr`, sound to decision) evaluated under a netlist transformation.

Fabrication spread (`springc eval MODEL --mc N --spread S`): device k is the network with
every element coefficient of the chosen stage multiplied by its own draw of gauss(1, S) in
Monte Carlo sample k (`springc.lang.draws`, so a draw depends on seed, device, the element's
instance path and the coefficient's key only). Local mismatch draws per element, as
`gauss(nom, S)` written in every element value would; global spread draws once per kind of
coefficient (every spring's k one factor, every mass's m another), at the top level. The
coefficients are those of `FABRICATED`: masses, damping, stiffnesses, leverages, monomial
coefficients and input gains; the initial state is not fabricated.

Physical scale (`springc eval MODEL --temp K --mass KG --spl DB --area M2`): the network at
mass scale mu = KG with the `in` force of a unit-RMS clip the sound pressure p = 20 uPa x
10^(DB/20) on a membrane of A m^2. The displacement scale follows from the force:
lambda = p A / (mu g), g the largest `in` gain, so that without noise the physical network
is the normalised one in other units (`springc.design.scale`, exact for the nonlinear
elements too) and every damper adds its thermal force at K kelvin. Readouts convert back as
x / lambda, the features Phi (quadratic in displacement) as Phi / lambda^2. In normalised
units a damper b (mu b in SI) makes the force PSD 4 k_B K b mu g^2 / (p A)^2: the noise
depends on K mu / (p A)^2 alone, and at a given sound a heavier device is the noisier one
(its dampers grow with it, the force p A does not).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path

import numpy as np

from springc.check import CheckedNetlist, check
from springc.design.scale import P_REF, acoustic_gains, scale_netlist
from springc.errors import CheckError, DataError, DivergedRuns, UsageError
from springc.kws.data.task import open_task_data, targets
from springc.kws.evaluation.evaluate import model_integration, selection_models, trained_data
from springc.kws.features import integration
from springc.kws.features import massspring as msp
from springc.kws.training.report import score
from springc.kws.training.transfer import Head, decisions, model_heads, readout_reductions
from springc.lang import draws
from springc.lang.ir import FlatNetlist

STAGES = ("filters", "compressors", "delays", "couplings", "readouts")
DEVICE_GROUP = 8  # devices per kernel call: progress after each group
SPREAD_KINDS = ("local", "global")
# (table, element key) of every fabricated coefficient; x0 and v0 are initial state
FABRICATED = (
    ("masses", "m"), ("masses", "b"), ("springs", "k"), ("duffings", "l"),
    ("couplings", "k"), ("couplings", "a"), ("quads", "g"), ("quads", "a"),
    ("dashpots", "b"), ("monomials", "c"), ("forces", "gain"),
)
# the classifier's instances (classifier_text, front_end) by stage: the squarers and
# low-pass masses that demodulate go with the compressors; a head's mvm and its quadratic
# couplings are the couplings
_FRONT = {"Xf": "filters", "Xq": "compressors", "Xlp": "compressors", "Xc": "compressors",
          "Cfan": "delays", "Xd": "delays", "Ct": "delays",
          "Mf": "delays", "Cbf": "delays", "Kgf": "delays",  # a tap buffer's terminals
          "Bra": "readouts", "Brb": "readouts"}  # a router's readouts
_HEAD = {"Xm": "couplings", "Qy": "couplings", "Ms": "couplings", "Cs": "couplings",
         "Xr": "readouts"}


# -- fabrication spread -------------------------------------------------------------------------


@dataclass(frozen=True)
class Spread:
    """Relative standard deviation `sigma` of every coefficient of `stage` ("all": every
    stage), drawn per element ("local") or per kind of coefficient ("global")."""

    sigma: float
    kind: str = "local"
    stage: str = "all"
    seed: int = 0

    def validate(self) -> None:
        """UsageError naming the option for a value out of its range."""
        if not (math.isfinite(self.sigma) and self.sigma >= 0):
            raise UsageError(f"--spread must be a finite relative deviation >= 0, not "
                             f"{self.sigma:g}", hint="0.01 is 1% of every coefficient")
        if self.kind not in SPREAD_KINDS:
            raise UsageError(f"--spread-kind must be one of {', '.join(SPREAD_KINDS)}, not "
                             f"{self.kind!r}")
        if self.stage not in STAGES + ("all",):
            raise UsageError(f"--stage must be one of {', '.join(STAGES)} or all, not "
                             f"{self.stage!r}")
        check_seed(self.seed)

    def describe(self) -> str:
        return (f"{self.kind} spread {100 * self.sigma:g}% of every coefficient of "
                f"{'every stage' if self.stage == 'all' else 'the ' + self.stage}, "
                f"seed {self.seed}")


def check_seed(seed: int) -> None:
    if not 0 <= seed < draws.MAX_SEED:
        raise UsageError(f"--seed must be an integer from 0 to 2^63 - 1, not {seed}")


def stage_of(name: str) -> str | None:
    """The stage of a classifier element from its instance path (`Xh3.Xm.M2`: couplings),
    None for an element of no known stage."""
    first, _, rest = name.partition(".")
    base = first.rstrip("0123456789_")
    if base == "Xh":
        return _HEAD.get(rest.partition(".")[0].rstrip("0123456789_"))
    return _FRONT.get(base)


def stages(net: FlatNetlist, table: str) -> np.ndarray:
    """The stage of every element of a table; DataError for an element of none."""
    names = getattr(net, table).names
    out = np.array([stage_of(n) or "" for n in names], dtype=object)
    if len(out) and (out == "").any():
        bad = names[int(np.flatnonzero(out == "")[0])]
        raise DataError(net.file, f"element {bad} belongs to no stage of the classifier "
                        f"({', '.join(STAGES)})", hint="use --stage all")
    return out


def factors(net: FlatNetlist, spread: Spread, devices) -> dict[tuple[str, str], np.ndarray]:
    """Per (table, key) of `FABRICATED` the factors (devices, elements) of the given devices
    (Monte Carlo sample indices): draws of gauss(1, sigma), 1 outside the stage."""
    devices = np.atleast_1d(np.asarray(devices, np.int64))
    out = {}
    for table, key in FABRICATED:
        names = getattr(net, table).names
        f = np.ones((len(devices), len(names)))
        chosen = (np.arange(len(names)) if spread.stage == "all"
                  else np.flatnonzero(stages(net, table) == spread.stage))
        if spread.sigma > 0 and len(chosen):
            f[:, chosen] = _draws(names, chosen, table, key, spread, devices)
        out[(table, key)] = f
    return out


def _draws(names: list[str], chosen: np.ndarray, table: str, key: str, spread: Spread,
           devices: np.ndarray) -> np.ndarray:
    """(devices, chosen) draws: per element at its own site, or one per kind at the top."""
    args = [1.0, spread.sigma]
    if spread.kind == "global":
        one = draws.values("gauss", args, spread.seed, devices, "", f"{table}.{key}")
        return np.repeat(one[:, None], len(chosen), axis=1)
    return np.stack([draws.values("gauss", args, spread.seed, devices, names[e], key)
                     for e in chosen], axis=1)


def fabricate(net: FlatNetlist, spread: Spread, device: int) -> FlatNetlist:
    """Device `device` of the population: `net` with every coefficient times its factor.
    UsageError if a factor is not positive (a spread too wide for a multiplicative draw)."""
    out = net
    for (table, key), f in factors(net, spread, [device]).items():
        tab = getattr(out, table)
        if (f <= 0).any():
            e = int(np.flatnonzero(f[0] <= 0)[0])
            raise UsageError(f"device {device}: element {tab.names[e]} draws the factor "
                             f"{f[0, e]:.3g} for {key} (--spread {spread.sigma:g} is too wide: a "
                             "coefficient would change sign)", hint="use a spread below 0.2")
        out = replace(out, **{table: replace(tab, **{key: getattr(tab, key) * f[0]})})
    return out


# -- physical scale -----------------------------------------------------------------------------


@dataclass(frozen=True)
class Physical:
    """The device at temperature `temp` (K), mass scale `mass` (kg per normalised mass unit),
    hearing `spl` (dB re 20 uPa) on a membrane of `area` (m^2); thermal draws from `seed`."""

    temp: float
    mass: float
    spl: float
    area: float
    seed: int = 0

    def validate(self) -> None:
        """UsageError naming the option and its unit for a value out of range."""
        if not (math.isfinite(self.temp) and self.temp >= 0):
            raise UsageError(f"--temp must be a finite temperature >= 0 K, not {self.temp:g}",
                             hint="kelvin: 300 is room temperature")
        for name, value, unit in (("mass", self.mass, "kg"), ("area", self.area, "m^2")):
            if not (math.isfinite(value) and value > 0):
                raise UsageError(f"--{name} must be a positive finite number of {unit}, not "
                                 f"{value:g}")
        if not math.isfinite(self.spl):
            raise UsageError(f"--spl must be a finite level in dB re 20 uPa, not {self.spl:g}")
        check_seed(self.seed)

    @property
    def pressure(self) -> float:
        """Pa: the RMS sound pressure of `spl`."""
        return P_REF * 10 ** (self.spl / 20)

    def describe(self) -> str:
        return (f"{self.temp:g} K, mass scale {self.mass:.3g} kg, {self.spl:g} dB SPL "
                f"({self.pressure:.3g} Pa) on {self.area:.3g} m^2, seed {self.seed}")


def unit_mass(model_dir: Path, device_mass: float, mass: float | None) -> float:
    """kg per normalised mass unit of a model's whole network weighing `device_mass` kg
    (`--device-mass`, beside `--mass`, which gives the unit's mass directly)."""
    from springc.kws.evaluation.energy import model_network

    if mass is not None:
        raise UsageError("--device-mass (the whole device) and --mass (kg per unit) say the "
                         "same thing: give one")
    if not (math.isfinite(device_mass) and device_mass > 0):
        raise UsageError(f"--device-mass must be a positive finite number of kg, not "
                         f"{device_mass:g}")
    net, _ = model_network(model_dir, 1.0)
    return device_mass / float(net.mass().sum())


def length_scale(net: FlatNetlist, phys: Physical) -> float:
    """lambda (m per normalised displacement): p A / (mu g) for g the largest `in` gain."""
    driven = np.array([s.kind == "in" for s in net.forces.source], bool)
    if not driven.any():
        raise UsageError("the network has no F ... in(k) element for sound to drive")
    return phys.pressure * phys.area / (phys.mass * np.abs(net.forces.gain[driven]).max())


def physical_network(net: FlatNetlist, phys: Physical) -> tuple[FlatNetlist, float]:
    """The network at physical scale (module docstring) and its length scale lambda."""
    lam = length_scale(net, phys)
    return acoustic_gains(scale_netlist(net, phys.mass, lam), phys.spl, phys.area), lam


# -- simulating the network ---------------------------------------------------------------------


def network_batch(items: np.ndarray, checked, specs: list, tstop: float,
                  plan: integration.Integration, s: msp.MassSpringSettings,
                  tries: slice = slice(None), temp: float | None = None,
                  seed: int = 0, judged: bool = True) -> dict:
    """Reductions of one batch (a Dask task): `items` rows are (clip index, samples...).
    With a temperature, the batch's thermal draws come from `seed` and its first clip's
    index (a call's runs are numbered from 0, so batches need seeds of their own).
    `judged`: whether the step was judged stable (`outputs`)."""
    from springc.sim.simulate import simulate

    sig = items[:, 1:].astype(np.float64)
    first = int(items[0, 0])
    batch_seed = (seed + first * 0x9E3779B97F4A7C15) % draws.MAX_SEED

    def run(method, substeps, idx):
        return simulate(checked, sig[idx, None, :], msp.INPUT_RATE, probes=[],
                        reductions=specs, tstop=tstop, chunk=msp.BATCH, batch=len(idx),
                        method=method, substeps=substeps, precision=plan.precision,
                        temp=temp, seed=batch_seed if temp else None,
                        check_step=judged).reductions

    return integration.run_with_retries(plan, run, len(sig), tries, msp.stiffness(sig, s))


def devices_batch(items: np.ndarray, members: list, specs: list, tstop: float,
                  plan: integration.Integration, s: msp.MassSpringSettings,
                  tries: slice = slice(None)) -> dict:
    """`network_batch` for a population: every device of `members` (checked netlists of one
    structure) on every clip of the batch in the lanes of one kernel call per try
    (`simulate_lanes`), so nothing is compiled or called per device. Retries go run by run as
    `integration.run_with_retries` does (a run: a device on a clip); a run that diverges at
    the last retry has NaN rows, so that it fails its device alone. Reductions (clips,
    devices, ...): a clip a row, as `msp.map_pooled` gathers rows."""
    from springc.sim.simulate import simulate_lanes

    sig = items[:, 1:].astype(np.float64)
    clips, labels = len(sig), [f"device {p}" for p in range(len(members))]
    final = plan.retries()[-1]

    def run(method, substeps, idx):
        mem, clip = np.unique(idx // clips), np.unique(idx % clips)
        try:
            red = simulate_lanes([members[p] for p in mem], [labels[p] for p in mem],
                                 sig[clip, None, :], msp.INPUT_RATE, probes=[],
                                 reductions=specs, tstop=tstop, chunk=msp.BATCH,
                                 batch=len(mem) * len(clip), method=method,
                                 substeps=substeps, precision=plan.precision,
                                 check_step=False).reductions
            diverged = np.zeros(0, np.int64)
        except DivergedRuns as err:
            red, diverged = err.reductions, np.asarray(err.diverged, np.int64)
        # the call ran every chosen device on every chosen clip: the runs asked for
        call = np.searchsorted(mem, idx // clips) * len(clip) + np.searchsorted(clip, idx % clips)
        got = {key: value[call].astype(np.float64) for key, value in red.items()}
        bad = np.flatnonzero(np.isin(call, diverged))
        if len(bad) and (method, substeps) != final:
            raise DivergedRuns(f"{len(bad)} run(s) diverged", bad, got)
        for value in got.values():
            value[bad] = np.nan
        return got

    stiffness = np.tile(msp.stiffness(sig, s), len(members))
    out = integration.run_with_retries(plan, run, len(members) * clips, tries, stiffness)
    return {key: np.swapaxes(v.reshape((len(members), clips) + v.shape[1:]), 0, 1)
            for key, v in out.items()}


@dataclass(frozen=True)
class Setup:
    """What every device shares: the model's settings, heads and integration, its normalised
    classifier network, the test clips (signals) and their classes."""

    model: object
    s: msp.MassSpringSettings
    heads: list[Head]
    net: FlatNetlist
    plan: integration.Integration
    signals: np.ndarray
    y: np.ndarray

    @property
    def task(self) -> str:
        return self.model.settings["task"]


def load_setup(model_dir: Path, data: Path | None = None, clips: int | None = None,
               protocol: str | None = None, split: str = "test") -> Setup:
    """The model's network and its test split (or `split`; `clips` clips spread evenly over
    it, default all), read as `springc eval` reads them. UsageError for a model that is not
    mass-spring."""
    from springc.kws.training.model import load_model
    from springc.lang import load_file

    model = load_model(Path(model_dir))
    if model.settings["realisation"] != "mass-spring":
        raise UsageError(f"{model_dir} is a {model.settings['realisation']} model; a device "
                         "is a mass-spring network", hint="train with --realisation mass-spring")
    s, heads = model_heads(model)
    return Setup(model, s, heads, load_file(model.folder / "classifier.spr"),
                 model_integration(model), *split_signals(model, data, clips, protocol, split))


def split_signals(model, data: Path | None, clips: int | None, protocol: str | None,
                  split: str) -> tuple[np.ndarray, np.ndarray]:
    """The signals and classes of `clips` clips spread evenly over the model's `split` of
    `data` (default: the data it was trained on; all clips where `clips` is None)."""
    ds = open_task_data(Path(data) if data else trained_data(model), model.settings["task"],
                        int(model.settings.get("seed", 0)),
                        protocol or model.settings.get("protocol"), splits=(split,))
    chosen = ds.split(split)
    if clips is not None and clips < len(chosen):  # spread evenly: classes in proportion
        chosen = [chosen[k] for k in np.linspace(0, len(chosen) - 1, clips).round().astype(int)]
    return msp.load_signals(chosen, False, 0, []), targets(chosen, model.settings["task"])


def outputs(setup: Setup, net: FlatNetlist, *, lam: float = 1.0, temp: float | None = None,
            seed: int = 0, phi: bool = False, judge: bool = True,
            scheduler: str | None = None, jobs: int = 0,
            desc: str = "device") -> dict[str, np.ndarray]:
    """The decisions (clips, rows) and, with `phi`, the features Phi (clips, N) of the test
    clips through `net`, converted to normalised units by the length scale `lam`. `judge`:
    refuse a step above the stability limit; a fabricated device is not judged, because
    mismatch turns the heads' designed zero modes into slowly growing ones, which no step
    makes stable (the check refuses them) while the clip lasts too short for most to matter:
    what the device then does, the simulation shows (a run that blows up diverges)."""
    specs: list = readout_reductions(setup.heads)
    if phi:
        specs.append(msp.phi_reduction(net, setup.s))
    items, tstop = _clips(setup)
    work = partial(network_batch, checked=check(net, judge_step=judge), specs=specs,
                   tstop=tstop, plan=setup.plan, s=setup.s, temp=temp, seed=seed,
                   judged=judge)
    reds = msp.map_pooled(work, items, desc, scheduler, jobs or None)
    out = {"decisions": decisions({k: v / lam for k, v in reds.items()
                                   if k.startswith("final:")}, setup.heads)}
    if phi:
        out["phi"] = reds["phi"] / lam**2
    return out


def _clips(setup: Setup) -> tuple[np.ndarray, float]:
    """The test clips as Dask items (rows: clip index, samples...) and the simulated time."""
    items = np.column_stack([np.arange(len(setup.signals)), setup.signals.astype(np.float64)])
    return items, msp.horizon(setup.s, setup.signals.shape[1] / msp.INPUT_RATE)


def device_decisions(setup: Setup, members: list, *, scheduler: str | None = None,
                     jobs: int = 0, desc: str = "devices") -> np.ndarray:
    """The decisions (devices, clips, rows) of the test clips through every device of
    `members` (checked, unjudged netlists of the classifier's structure) at once
    (`devices_batch`); a device's run that diverges at every retry gives NaN rows."""
    items, tstop = _clips(setup)
    work = partial(devices_batch, members=members, specs=readout_reductions(setup.heads),
                   tstop=tstop, plan=setup.plan, s=setup.s)
    reds = msp.map_pooled(work, items, desc, scheduler, jobs or None)
    return np.stack([decisions({k: v[:, p] for k, v in reds.items() if k.startswith("final:")},
                               setup.heads) for p in range(len(members))])


def accuracy(setup: Setup, d: np.ndarray) -> float:
    """The accuracy of decision rows, scored like `springc eval`'s; a clip whose decisions
    are not finite counts as an error."""
    ok = np.isfinite(d).all(axis=1)
    if not ok.any():
        return 0.0
    report = score(selection_models(setup.model.models), d[ok], setup.y[ok], setup.task)
    return report["accuracy"] * report["n"] / (report["n"] + int((~ok).sum()))


def summary(values: np.ndarray) -> dict[str, float]:
    """Mean, standard deviation, its standard error, 5th percentile and worst."""
    v = np.asarray(values, np.float64)
    sd = float(v.std(ddof=1)) if len(v) > 1 else 0.0
    return {"mean": float(v.mean()), "sd": sd, "stderr": sd / math.sqrt(len(v)),
            "p5": float(np.percentile(v, 5)), "worst": float(v.min())}


def evaluate_spread(setup: Setup, devices: int, spread: Spread, *,
                    nominal: np.ndarray | None = None, scheduler: str | None = None,
                    jobs: int = 0, progress: Callable[[str], None] | None = None) -> dict:
    """The accuracy of the nominal design (its decisions simulated unless `nominal` gives
    them) and of `devices` fabricated devices (0 .. N-1) on the setup's clips, with each
    device's decision error: the median |device - nominal decision| over the median
    |nominal decision|. A device whose network diverges, or that the checks find statically
    unstable (stiffness at rest not positive semidefinite), scores 0 (marked "diverged")."""
    spread.validate()

    def row(k: int, dk: np.ndarray, nominal: np.ndarray) -> dict:
        return {"device": k, "accuracy": accuracy(setup, dk), "diverged": False,
                "decision_error": decision_error(dk, nominal)}

    nominal, rows = population(setup, devices, spread, row, nominal=nominal,
                               scheduler=scheduler, jobs=jobs, progress=progress)
    acc = np.array([r["accuracy"] for r in rows])
    return {"devices": rows, "nominal": accuracy(setup, nominal), "accuracy": summary(acc),
            "n": len(setup.y), "spread": spread.sigma, "kind": spread.kind,
            "stage": spread.stage, "seed": spread.seed}


def population(setup: Setup, devices: int, spread: Spread,
               row: Callable[[int, np.ndarray, np.ndarray], dict], *,
               nominal: np.ndarray | None = None, scheduler: str | None = None, jobs: int = 0,
               progress: Callable[[str], None] | None = None) -> tuple[np.ndarray, list[dict]]:
    """The nominal design's decisions on the setup's clips (simulated unless `nominal` gives
    them) and a row per device 0 .. N-1: `row(k, its decisions, the nominal's)`, or
    `diverged_row` for a device the checks find unstable or whose network diverges; devices
    simulated `DEVICE_GROUP` at a time, with progress after each group."""
    from springc.kws.features.distributed import session

    rows, start = [], time.perf_counter()
    with session(scheduler, jobs or None):
        if nominal is None:
            nominal = outputs(setup, setup.net, scheduler=scheduler, jobs=jobs,
                              desc="nominal design")["decisions"]
        for first in range(0, devices, DEVICE_GROUP):
            ks = range(first, min(first + DEVICE_GROUP, devices))
            for k, dk in fabricated_decisions(setup, ks, spread, scheduler, jobs).items():
                rows.append(diverged_row(k, dk) if isinstance(dk, str) else row(k, dk, nominal))
            if progress:
                progress(progress_line(rows, devices, time.perf_counter() - start))
    return nominal, rows


def fabricated_decisions(setup: Setup, ks: range, spread: Spread, scheduler=None,
                         jobs: int = 0) -> dict[int, np.ndarray | str]:
    """Device k's decisions (clips, rows) for every k of `ks`, simulated together
    (`device_decisions`), or why it has none: the checks found it statically unstable, or
    its network diverged at every retry."""
    out: dict[int, np.ndarray | str] = {}
    members = {}
    for k in ks:
        device = checked_device(setup.net, spread, k)
        if isinstance(device, str):
            out[k] = device
        else:
            members[k] = device
    if members:
        d = device_decisions(setup, list(members.values()), scheduler=scheduler, jobs=jobs,
                             desc=f"devices {ks.start}-{ks.stop - 1}")
        for k, dk in zip(members, d):
            out[k] = dk if np.isfinite(dk).all() else \
                "its network diverged at every integration retry"
    return {k: out[k] for k in ks}


def checked_device(net: FlatNetlist, spread: Spread, k: int) -> CheckedNetlist | str:
    """Device k of the population, checked with its step not judged (mismatch turns the
    heads' designed zero modes into slowly growing ones, `outputs`), or why the checks find
    it statically unstable."""
    try:
        return check(fabricate(net, spread, k), judge_step=False)
    except CheckError as err:
        return err.message


def diverged_row(k: int, why: str) -> dict:
    return {"device": k, "accuracy": 0.0, "diverged": True, "decision_error": None,
            "why": why}


def decision_error(d: np.ndarray, nominal: np.ndarray) -> float:
    """The median |d - nominal decision| over the median |nominal decision|."""
    return float(np.median(np.abs(d - nominal)) / np.median(np.abs(nominal)))


def progress_line(rows: list[dict], total: int, seconds: float) -> str:
    """'device 3 of 8: 51.56%; 0.8 devices/min, about 6 min left'."""
    done = len(rows)
    rate = done / seconds
    return (f"device {done} of {total}: {100 * rows[-1]['accuracy']:.2f}%"
            f"{' (diverged)' if rows[-1]['diverged'] else ''}; {60 * rate:.2g} devices/min, "
            f"about {(total - done) / rate / 60:.1f} min left")


def evaluate_physical(setup: Setup, phys: Physical, *, reference: dict | None = None,
                      scheduler: str | None = None, jobs: int = 0) -> dict:
    """Accuracy with thermal noise at physical scale, beside the noiseless accuracy, the
    signal-to-noise ratio of Phi (noiseless Phi over noisy minus noiseless, per feature over
    the clips) and the decision error (`decision_error` against the noiseless decisions).
    `reference`: the noiseless normalised `outputs(..., phi=True)`, computed here unless
    given (it is the same for every scale). Noise that drives a nonlinear element beyond its
    bounds diverges the run: the device then decides nothing, scores 0 and is `diverged`,
    as a diverged device of a population is."""
    from springc.kws.features.distributed import session

    phys.validate()
    net, lam = physical_network(setup.net, phys)
    with session(scheduler, jobs or None):
        if reference is None:
            reference = outputs(setup, setup.net, phi=True, scheduler=scheduler, jobs=jobs,
                                desc="noiseless")
        try:
            noisy = outputs(setup, net, lam=lam, temp=phys.temp, seed=phys.seed, phi=True,
                            scheduler=scheduler, jobs=jobs, desc="thermal noise")
        except DivergedRuns as err:
            noisy = {"decisions": None, "why": err.message}
    scale = physical_report(phys, lam, setup.net, len(setup.y),
                            accuracy(setup, reference["decisions"]))
    if noisy["decisions"] is None:
        return {"accuracy": 0.0, "diverged": noisy["why"], "phi_snr_db": None,
                "decision_error": float("inf"), **scale}
    return {"accuracy": accuracy(setup, noisy["decisions"]), "diverged": None,
            "phi_snr_db": phi_snr_db(reference["phi"], noisy["phi"]),
            "decision_error": decision_error(noisy["decisions"], reference["decisions"]),
            **scale}


def physical_report(phys: Physical, lam: float, net: FlatNetlist, n: int,
                    noiseless: float) -> dict:
    """The part of a physical-scale report that says where it was measured: clips, scale,
    length scale, device mass and the noiseless accuracy."""
    return {"n": n, "temp": phys.temp, "mass": phys.mass, "spl": phys.spl, "area": phys.area,
            "seed": phys.seed, "pressure": phys.pressure, "length": lam,
            "device_mass": float(phys.mass * net.mass().sum()), "noiseless": noiseless}


def phi_snr_db(clean: np.ndarray, noisy: np.ndarray) -> dict[str, float]:
    """SNR of the features in dB: per feature sum(clean^2) / sum((noisy - clean)^2) over
    the clips; the median and the worst feature, and all features pooled."""
    err = np.sum((noisy - clean) ** 2, axis=0)
    sig = np.sum(clean**2, axis=0)
    with np.errstate(divide="ignore"):
        per = 10 * np.log10(sig / err)
        pooled = 10 * np.log10(sig.sum() / err.sum())
    return {"median": float(np.median(per)), "worst": float(per.min()),
            "pooled": float(pooled)}


# -- the command's options and report -----------------------------------------------------------


def study(devices: int | None, spread: float | None, kind: str | None, stage: str | None,
          seed: int | None, temp: float | None, mass: float | None, spl: float | None,
          area: float | None) -> Spread | Physical | None:
    """The study `springc eval`'s options ask for (None: a plain evaluation), validated; a
    UsageError names a missing or stray option."""
    population = {"--mc": devices, "--spread": spread, "--spread-kind": kind, "--stage": stage}
    physical = {"--temp": temp, "--mass": mass, "--spl": spl, "--area": area}
    in_population = any(v is not None for v in population.values())
    if in_population and any(v is not None for v in physical.values()):
        raise UsageError("--mc/--spread (fabrication spread) and --temp/--mass/--spl/--area "
                         "(thermal noise at physical scale) are separate studies",
                         hint="run eval once for each")
    if in_population:
        _require(population, ("--mc", "--spread"), "a fabricated population")
        if devices < 1:
            raise UsageError(f"--mc must be at least 1 device, not {devices}")
        return _validated(Spread(float(spread), kind or "local", stage or "all", seed or 0))
    if all(v is None for v in physical.values()):
        if seed is not None:
            raise UsageError("--seed draws the devices of --mc or the noise of --temp")
        return None
    _require(physical, tuple(physical), "the device at physical scale")
    return _validated(Physical(float(temp), float(mass), float(spl), float(area), seed or 0))


def _require(given: dict, names: tuple[str, ...], what: str) -> None:
    missing = [n for n in names if given[n] is None]
    if missing:
        present = ", ".join(n for n in given if given[n] is not None)
        raise UsageError(f"{present} also need{'s' if ', ' not in present else ''} "
                         f"{' and '.join(missing)} ({what})",
                         hint=f"give {' '.join(f'{n} VALUE' for n in names)}")


def _validated(item: Spread | Physical) -> Spread | Physical:
    item.validate()
    return item


def spread_lines(report: dict, spread: Spread) -> list[str]:
    """The population's report as text: every device, then the summary."""
    trimmed = "trimmed" in report  # `eval --trim`: the trimmed figure beside each
    lines = [f"{len(report['devices'])} fabricated device(s), {spread.describe()}, "
             f"{report['n']} test clips"
             + (f"; trimmed on {report['trim_clips']} validation clips (untrimmed, trimmed):"
                if trimmed else ":"),
             f"  nominal design  {100 * report['nominal']:6.2f}%"
             + (f"  {100 * report['nominal_trimmed']:6.2f}%" if trimmed else "")]
    for r in report["devices"]:
        lines.append(f"  device {r['device']:<7d} {100 * r['accuracy']:6.2f}%"
                     + (f"  {100 * r['trimmed']:6.2f}%" if trimmed else "")
                     + ("  (diverged)" if r["diverged"] else ""))
    lines.append(_summary_line("untrimmed: " if trimmed else "", report["accuracy"]))
    if trimmed:
        lines.append(_summary_line("trimmed:   ", report["trimmed"]))
    return lines


def _summary_line(label: str, a: dict) -> str:
    return (f"{label}mean {100 * a['mean']:.2f}% (sd {100 * a['sd']:.2f}, standard error "
            f"{100 * a['stderr']:.2f}), 5th percentile {100 * a['p5']:.2f}%, worst "
            f"{100 * a['worst']:.2f}%")


def physical_lines(report: dict, phys: Physical) -> list[str]:
    """The physical-scale report as text."""
    snr = report["phi_snr_db"]
    of = report.get("snr_of", "the features Phi")
    head = [f"device at physical scale: {phys.describe()}; {report['n']} test clips",
            f"  displacement scale {report['length']:.3g} m per unit, device mass "
            f"{report['device_mass']:.3g} kg"]
    if report.get("diverged"):
        return head + [f"  the noise drove the network beyond its bounds ({report['diverged']})"
                       f": no decision (scored 0); {100 * report['noiseless']:.2f}% noiseless"]
    return head + [f"  accuracy {100 * report['accuracy']:.2f}% with thermal noise, "
                   f"{100 * report['noiseless']:.2f}% noiseless",
                   f"  SNR of {of}: median {snr['median']:.1f} dB over them, worst "
                   f"{snr['worst']:.1f} dB, pooled {snr['pooled']:.1f} dB",
                   f"  decision error (median |noisy - noiseless| / median |noiseless|) "
                   f"{report['decision_error']:.3g}", *_calibrated_lines(report)]


def _calibrated_lines(report: dict) -> list[str]:
    """A router's decision with its readouts' thermal offsets subtracted, if measured."""
    cal = report.get("calibrated")
    if not cal:
        return []
    return [f"  calibrated: each readout's mean dissipation on {cal['dark_clips']} silent "
            f"clips subtracted: accuracy {100 * cal['accuracy']:.2f}%, decision error "
            f"{cal['decision_error']:.3g}"]
