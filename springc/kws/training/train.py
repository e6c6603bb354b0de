"""Training the keyword spotter: features of every clip (in parallel, cached), a linear SVM
per task (`springc.kws.data.task`) with C chosen on the validation split, and a model folder with
weights and report.

Realisations: "digital" (the paper's architecture evaluated numerically, `digital` + `phi`),
"baseline" (log-Mel + logistic regression), "mass-spring" (features simulated by
`massspring`; the model folder also gets the classifier netlists of `transfer`), "router"
(a linear passive network, `router`: the filters' dissipated energies, an SVM without
intercept, and the network in the model folder's router.spr)."""

from __future__ import annotations

import itertools
import multiprocessing
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits
from tqdm import tqdm

from springc.version import __version__
from springc.errors import DataError, UsageError
from springc.kws.features import cache
from springc.kws.features.baseline import baseline_features, baseline_settings
from springc.kws.features.digital import FeatureSettings, features
from springc.kws.features.phi import phi_vector
from springc.kws.training.report import evaluate_fits
from springc.kws.training.svm import LOGREG_GRID, SVM_GRID, LinearModel, select
from springc.kws.data.task import (DIGITS, REALISATIONS, open_task_data, targets, task_counts,
                                   task_protocol, task_weights)

CHUNK = 8  # clips per work item: big enough for batched FFTs, small enough for memory
# the router's filter energies are simulated in one process, this many clips a kernel call:
# the kernel runs its clips on every core, and a process per core beside it would only
# load the kernel again in each and contend for the cores
ROUTER_CHUNK = 64


@dataclass
class TrainOptions:
    """Everything `springc train` needs."""

    data: Path
    out: Path
    settings: FeatureSettings = field(default_factory=FeatureSettings)
    realisation: str = "digital"
    task: str = "kws12"
    jobs: int = 0  # 0: all cores
    seed: int = 0
    use_cache: bool = True
    grid: tuple[float, ...] | None = None
    protocol: str | None = None  # held-out protocol, "lists" or "balanced"; None: task default
    balance_weights: bool | None = None  # class weights "balanced"; None: task default
    # mass-spring only: physical settings (default: from `settings`), the squaring error of
    # the classifier heads, and a Dask scheduler address (default: a local cluster)
    massspring: object = None
    integration: object = None  # what `tolerance` chose (`massspring.integrated`)
    epsilon: float | None = None
    scheduler: str | None = None
    # the error allowed on Phi and the readouts, which chooses the integrator
    # (`springc.kws.features.integration`); None: the paper's RK4 with 8 substeps
    tolerance: float | None = 1e-3
    # mass-spring only: how the heads are built (`transfer.Design`; None: `default_design` of
    # the epsilon) and, for a device model, its physical scale (spl, area, temp, device_mass)
    design: object = None
    device: dict | None = None


def check_realisation(realisation: str) -> None:
    """UsageError for realisations that cannot run (yet)."""
    if realisation not in REALISATIONS:
        raise UsageError(f"unknown realisation {realisation!r}; use one of {REALISATIONS}")


def feature_key(realisation: str, settings: FeatureSettings) -> dict:
    """The settings that determine a clip's feature vector (cache key, settings.json)."""
    if realisation == "baseline":
        return {"realisation": "baseline", **baseline_settings()}
    return {"realisation": realisation, **settings.to_dict()}


# -- parallel feature extraction ----------------------------------------------------------

_WORKER: dict = {}


def _init_worker(clips: list, realisation: str, settings_list: list, augment: bool,
                 seed: int, noise_files: list) -> None:
    from springc.kws.data.dataset import NoiseBank

    _WORKER.update(clips=clips, realisation=realisation, settings_list=settings_list,
                   augment=augment, seed=seed,
                   noise=NoiseBank(noise_files) if augment and noise_files else None)


