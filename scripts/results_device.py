"""The keyword spotter as a device: today's mass-spring design (zero-mode heads) beside the
device design (summing heads, `springc train --realisation device`) and the router (a linear
passive network) under fabrication spread, thermal noise at physical scale, and the energy
budget against the 53 dB a decision may lose.

    python scripts/results_device.py run --data CORPUS --out DIR [--sizes 4x2 8x3]
    python scripts/results_device.py page --out DIR --md docs/results-device.md
    python scripts/results_device.py cv --data CORPUS --out DIR [--folds 3] [--designs ...]
    python scripts/results_device.py stiffness --data CORPUS --out DIR [--factors 1 10 100]
        [--sizes 4x2] [--epsilon EPS] [--threshold A_C] [--squarer-range R]
        [--masses KG ...] [--spreads S ...]
    python scripts/results_device.py stiffness-page
    python scripts/results_device.py trim-page [--reports SIZE=REPORT.json ...]
    python scripts/results_device.py router --data CORPUS --out DIR [--bins 8 16]
    python scripts/results_device.py router-page

`run` trains both designs per size on CORPUS (skipped where DIR holds the model), and
through `springc.evaluate` measures the whole network's accuracy on the test split, the
population of --devices devices at each --spreads (on --clips test clips), the device with
thermal noise at each --masses (kg, 300 K, 60 dB SPL, 1 mm^2) and the budget of --budget
clips; and the 8x3 mass-spring network trained at --epsilon 1 (the buffered design) beside
1e-6. With --leave-out ENGINE, the same two 8x3 networks trained on a corpus without that
text-to-speech engine and tested on their own split and on a corpus of that engine alone
(voices no model heard). Results go to DIR/results.json as they come. `page` writes the
markdown and the plot. `cv` cross-validates the 8x3 designs over speakers: per fold of
`springc.kws.evaluation.crossval.write_fold_views` both trained and their whole networks
evaluated on the fold's test split, the summing design's devices at a 1e-3 spread too
(DIR/cv.json, and a table printed); --designs adds summing-stiff, the device design with
the stiffness study's levers. `stiffness` trains the device design at each stage
stiffness of --factors (`springc train --stage-stiffness`; heads at --epsilon, compression
from --threshold, squarers of --squarer-range) and records its accuracy and budget, and
where asked its thermal noise at --masses and its population at --spreads (the models in
DIR/models, the rows in --store, docs/results-stiffness.json, then docs/results-stiffness.md
written from them; `stiffness-page` writes that page alone from the stored rows).
`trim-page` writes docs/results-trim.md from its rows in docs/results-trim.json, after
adding or replacing the rows of the given `springc eval MODEL --mc N --spread S [--trim K |
--stage X] --json` reports (SIZE: the model's, e.g. 8x3). `router` trains a router of
each --bins filters (`springc train --realisation router`) and measures it as `run` measures
a design, on every test clip (the rows in --store, docs/results-router.json); `router-page`
prints their table and draws the front, docs/results-router.png, beside the 8x3 squaring
designs of docs/results-stiffness.json.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import springc
from springc.kws.features.massspring import SQUARER_RANGE

DESIGNS = {"zero-mode": "mass-spring", "summing": "device"}
# What `cv` can train, by name: `springc train` options. summing-stiff: the device design
# with the stiffness study's levers that kept its accuracy (docs/results-device.md).
CV_DESIGNS = {"zero-mode": {"realisation": "mass-spring"},
              "summing": {"realisation": "device"},
              "summing-stiff": {"realisation": "device", "stage_stiffness": 1e4,
                                "squarer_range": 1.0, "epsilon": 0.01},
              "router": {"realisation": "router", "bins": 16}}
SPREADS = (1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 3e-2)
MASSES = (1e-40, 1e-36, 1e-30, 1e-20, 1e-10)


def stored(path: Path, default):
    """The JSON stored at `path`, or `default` where there is none yet."""
    return json.loads(path.read_text()) if path.exists() else default


def model(out: Path, data: Path, size: str, realisation: str, epsilon=None) -> Path:
    """The model folder of one design and size, trained on `data` unless it is there."""
    n, m = (int(v) for v in size.split("x"))
    tag = f"{realisation}-{size}" + (f"-eps{epsilon:g}" if epsilon else "")
    folder = out / "models" / tag
    if not (folder / "settings.json").exists():
        springc.train(data, folder, bins=n, delays=m, realisation=realisation,
                      epsilon=epsilon)
    return folder


def measure(folder: Path, args) -> dict:
    """Nominal accuracy, the spread sweep, the noise sweep and the budget of one model."""
    nominal = springc.evaluate(folder)
    row = {"accuracy": nominal["accuracy"], "ideal": nominal["digital_same_model"]["accuracy"],
           "n": nominal["n"], "loss_db": nominal["insertion_loss_db"]["median"]}
    row["spread"] = [_spread(folder, s, args) for s in args.spreads]
    row["noise"] = [_noise(folder, mass, args) for mass in args.masses]
    from springc.kws.evaluation.energy import budget_json

    row["budget"] = budget_json(springc.evaluate(folder, budget=args.budget))
    row["train_s"] = train_seconds(folder)
    return row


def train_seconds(folder: Path) -> float:
    """The training's stages, summed from the model's report (seconds)."""
    return float(sum(json.loads((folder / "report.json").read_text())["seconds"].values()))


def _spread(folder: Path, spread: float, args) -> dict:
    rep = springc.evaluate(folder, mc=args.devices, spread=spread, clips=args.clips)
    return {"spread": spread, "nominal": rep["nominal"], **rep["accuracy"]}


def _noise(folder: Path, mass: float, args) -> dict:
    rep = springc.evaluate(folder, temp=300.0, device_mass=mass, spl=60.0, area=1e-6,
                           clips=args.clips)
    return {"device_mass": mass, "accuracy": rep["accuracy"], "noiseless": rep["noiseless"],
            "decision_error": rep["decision_error"], "diverged": bool(rep.get("diverged")),
            "calibrated": (rep.get("calibrated") or {}).get("accuracy")}


WORDS = "yes,no,up,down,left,right,on,off,stop,go,one,two,three,four"
ENGINES = ("espeak", "flite", "festival")


def synth(folder: Path, clips: int, engines: list[str], seed: int) -> Path:
    """A built-in corpus of `engines` in `folder` (kept if there)."""
    if not folder.exists():
        springc.synthesise(folder, clips=clips, seed=seed, words=WORDS.split(","),
                           engines=engines)
    return folder


def unheard(out: Path, engine: str, clips: int) -> dict:
    """The 8x3 mass-spring network at eps 1e-6 and 1 trained without `engine`: accuracy on
    its own test split and on every clip of a corpus of `engine` alone."""
    train = synth(out / f"without-{engine}", clips, [e for e in ENGINES if e != engine], 1)
    alone = synth(out / f"only-{engine}", clips // 4, [engine], 2)
    for name in ("testing_list.txt", "validation_list.txt"):  # every clip a test clip
        (alone / name).unlink(missing_ok=True)
    rows = {}
    for eps in (1e-6, 1.0):
        folder = out / "models" / f"mass-spring-8x3-eps{eps:g}-without-{engine}"
        if not (folder / "settings.json").exists():
            springc.train(train, folder, bins=8, delays=3, realisation="mass-spring",
                          epsilon=eps)
        own, left = springc.evaluate(folder), springc.evaluate(folder, data=alone)
        rows[f"eps {eps:g}"] = {"own": own["accuracy"], "own_n": own["n"],
                                "unheard": left["accuracy"], "unheard_n": left["n"],
                                "loss_db": own["insertion_loss_db"]["median"]}
    return rows


def run(args) -> None:
    out = Path(args.out)
    path = out / "results.json"
    results = stored(path, {})
    for size in args.sizes:
        for design, realisation in DESIGNS.items():
            key = f"{size} {design}"
            if key in results:
                continue
            start = time.perf_counter()
            results[key] = measure(model(out, Path(args.data), size, realisation), args)
            results[key]["seconds"] = time.perf_counter() - start
            path.write_text(json.dumps(results, indent=1))
            print(f"{key}: {results[key]['accuracy']:.3f} in {results[key]['seconds']:.0f} s")
    for eps in (1e-6, 1.0):
        key = f"8x3 zero-mode eps {eps:g}"
        if key not in results:
            rep = springc.evaluate(model(out, Path(args.data), "8x3", "mass-spring", eps))
            results[key] = {"accuracy": rep["accuracy"], "n": rep["n"],
                            "loss_db": rep["insertion_loss_db"]["median"]}
            path.write_text(json.dumps(results, indent=1))
    if args.leave_out and "unheard" not in results:
        results["unheard"] = {"engine": args.leave_out,
                              **unheard(out, args.leave_out, args.voice_clips)}
        path.write_text(json.dumps(results, indent=1))


def cv(args) -> None:
    from springc.kws.evaluation.crossval import write_fold_views
    from springc.kws.evaluation.device_page import cv_rows

    out = Path(args.out)
    path = out / "cv.json"
    results = stored(path, {})
    for k, view in enumerate(write_fold_views(Path(args.data), args.folds, out / "views")):
        for design in args.designs:
            key = f"fold{k} {design}"
            if key not in results:
                results[key] = _fold_row(view, out / "models" / f"cv-{key.replace(' ', '-')}",
                                         CV_DESIGNS[design], args)
                path.write_text(json.dumps(results, indent=1))
                print(key, results[key], flush=True)
    print("\n".join(cv_rows(results)))


def _fold_row(view: Path, folder: Path, options: dict, args) -> dict:
    """One fold of one design (`springc.train` `options`): trained on the view, its whole
    network on the test split (and, for a device, `args.devices` devices at a 1e-3 spread
    on `args.clips`)."""
    start = time.perf_counter()
    if not (folder / "settings.json").exists():
        springc.train(view, folder, **{"bins": 8, "delays": 3, **options})
    rep = springc.evaluate(folder)
    row = {"accuracy": rep["accuracy"], "n": rep["n"],
           "loss_db": rep["insertion_loss_db"]["median"]}
    if options["realisation"] in ("device", "router"):
        row["spread"] = _spread(folder, 1e-3, args)
    row["seconds"] = time.perf_counter() - start
    return row


def stiffness(args) -> None:
    """The device design at each stage stiffness (`springc train --stage-stiffness`): its
    whole network's accuracy and its budget, per size, into --store, then the page."""
    from springc.kws.evaluation.stiffness_page import stiffness_rows

    out, path = Path(args.out), Path(args.store)
    results = stored(path, {})
    for size in args.sizes:
        for factor in args.factors:
            tag = (f"{size}-stiffness{factor:g}" + (f"-eps{args.epsilon:g}" if args.epsilon else "")
                   + (f"-threshold{args.threshold:g}" if args.threshold else "")
                   + (f"-range{args.squarer_range:g}" if args.squarer_range else ""))
            folder = out / "models" / f"device-{tag}"
            if tag not in results:
                results[tag] = _stiffness_row(folder, size, factor, args)
            _stiffness_studies(results[tag], folder, args)
            path.write_text(json.dumps(results, indent=1))
            print(tag, results[tag]["accuracy"], flush=True)
    print("\n".join(stiffness_rows(results)))
    stiffness_page(args)


