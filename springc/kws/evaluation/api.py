"""Keyword spotting from Python: `train`, `evaluate`, `cross_validate` and `synthesise` do what
`springc train`, `eval`, `cv` and `data synth` do, with keyword arguments named as the options
(the commands call these, or the library function they wrap), and `load_model` reads a trained
model that classifies sound files and evaluates test splits as `springc classify` and `eval`
do. Each is reached as `springc.train`, `springc.kws.load_model` and so on."""

from __future__ import annotations

import contextlib
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from springc.errors import DataError, UsageError
from springc.kws.evaluation.classify import classify
from springc.kws.evaluation.evaluate import evaluate as evaluate_split
from springc.kws.features.digital import FeatureSettings
from springc.kws.training.model import TrainedModel, load_model as read_model

Progress = Callable[[str], None] | None  # called with a line of progress, or None: silent


def train(data: str | Path, out: str | Path, *, bins: int = 8, delays: int = 3,
          realisation: str = "digital", filterbank: str = "two-mode", task: str = "kws12",
          td: float = 0.032, tau: float = 80.0, fc: float = 50.0,
          feature_rate: float = 1000.0, protocol: str | None = None,
          class_weights: str | None = None, jobs: int = 0, seed: int = 0,
          use_cache: bool = True, epsilon: float | None = None,
          threshold: float | None = None, tolerance: float = 1e-3,
          paper_steps: bool = False, scheduler: str | None = None,
          heads: str | None = None, buffer: tuple[float, float] | None = None,
          mvm_stiffness: float | None = None, spl: float | None = None,
          area: float | None = None, temp: float | None = None,
          device_mass: float | None = None, stage_stiffness: float | None = None,
          squarer_range: float | None = None, device: str | None = None) -> dict:
    """Train the keyword spotter on the data set folder `data` (GSCD layout), test it and
    write the model folder `out`, as `springc train`: `bins` mel bins of `delays` delays
    each, `realisation` digital, baseline, mass-spring, device (a mass-spring network
    built for a fabricated device: summing heads) or router (a linear passive network; the
    device and the router record their physical scale `spl`, `area`, `temp`, `device_mass`,
    defaults `energy.DEFAULTS`), `filterbank`, `task` (kws12 or
    digits-pairs), tap delay `td` (s), readout time constant `tau` (s), low-pass cut-off
    `fc` (Hz), `feature_rate` (Hz), held-out `protocol` (lists or balanced; None: the
    task's), `class_weights` (balanced or none; None: the task's), `jobs` worker processes
    (0: all cores), `seed`, `use_cache` (False: `--no-cache`). Mass-spring only: `epsilon`
    (squaring error of the heads), `threshold` (compression A_c, m), `tolerance` (error that
    chooses the integrator; `paper_steps`: RK4 x8 float32 instead), `scheduler` (a Dask
    address), `heads` (zero-mode or summing; None: zero-mode, summing for a device),
    `buffer` (kb, kg: a tap buffer in units of kc) and `mvm_stiffness` (None: the paper's
    heads up to eps 1e-5, beyond it the buffered design `transfer.BUFFERED`),
    `stage_stiffness` (every stage after the Mel filters that many times stiffer,
    `massspring.stage_scaled`; None: 1), `squarer_range` (m of filter output where the
    squarers detune the filters fully; None: `massspring.SQUARER_RANGE`), `device` (cpu,
    cuda or auto; None: that of the innermost `springc.default_device`). Returns the training
    report: accuracy, n, per_class, confusion, counts, ... as report.json holds it, with each
    phase's wall "seconds"."""
    from springc.kws.training.model import check_out_folder
    from springc.kws.training.train import TrainOptions, train as run

    design, scale = _design(realisation, epsilon, heads, buffer, mvm_stiffness,
                            dict(spl=spl, area=area, temp=temp, device_mass=device_mass))
    given = {"--stage-stiffness": stage_stiffness, "--squarer-range": squarer_range}
    for name, value in given.items():
        if value is not None and realisation not in ("mass-spring", "device"):
            raise UsageError(f"{name} is a setting of the mass-spring network",
                             hint="--realisation mass-spring or device")
    realisation = "mass-spring" if realisation == "device" else realisation

    out = Path(out)
    check_out_folder(out)  # before the minutes of training
    settings = FeatureSettings(bins=bins, delays=delays, filterbank=filterbank, td=td,
                               tau=tau, fc=fc, feature_rate=feature_rate)
    opts = TrainOptions(data=Path(data), out=out, settings=settings, realisation=realisation,
                        task=task, jobs=jobs, seed=seed, use_cache=use_cache,
                        epsilon=epsilon, scheduler=scheduler, protocol=protocol,
                        balance_weights=_balance(class_weights),
                        massspring=_massspring(settings, threshold, stage_stiffness,
                                               squarer_range),
                        tolerance=_tolerance(tolerance, paper_steps), design=design,
                        device=scale)
    with _on(device):
        return run(opts)