def _init_pool_worker(*args) -> None:
    threadpool_limits(1)  # the processes are the parallelism; see svm.select
    _init_worker(*args)


def _work(span: tuple[int, int]) -> list[np.ndarray]:
    """Feature matrices (one per settings) for clips[span[0]:span[1]]."""
    from springc.kws.data.dataset import SAMPLE_RATE, _clip_rng, load_clip

    w = _WORKER
    clips = w["clips"][span[0]:span[1]]
    signals = np.stack([
        load_clip(c, augment=w["augment"], rng=_clip_rng(w["seed"], c.key()), noise=w["noise"])
        for c in clips])
    if w["realisation"] == "baseline":
        return [baseline_features(signals, SAMPLE_RATE).astype(np.float32)]
    if w["realisation"] == "router":
        from springc.kws.features.router import filter_energies

        return [filter_energies(signals, s) for s in w["settings_list"]]
    return _phi_for_all(signals, SAMPLE_RATE, w["settings_list"])


def _phi_for_all(signals: np.ndarray, rate: int, settings_list: list) -> list[np.ndarray]:
    """Phi for several settings that differ only in `delays`: the features x are causal, so
    the shorter horizons are prefixes of the longest and one filterbank pass serves all."""
    longest = max(settings_list, key=lambda s: s.delays)
    x = features(signals, rate, longest)
    out = []
    for s in settings_list:
        k = round((signals.shape[1] / rate + (s.delays - 1) * s.td) * s.feature_rate) + 1
        out.append(phi_vector(x[..., :k], s))
    return out


def _run(clips: list, realisation: str, settings_list: list, augment: bool, seed: int,
         noise_files: list, jobs: int, desc: str) -> list[np.ndarray]:
    chunk = ROUTER_CHUNK if realisation == "router" else CHUNK
    spans = [(i, min(i + chunk, len(clips))) for i in range(0, len(clips), chunk)]
    init = (clips, realisation, settings_list, augment, seed, noise_files)
    jobs = 1 if realisation == "router" else jobs or os.cpu_count() or 1
    bar = tqdm(total=len(clips), desc=desc, unit="clip", file=sys.stderr, leave=False,
               disable=None)
    parts = []
    with bar:
        if jobs == 1 or len(spans) == 1:
            _init_worker(*init)
            with threadpool_limits(1):
                for span in spans:
                    parts.append(_work(span))
                    bar.update(span[1] - span[0])
        else:
            ctx = multiprocessing.get_context("spawn" if sys.platform == "darwin" else "fork")
            with ctx.Pool(min(jobs, len(spans)), _init_pool_worker, init) as pool:
                for span, res in zip(spans, pool.imap(_work, spans)):
                    parts.append(res)
                    bar.update(span[1] - span[0])
    return [np.concatenate([p[i] for p in parts]) for i in range(len(parts[0]))]


def feature_matrices(clips: list, split: str, realisation: str,
                     settings_list: list[FeatureSettings], *, noise_files: list, seed: int = 0,
                     jobs: int = 0, use_cache: bool = True,
                     scheduler: str | None = None) -> list[np.ndarray]:
    """Feature matrices (clips, N) of `clips` for each settings in `settings_list` (which may
    differ only in `delays`), from the cache where present. Training clips are augmented
    (`load_clip(augment=True)` with a per-clip generator seeded from `seed`)."""
    if not clips:
        raise DataError(split, "the split holds no clips")
    if jobs < 0:
        raise UsageError(f"--jobs must be 0 (all cores) or positive (got {jobs})")
    augment = split == "train"
    fp = cache.fingerprint(clips)
    tag = seed if augment else None
    paths = [cache.entry_path(fp, split, feature_key(realisation, s), tag) for s in settings_list]
    found = [cache.load(p, len(clips)) if use_cache else None for p in paths]
    todo = [s for s, f in zip(settings_list, found) if f is None]
    if todo:
        if realisation == "mass-spring":  # simulated on Dask (springc.kws.features.distributed)
            from springc.kws.features.massspring import dataset_phi

            computed = iter([dataset_phi(clips, split, s, noise_files=noise_files, seed=seed,
                                         scheduler=scheduler, workers=jobs or None)
                             for s in todo])
        else:
            computed = iter(_run(clips, realisation, todo, augment, seed, noise_files, jobs,
                                 f"features {split}"))
        found = [f if f is not None else next(computed) for f in found]
        if use_cache:
            for p, f in zip(paths, found):
                cache.save(p, f)
    return found