def stiffness_page(args) -> None:
    """docs/results-stiffness.md (--md) from the stored rows (--store) and, where it is
    beside them, the speaker folds of `cv --designs summing summing-stiff` (--store's name
    with -cv: docs/results-stiffness-cv.json, a copy of that run's DIR/cv.json)."""
    from springc.kws.evaluation.stiffness_page import write_page

    cv_json = Path(args.store).with_name(Path(args.store).stem + "-cv.json")
    write_page(json.loads(Path(args.store).read_text()), Path(args.md),
               cv=stored(cv_json, None))


def trim_page(args) -> None:
    """docs/results-trim.md (--md) from the stored rows (--store), with the rows of
    --reports SIZE=PATH (`eval --mc --json` outputs, with --trim or --stage) added first, a
    row per size, spread, stage and trim."""
    from springc.kws.evaluation.trim_page import row, write_page

    def key(r: dict) -> tuple:
        return r["size"], r["spread"], r["stage"], "trimmed" in r

    rows = {key(r): r for r in stored(Path(args.store), [])}
    for item in args.reports:
        size, path = item.split("=", 1)
        r = row(size, json.loads(Path(path).read_text().splitlines()[-1]))
        rows[key(r)] = r
    Path(args.store).write_text(json.dumps(list(rows.values()), indent=1) + "\n")
    write_page(list(rows.values()), Path(args.md))