def evaluate(model: str | Path, data: str | Path | None = None, *,
             realisation: str | None = None, protocol: str | None = None, jobs: int = 0,
             use_cache: bool = True, scheduler: str | None = None, budget: int | None = None,
             mc: int | None = None, spread: float | None = None,
             spread_kind: str | None = None, stage: str | None = None,
             temp: float | None = None, mass: float | None = None, spl: float | None = None,
             area: float | None = None, seed: int | None = None, clips: int | None = None,
             device_mass: float | None = None, trim: int | None = None,
             device: str | None = None, progress: Progress = None) -> dict:
    """Evaluate the model folder `model` on the test split of `data` (default: the data set
    it was trained on), as `springc eval`: `realisation` must match the model's (None: the
    model's), `protocol` lists or balanced (None: the model's), `jobs`, `use_cache`,
    `scheduler`, `device` as for `train`. Returns the evaluation report: accuracy,
    majority_rate, n, per_class, confusion (mass-spring: the network's figures too).

    The other studies of `springc eval`, on mass-spring models: `budget=N`, where the input
    work of the first N test clips goes at the physical scale of `spl`, `area`, `temp` and
    `device_mass` (or `mass` per unit; for what is not given, the scale a device model
    recorded, else `energy.DEFAULTS`):
    `energy.physical_budget`'s dict, `"stages"` {"work in", stage..., "left at the end"}
    each (N,) in J, the sound, k_B T and the loss bound; `mc=N` devices with coefficients
    spread by `spread` (relative sd), `spread_kind` (local or global), `stage`, `seed`: the
    population's report (devices, nominal, accuracy summary); `temp` (K), `mass` (kg per
    normalised unit, or `device_mass` for the whole device), `spl` (dB), `area` (m^2), `seed`:
    the device at physical scale with thermal noise (a device model's recorded spl, area and
    device mass where not given); `clips`: with `mc` or `temp`, that many
    test clips spread over the split; `trim=K` with `mc`: each device and the nominal design
    also trimmed on K validation clips (`springc.kws.evaluation.trim`), "trimmed" beside
    each accuracy; `progress` hears the population's progress."""
    from springc.kws.evaluation import device as dv

    model, data = Path(model), Path(data) if data else None
    if trim is not None:
        _trim_allowed(trim, budget, mc)
    if budget:
        return _budget(model, data, budget, protocol, mc, spread, clips, recorded_scale(
            model, dict(spl=spl, area=area, temp=temp, device_mass=device_mass, mass=mass)))
    if temp is not None:  # the noise study: at the device model's own scale unless given
        scale = recorded_scale(model, dict(spl=spl, area=area, device_mass=device_mass,
                                           mass=mass))
        spl, area, device_mass = scale["spl"], scale["area"], scale["device_mass"]
    if device_mass is not None:
        mass = dv.unit_mass(model, device_mass, mass)
    study = dv.study(mc, spread, spread_kind, stage, seed, temp, mass, spl, area)
    with _on(device):
        if study is not None and _is_router(model):
            return _router_study(model, data, study, mc, clips, protocol, trim, progress)
        if study is not None or clips is not None:
            setup = _device_setup(model, data, study, realisation, budget, clips, protocol)
            if isinstance(study, dv.Spread) and trim is not None:
                return _trimmed(setup, model, data, trim, protocol, mc, study, scheduler,
                                jobs, progress)
            if isinstance(study, dv.Spread):
                return dv.evaluate_spread(setup, mc, study, scheduler=scheduler, jobs=jobs,
                                          progress=progress)
            return dv.evaluate_physical(setup, study, scheduler=scheduler, jobs=jobs)
        if _is_router(model) and realisation in (None, "router"):
            from springc.kws.evaluation.router import evaluate_model

            return evaluate_model(model, data, protocol, jobs, use_cache)
        return evaluate_split(model, data, realisation, jobs=jobs, use_cache=use_cache,
                              scheduler=scheduler, protocol=protocol)


