"""Time elaborating and checking a Monte Carlo population, in this tree or in an older one.

    python scripts/population_checks.py [--masses 500] [--samples 256] [--tree DIR]
                                        [--save RESULTS.pkl]

The population is `springc bench --population`'s chain (`springc.bench.population`): its
`.mc` samples are elaborated (`Variation.point_set`) and checked (`check_points`, RK4), and
the wall time of each stage is printed per sample with the worst point. `--tree DIR` imports
springc from DIR instead of the installed tree, for a before/after pair on one machine:

    git archive COMMIT springc | tar -x -C /tmp/before
    python scripts/population_checks.py --tree /tmp/before --save before.pkl
    python scripts/population_checks.py --save after.pkl

`--save` writes every point's step limit, omega_max, eigenvalues, fastest mode and
diagnostics, so that two trees' results can be compared for equality.
"""

from __future__ import annotations

import argparse
import os
import pickle
import sys
import time


def _use_tree(tree: str) -> None:
    """Import springc from `tree`: drop the editable install's finder, put `tree` first."""
    sys.meta_path = [f for f in sys.meta_path
                     if "editable" not in str(getattr(f, "__module__", ""))]
    sys.path.insert(0, os.path.abspath(tree))


def _parser() -> argparse.ArgumentParser:
    """The command line: the population's size, the tree to import and the results file."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--masses", type=int, default=500)
    parser.add_argument("--samples", type=int, default=256)
    parser.add_argument("--tree", help="import springc from this folder")
    parser.add_argument("--save", help="write every point's check results here (pickle)")
    return parser


def main() -> None:
    args = _parser().parse_args()
    if args.tree:
        _use_tree(args.tree)
    import springc
    from springc.bench.population import population_text
    from springc.check.points import check_points, worst
    from springc.lang import parse, variation

    var = variation.read(parse(population_text(args.masses, args.samples), "population.spr"))
    start = time.perf_counter()
    points = var.point_set()
    elaborated = time.perf_counter()
    points = check_points(points, "rk4")
    checked = time.perf_counter()
    index = worst(points)
    result = points.checked[index]
    n = len(points)
    print(f"springc from {os.path.dirname(springc.__file__)}, load {os.getloadavg()[0]:.2f}")
    print(f"{args.masses} masses, {n} samples: elaborate {elaborated - start:.2f} s "
          f"({(elaborated - start) / n * 1e3:.1f} ms per sample), check "
          f"{checked - elaborated:.2f} s ({(checked - elaborated) / n * 1e3:.1f} ms per "
          f"sample), together {(checked - start) / n * 1e3:.1f} ms per sample; worst point "
          f"{index}: step limit {result.step.dt!r} s, omega_max {result.modes.omega_max!r}")
    if args.save:
        _save(args.save, points)


def _save(path: str, points) -> None:
    """Every point's step limit, omega_max, eigenvalues, fastest mode and diagnostics, pickled
    (two trees' files compare for equality)."""
    rows = [(r.step.dt, r.modes.omega_max, r.modes.eigenvalues.tobytes(),
             r.step.mode.describe(), [d.message for d in r.diagnostics])
            for r in points.checked]
    with open(path, "wb") as f:
        pickle.dump(rows, f)


if __name__ == "__main__":
    main()