def router(args) -> None:
    """Routers of --bins filters (`springc train --realisation router`) on CORPUS, each
    measured as `measure` measures a design (every test clip unless --clips), into --store,
    then their table and the front's plot."""
    out, path = Path(args.out), Path(args.store)
    results = stored(path, {})
    for bins in args.bins:
        folder = out / "models" / f"router-{bins}"
        if not (folder / "settings.json").exists():
            springc.train(Path(args.data), folder, bins=bins, realisation="router")
        if f"{bins} bins" not in results:
            results[f"{bins} bins"] = measure(folder, args)
            path.write_text(json.dumps(results, indent=1))
    router_page(args)


def router_page(args) -> None:
    """The routers' table (printed) and docs/results-router.png (--png): the routers of
    --store beside the 8x3 squaring designs of docs/results-stiffness.json."""
    from springc.kws.evaluation.router_page import front_plot, router_rows

    routers = json.loads(Path(args.store).read_text())
    squaring = {f"8x3 S {r['factor']:g}": r for r in
                json.loads(Path(args.stiffness).read_text()).values() if r["size"] == "8x3"}
    print("\n".join(router_rows(routers)))
    front_plot(routers, squaring, Path(args.png))


def _stiffness_studies(row: dict, folder: Path, args) -> None:
    """The noise study at --masses and the population at --spreads, where asked and not
    yet in `row`."""
    if args.masses and "noise" not in row:
        row["noise"] = [_noise(folder, mass, args) for mass in args.masses]
    if args.spreads and "spread" not in row:
        row["spread"] = [_spread(folder, spread, args) for spread in args.spreads]