# -- training -----------------------------------------------------------------------------

def split_features(ds, realisation: str, settings_list: list[FeatureSettings], *, seed: int,
                   jobs: int, use_cache: bool,
                   scheduler: str | None = None) -> dict[str, list[np.ndarray]]:
    """{split: [matrix per settings]} for train, validation and test."""
    return {split: feature_matrices(ds.split(split), split, realisation, settings_list,
                                    noise_files=ds.noise_files, seed=seed, jobs=jobs,
                                    use_cache=use_cache, scheduler=scheduler)
            for split in ("train", "validation", "test")}


def fit_task(x: dict[str, np.ndarray], y: dict[str, np.ndarray], task: str, kind: str,
             grid: tuple[float, ...], jobs: int = 1, balance_weights: bool | None = None,
             intercept: bool = True) -> list[tuple[tuple[str, ...], LinearModel, float, dict]]:
    """[(classes, model, C, validation scores)]: one multiclass model, or one per digit pair.
    `jobs` threads fit the regularisation grid concurrently; class weights "balanced" when
    `balance_weights` (None: the task's default, see `task_weights`); `intercept` False:
    the kws12 model decides without one (the router)."""
    class_weight = task_weights(task, balance_weights)
    if task == "kws12":
        model, c, scores = select(x["train"], y["train"], x["validation"], y["validation"],
                                  kind, grid, jobs, class_weight, intercept=intercept)
        return [(tuple(model.classes), model, c, scores)]
    fits = []
    for pair in itertools.combinations(DIGITS, 2):
        m = {s: np.isin(y[s], pair) for s in x}
        tr, va = m["train"], m["validation"]
        model, c, scores = select(x["train"][tr], y["train"][tr],
                                  x["validation"][va], y["validation"][va],
                                  kind, grid, jobs, class_weight)
        fits.append((pair, model, c, scores))
    return fits


def train(opts: TrainOptions) -> dict:
    """Train, evaluate on the test split and write the model folder. Returns the report,
    with the wall time of each phase ("seconds")."""
    check_realisation(opts.realisation)
    if opts.realisation in ("digital", "router"):
        opts.settings.validate(16000)
    if opts.realisation == "router" and opts.task != "kws12":
        raise UsageError("the router decides by the readout that dissipates most: it needs "
                         "the multiclass kws12 task", hint="--task kws12")
    if opts.realisation == "mass-spring":
        from springc.kws.features.massspring import physical_settings

        opts.massspring = physical_settings(opts.settings, opts.massspring)
    ds = open_task_data(opts.data, opts.task, opts.seed, opts.protocol)
    with _session(opts):  # the workers compile ahead during the choices (`integration`)
        return _train(opts, ds, Phases())