def _is_router(model: Path) -> bool:
    from springc.kws.training.model import load_model

    return load_model(model).settings.get("realisation") == "router"


def _router_study(model: Path, data: Path | None, study, devices: int | None,
                  clips: int | None, protocol: str | None, trim: int | None,
                  progress: Progress) -> dict:
    """A device study of a router model (`springc.kws.evaluation.router`)."""
    from springc.kws.evaluation import device as dv, router
    from springc.kws.training.model import load_model

    if trim is not None:
        raise UsageError("--trim retunes a mass-spring network's readouts; a router has none "
                         "to trim")
    m = load_model(model)
    signals, y = dv.split_signals(m, data, clips, protocol, "test")
    if isinstance(study, dv.Spread):
        return router.population(m, signals, y, devices, study, progress)
    return router.physical(m, signals, y, study)


def _trim_allowed(clips: int, budget: int | None, devices: int | None) -> None:
    """UsageError for `trim` where it does not go: without a population, or too few clips."""
    if budget or devices is None:
        raise UsageError("--trim trims fabricated devices", hint="give it with --mc and --spread")
    if clips < 2:
        raise UsageError(f"--trim must measure at least 2 clips, not {clips}")


def _trimmed(setup, model: Path, data: Path | None, clips: int, protocol: str | None,
             devices: int, spread, scheduler, jobs: int, progress: Progress) -> dict:
    """`trim.evaluate_trimmed` of `devices` devices trimmed on `clips` validation clips."""
    from springc.kws.evaluation import trim as tr

    cal = tr.calibration_setup(setup, model, data, clips, protocol)
    return tr.evaluate_trimmed(setup, cal, devices, spread, scheduler=scheduler, jobs=jobs,
                               progress=progress)


def recorded_scale(model: Path, given: dict) -> dict:
    """`given` (spl, area, temp, device_mass, mass; None where not given) with what is not
    given taken from the physical scale a device model recorded (settings.json's "device",
    `train --realisation device`); a model that recorded none, or a `mass` per unit given,
    leaves the rest to `energy.DEFAULTS`."""
    path = model / "settings.json"
    try:
        recorded = json.loads(path.read_text()).get("device") or {} if path.is_file() else {}
    except (OSError, ValueError, AttributeError) as exc:
        raise DataError(str(path), f"is not a model's settings ({exc})") from None
    if given.get("mass") is not None:
        recorded = {k: v for k, v in recorded.items() if k != "device_mass"}
    return {k: recorded.get(k) if v is None and k != "mass" else v for k, v in given.items()}


def _budget(model: Path, data: Path | None, clips: int, protocol: str | None, mc, spread,
            given_clips, scale: dict) -> dict:
    """`energy.physical_budget` of the first `clips` test clips at the scale `scale` gives."""
    from springc.kws.evaluation import energy
    from springc.kws.evaluation.evaluate import budget_signals

    if mc is not None or spread is not None or given_clips is not None:
        raise UsageError("--budget is a study of its own; drop --mc/--spread/--clips",
                         hint="--budget N takes the first N test clips")
    signals = budget_signals(model, data, clips, protocol)
    return energy.physical_budget(model, signals, energy.Scale.of(**scale))