def _stiffness_row(folder: Path, size: str, factor: float, args) -> dict:
    """One device model of `stiffness`: trained unless `folder` holds it, then measured."""
    from springc.kws.evaluation.energy import budget_json

    start = time.perf_counter()
    if not (folder / "settings.json").exists():
        n, m = (int(v) for v in size.split("x"))
        springc.train(args.data, folder, bins=n, delays=m, realisation="device",
                      stage_stiffness=factor, epsilon=args.epsilon, threshold=args.threshold,
                      squarer_range=args.squarer_range)
    rep = springc.evaluate(folder)
    settings = json.loads((folder / "settings.json").read_text())
    return {"size": size, "factor": factor, "epsilon": settings["transfer"]["epsilon"],
            "threshold": settings["features"]["threshold"],
            "squarer_range": settings["features"].get("squarer_range", SQUARER_RANGE),
            "accuracy": rep["accuracy"],
            "n": rep["n"], "budget": budget_json(springc.evaluate(folder, budget=args.budget)),
            "seconds": time.perf_counter() - start}


def page(args) -> None:
    """The page from DIR's results.json (and cv.json where it is)."""
    from springc.kws.evaluation.device_page import write_page

    out = Path(args.out)
    cv_json = out / "cv.json"
    write_page(json.loads((out / "results.json").read_text()), Path(args.md),
               cv=stored(cv_json, None))


