"""Regenerate the golden files of the tests.

    python tests/regen_golden.py               # both groups
    python tests/regen_golden.py examples      # the example netlists only
    python tests/regen_golden.py references    # the DOP853 references only (about 2 min)

`examples`: the trajectories of the example netlists (`netlists/examples/*.spr`) in
`tests/golden/<example>.npz` (`t` and one array per probe, as `springc sim` writes them).
Examples that read `in(0)` get `golden_inputs`: a deterministic chirp. Run it only when a change
of the numbers is intended (a new integrator default, a corrected example), and say so in the
commit message; `tests/test_simulate.py::test_golden_trajectories` compares against these
files.

`references`: the scipy DOP853 trajectories of the integrator tests' filter networks
(`tests/filter_refs.py`), which `tests/test_golden_refs.py` checks for staleness. Run it when
that module's networks, inputs or tolerances change.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "netlists" / "examples"
GOLDEN = ROOT / "tests" / "golden"
MAX_SAMPLES = 2000  # recorded samples per probe: enough to see the dynamics, small on disk
MAX_SECONDS = 0.05  # stop time for examples driven by input signals


def golden_inputs(tstep: float, seconds: float) -> np.ndarray:
    """A linear chirp 100 Hz -> 4 kHz at amplitude 1e-3, shape (1, 1, samples) at 1/tstep."""
    t = np.arange(int(round(seconds / tstep)) + 1) * tstep
    phase = 2 * np.pi * (100 * t + 0.5 * (4000 - 100) / seconds * t**2)
    return 1e-3 * np.sin(phase)[None, None, :]


def simulate_example(path: Path):
    """Simulate one example with the golden settings: its own .tran and .options, inputs from
    `golden_inputs` if it reads any, outputs thinned to at most MAX_SAMPLES samples."""
    from springc.check import check
    from springc.lang import load_file
    from springc.sim.simulate import settings, simulate
    from springc.sim.sources import channels_used

    net = load_file(path)
    tstop = min(net.tran.tstop, MAX_SECONDS) if channels_used(net) else net.tran.tstop
    inputs = golden_inputs(net.tran.tstep, tstop) if channels_used(net) else None
    st = settings(net, tstop=tstop)
    every = max(1, math.ceil(st.nsteps / MAX_SAMPLES))
    return simulate(check(net), inputs, tstop=tstop, outrate=1.0 / (every * st.h))


def examples() -> None:
    """Write the example netlists' golden trajectories."""
    for path in sorted(EXAMPLES.glob("*.spr")):
        res = simulate_example(path)
        out = GOLDEN / f"{path.stem}.npz"
        np.savez_compressed(out, t=res.t, **{k: v for k, v in res.probes.items()})
        print(f"{out.relative_to(ROOT)}: {len(res.t)} samples, probes {list(res.probes)}",
              file=sys.stderr)


def references() -> None:
    """Write the DOP853 references of `filter_refs.REFERENCES`."""
    import filter_refs

    for name in filter_refs.REFERENCES:
        out = filter_refs.save(name)
        print(f"{out.relative_to(ROOT)}: {filter_refs.REFERENCES[name]}", file=sys.stderr)


def main(groups: list[str]) -> None:
    GOLDEN.mkdir(exist_ok=True)
    known = {"examples": examples, "references": references}
    for group in groups or list(known):
        if group not in known:
            sys.exit(f"regen_golden.py: unknown group {group!r} (choose from {', '.join(known)})")
        known[group]()


if __name__ == "__main__":
    main(sys.argv[1:])