def _device_setup(model: Path, data: Path | None, study, realisation: str | None,
                  budget: int | None, clips: int | None, protocol: str | None):
    """The shared setup of a device study (`device.load_setup`), after refusing options
    that do not go with one."""
    from springc.kws.evaluation import device as dv

    if study is None or budget:
        raise UsageError("--clips goes with --mc or --temp" if study is None else
                         "--budget is a study of its own; drop --mc/--temp or --budget")
    if realisation not in (None, "mass-spring"):
        raise UsageError("a device is a mass-spring network: --realisation mass-spring")
    return dv.load_setup(model, data, clips, protocol)


def cross_validate(data: str | Path, out: str | Path | None = None, *, bins: int = 8,
                   delays: int = 3, realisations: str | Sequence[str] | None = None,
                   folds: int = 5, threshold: float | None = None, jobs: int = 0,
                   seed: int = 0, use_cache: bool = True, tolerance: float = 1e-3,
                   paper_steps: bool = False, scheduler: str | None = None,
                   device: str | None = None, progress: Progress = None) -> dict:
    """Speaker-grouped cross-validation (12 classes) on every clip of `data`, as `springc
    cv`: `realisations` compared, the first as the reference (None: digital, mass-spring;
    `--realisation` repeated), `folds` speaker-disjoint folds; `bins`, `delays`,
    `threshold`, `jobs`, `seed`, `use_cache`, `tolerance`, `paper_steps`, `scheduler`,
    `device` as for `train`. Writes cv.json and cv.png into the folder `out` (None: nothing
    written). Returns the report cv.json holds: clips, fold_sizes and per realisation its
    balanced and plain accuracy, bootstrap standard errors and C per fold; per later
    realisation its paired difference from the first."""
    from springc.kws.evaluation import crossval

    chosen = (realisations,) if isinstance(realisations, str) else tuple(realisations or ())
    settings = FeatureSettings(bins=bins, delays=delays)
    opts = crossval.CVOptions(data=Path(data), settings=settings,
                              realisations=chosen or crossval.REALISATIONS, folds=folds,
                              seed=seed, jobs=jobs, use_cache=use_cache, scheduler=scheduler,
                              massspring=_massspring(settings, threshold),
                              tolerance=_tolerance(tolerance, paper_steps))
    with _on(device):
        report = crossval.cross_validate(opts, progress)
    if out is not None:
        crossval.write(report, Path(out))
    return report


def synthesise(out: str | Path, *, clips: int = 2400, seed: int = 0, jobs: int = 0,
               words: Sequence[str] | None = None,
               engines: Sequence[str] = ("espeak", "flite", "festival")) -> Path:
    """Write a GSCD-layout corpus of `clips` clips into the new folder `out` from the
    installed text-to-speech `engines`, as `springc data synth`: `words` a subset of the 35
    GSCD words (None: all), `seed` of every random choice, `jobs` worker processes (0: all
    cores). Returns the corpus folder."""
    from springc.kws.data.dataset import WORDS
    from springc.kws.data.synth import synthesise as run

    report = run(out, clips=clips, seed=seed, jobs=jobs,
                 words=tuple(words) if words else WORDS, engines=tuple(engines))
    return report.out