class Phases:
    """Wall seconds per named phase, in order."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self.start = time.perf_counter()

    def done(self, name: str) -> None:
        """The phase `name` ends now (it began where the previous one ended)."""
        now = time.perf_counter()
        self.seconds[name] = now - self.start
        self.start = now


def _train(opts: TrainOptions, ds, phases: Phases) -> dict:
    from springc.kws.training.model import write_model

    reference = None  # the mass-spring reference run on a sample: integration and heads
    if opts.realisation == "mass-spring":
        from springc.kws.features.massspring import integrated, reference_run, sample_signals
        from springc.kws.training.transfer import compile_ahead

        if opts.tolerance is not None:  # the classifier's choice runs in double precision
            compile_ahead(opts.massspring)
        opts.massspring, opts.integration, reference = integrated(
            opts.massspring, ds.split("train"), opts.tolerance)
        if reference is None:  # the paper's steps: the heads' amplitude still needs it
            reference = reference_run(sample_signals(ds.split("train")), opts.massspring)
        phases.done("integration of the features")
    feature_settings = _feature_settings(opts)
    feats = split_features(ds, opts.realisation, [feature_settings], seed=opts.seed,
                           jobs=opts.jobs, use_cache=opts.use_cache, scheduler=opts.scheduler)
    phases.done("features")
    x = {s: f[0] for s, f in feats.items()}
    y = {s: targets(ds.split(s), opts.task) for s in x}
    kind = "logreg" if opts.realisation == "baseline" else "svm"
    grid = opts.grid or (LOGREG_GRID if kind == "logreg" else SVM_GRID)
    fits = fit_task(x, y, opts.task, kind, grid, opts.jobs or os.cpu_count() or 1,
                    opts.balance_weights, intercept=opts.realisation != "router")
    report = evaluate_fits(fits, x["test"], y["test"], opts.task)
    phases.done("classifier fit")
    report.update(data_summary(opts, ds))
    settings = model_settings(opts, ds)
    if opts.integration is not None:
        settings["integration"] = report["integration"] = {"features":
                                                           opts.integration.to_dict()}
    extra = {}
    if opts.realisation == "mass-spring":  # the classifier netlists beside the weights
        from springc.kws.training.transfer import write_classifier

        extra = write_classifier(opts, fits, settings, reference)
        phases.done("classifier network")
    if opts.realisation == "router":
        from springc.kws.features.router import router_file

        extra = router_file(_feature_settings(opts), fits[0][1])
    report["seconds"] = phases.seconds
    write_model(opts.out, settings, fits, report, extra=extra)
    return report


def _feature_settings(opts: TrainOptions):
    """The settings the realisation's features follow (`feature_key`)."""
    if opts.realisation == "mass-spring":
        return opts.massspring
    if opts.realisation == "router":
        from springc.kws.features.router import RouterSettings

        s = opts.settings
        return RouterSettings(bins=s.bins, fmin=s.fmin, fmax=s.fmax)
    return opts.settings


def _session(opts: TrainOptions):
    """One Dask cluster for the three splits of a mass-spring run (none for the others)."""
    from contextlib import nullcontext

    from springc.kws.features.distributed import session

    if opts.realisation != "mass-spring":
        return nullcontext()
    return session(opts.scheduler, opts.jobs or None)


def data_summary(opts: TrainOptions, ds) -> dict:
    """What the report says about the data: protocol, class weights, counts per split."""
    return {"protocol": task_protocol(opts.task, opts.protocol),
            "class_weight": task_weights(opts.task, opts.balance_weights),
            "counts": task_counts(ds, opts.task)}


def model_settings(opts: TrainOptions, ds) -> dict:
    """Everything needed to reproduce the features and the training: settings.json."""
    return {
        "springc_version": __version__,
        "realisation": opts.realisation,
        "task": opts.task,
        "features": feature_key(opts.realisation, _feature_settings(opts)),
        "classifier": "logistic-regression" if opts.realisation == "baseline"
        else "linear-svm squared-hinge l2 primal one-vs-rest"
        + (" without intercept" if opts.realisation == "router" else ""),
        "class_weight": task_weights(opts.task, opts.balance_weights),
        "protocol": task_protocol(opts.task, opts.protocol),
        "seed": opts.seed,
        **({"device": dict(opts.device)} if opts.device else {}),
        "dataset": {"path": str(Path(opts.data).resolve()),
                    "fingerprint": {s: cache.fingerprint(ds.split(s))
                                    for s in ("train", "validation", "test")}},
    }