def _stiffness_options(st: argparse.ArgumentParser) -> None:
    """`stiffness`'s own options: the factors and the design's other levers."""
    st.add_argument("--factors", nargs="+", type=float, default=[1.0, 10.0, 100.0, 1000.0])
    for name in ("--epsilon", "--threshold", "--squarer-range"):
        st.add_argument(name, type=float, default=None)
    for name in ("--masses", "--spreads"):
        st.add_argument(name, nargs="+", type=float, default=[])


def _page_options(p, st, sp, tp) -> None:
    """Where `page`, `stiffness`, `stiffness-page` and `trim-page` keep rows and pages."""
    p.add_argument("--md", default="docs/results-device.md")
    for stored in (st, sp):
        stored.add_argument("--store", default="docs/results-stiffness.json")
        stored.add_argument("--md", default="docs/results-stiffness.md")
    tp.add_argument("--reports", nargs="*", default=[], metavar="SIZE=PATH")
    tp.add_argument("--store", default="docs/results-trim.json")
    tp.add_argument("--md", default="docs/results-trim.md")


def _router_options(ro: argparse.ArgumentParser, rp: argparse.ArgumentParser) -> None:
    """`router`'s and `router-page`'s options: what is measured, and where it is kept."""
    ro.add_argument("--data", required=True)
    ro.add_argument("--out", required=True)
    ro.add_argument("--bins", nargs="+", type=int, default=[16])
    ro.add_argument("--spreads", nargs="+", type=float, default=[1e-3, 1e-2, 3e-2])
    ro.add_argument("--masses", nargs="+", type=float,
                    default=[1e-6, 1e-7, 1e-8, 2e-9, 1e-10, 1e-12])
    ro.add_argument("--devices", type=int, default=4)
    ro.add_argument("--clips", type=int, default=None)
    ro.add_argument("--budget", type=int, default=8)
    for shown in (ro, rp):
        shown.add_argument("--store", default="docs/results-router.json")
        shown.add_argument("--stiffness", default="docs/results-stiffness.json")
        shown.add_argument("--png", default="docs/results-router.png")


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    names = ("run", "cv", "stiffness", "page", "stiffness-page", "trim-page", "router",
             "router-page")
    r, c, st, p, sp, tp, ro, rp = (sub.add_parser(name) for name in names)
    r.add_argument("--spreads", nargs="+", type=float, default=list(SPREADS))
    r.add_argument("--masses", nargs="+", type=float, default=list(MASSES))
    r.add_argument("--leave-out", choices=ENGINES, default="flite")
    r.add_argument("--voice-clips", type=int, default=1600)
    c.add_argument("--folds", type=int, default=3)
    c.add_argument("--designs", nargs="+", choices=list(CV_DESIGNS),
                   default=["zero-mode", "summing"])
    _stiffness_options(st)
    for sized in (r, st):
        sized.add_argument("--sizes", nargs="+", default=["4x2", "8x3"])
        sized.add_argument("--budget", type=int, default=8)
    for studied in (r, c, st):
        studied.add_argument("--data", required=True)
        studied.add_argument("--devices", type=int, default=4)
        studied.add_argument("--clips", type=int, default=48)
    _page_options(p, st, sp, tp)
    _router_options(ro, rp)
    for each in (r, c, st, p):
        each.add_argument("--out", required=True)
    return parser


def main() -> None:
    args = _parser().parse_args()
    {"run": run, "cv": cv, "stiffness": stiffness, "page": page,
     "stiffness-page": stiffness_page, "trim-page": trim_page, "router": router,
     "router-page": router_page}[args.command](args)


if __name__ == "__main__":
    main()