def _design(realisation: str, epsilon: float | None, heads: str | None, buffer,
            mvm_stiffness: float | None, scale: dict):
    """(transfer.Design or None for the epsilon's default, the physical scale of a device or
    router model or None) of `train`'s options; UsageError for head options on another
    realisation."""
    from springc.kws.training import tapbuffer, transfer

    device = realisation == "device"
    given = heads is not None or buffer is not None or mvm_stiffness is not None
    if not device and realisation != "mass-spring" and (given or epsilon is not None):
        raise UsageError("--heads, --buffer, --mvm-stiffness and --epsilon build mass-spring "
                         "heads", hint="--realisation mass-spring or device")
    scaled = device or realisation == "router"  # the models meant to be built
    if not scaled and any(v is not None for v in scale.values()):
        raise UsageError("--spl, --area, --temp and --device-mass describe a device model",
                         hint="--realisation device or router")
    physical = None
    if scaled:
        from springc.kws.evaluation.energy import Scale

        s = Scale.of(**scale)
        physical = {"spl": s.spl, "area": s.area, "temp": s.temp,
                    "device_mass": s.device_mass}
    if not (given or device):
        return None, physical
    base = transfer.default_design(epsilon or transfer.DEFAULT_EPSILON)
    kind = heads or ("summing" if device else base.heads)
    if kind == "summing":
        # a buffer holds the zero modes of the multipliers; the summing nodes hold themselves
        if buffer is not None or mvm_stiffness is not None:
            raise UsageError("--buffer and --mvm-stiffness build zero-mode heads; summing "
                             "heads have neither", hint="--heads zero-mode")
        return transfer.Design(kind, None, 1.0), physical
    return transfer.Design(
        kind, tapbuffer.TapBuffer(*buffer) if buffer is not None else base.buffer,
        float(mvm_stiffness) if mvm_stiffness is not None else base.mvm_stiffness), physical


def _balance(class_weights: str | None) -> bool | None:
    """TrainOptions.balance_weights of `--class-weights` (None: the task's default)."""
    if class_weights not in (None, "balanced", "none"):
        raise UsageError(f"class weights {class_weights!r}: use balanced or none")
    return None if class_weights is None else class_weights == "balanced"


def _tolerance(tolerance: float, paper_steps: bool) -> float | None:
    """TrainOptions/CVOptions.tolerance: None for the paper's setting."""
    if not tolerance > 0:
        raise UsageError(f"--tolerance must be above 0, not {tolerance:g}")
    return None if paper_steps else tolerance


def _massspring(settings: FeatureSettings, threshold: float | None,
                stage_stiffness: float | None = None, squarer_range: float | None = None):
    """Mass-spring settings for `--threshold`, `--squarer-range` and `--stage-stiffness`, or
    None (the defaults) without any."""
    if threshold is None and stage_stiffness is None and squarer_range is None:
        return None
    from springc.kws.features.massspring import from_features, stage_scaled

    given = {"threshold": threshold, "squarer_range": squarer_range}
    s = from_features(settings, **{k: v for k, v in given.items() if v is not None})
    s.validate()
    return s if stage_stiffness is None else stage_scaled(s, stage_stiffness)


def _on(device: str | None):
    """Within `springc.default_device(device)`; no change where `device` is None."""
    if device is None:
        return contextlib.nullcontext()
    from springc.sim import gpu

    return gpu.default_device(device)


def load_model(folder: str | Path) -> Model:
    """The model folder `springc train -o FOLDER` wrote; a `DataError` naming the file for
    anything missing or inconsistent."""
    return Model(read_model(Path(folder)))


@dataclass
class Model:
    """A trained model: its `settings` (settings.json) and the classes it tells apart."""

    trained: TrainedModel

    @property
    def folder(self) -> Path:
        return self.trained.folder

    @property
    def settings(self) -> dict:
        return self.trained.settings

    @property
    def classes(self) -> list[str]:
        """Every class a decision can name, in the order the model lists them."""
        return list(dict.fromkeys(c for classes, _ in self.trained.models for c in classes))

    def classify(self, files: Sequence[str | Path], *, jobs: int = 0) -> list[dict]:
        """Per sound file (folders: their sound files) `{"file", "label", "scores"}`, the
        predicted label and every class's decision value, as `springc classify --json`."""
        return classify(self.folder, [Path(f) for f in files], jobs=jobs)

    def evaluate(self, data: str | Path | None = None, *, protocol: str | None = None,
                 jobs: int = 0, use_cache: bool = True) -> dict:
        """Accuracy, per-class counts and (mass-spring) the network's figures on the test
        split of `data` (default: the data set the model was trained on), as `springc eval
        --json`."""
        return evaluate(self.folder, data, protocol=protocol, jobs=jobs, use_cache=use_cache)
