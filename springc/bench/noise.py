"""The cost of transient thermal noise: the wall time of a simulation with every damper's
noise force drawn (`.options temp=`, `springc.sim.thermal`) over the same simulation without
it, on the keyword-spotting feature network at 8x3 (`networks.pipeline_features`) by
default. The project's target is at most 1.5x.

Both kernels are compiled before the timing; the two simulations then alternate, `rounds`
times each, and the ratio is of their fastest rounds (the least disturbed by other work on
the machine).
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np

from springc.check import check
from springc.lang.ir import FlatNetlist
from springc.sim.simulate import simulate

RATE = 16000.0  # Hz: the feature network's input grid
TEMP = 300.0  # K


@dataclass(frozen=True)
class NoiseCost:
    """Fastest wall times (s) with and without noise, and their ratio."""

    network: str
    dofs: int
    dampers: int
    runs: int
    seconds: float
    method: str
    substeps: int
    noiseless_s: float
    noisy_s: float

    @property
    def ratio(self) -> float:
        return self.noisy_s / self.noiseless_s

    def as_dict(self) -> dict:
        return {**asdict(self), "ratio": self.ratio}


def measure(net: FlatNetlist | None = None, runs: int = 64, seconds: float = 0.25,
            method: str = "rk4", substeps: int = 4, rounds: int = 3,
            seed: int = 0) -> NoiseCost:
    """Time `runs` runs of `seconds` of white-noise input on `net` (None: the 8x3 feature
    network) at `TEMP` and without noise (`NoiseCost`; its `ratio` is the cost)."""
    if net is None:
        from springc.bench.networks import pipeline_features

        net = pipeline_features()
    checked = check(net)
    rng = np.random.default_rng(seed)
    u = 0.1 * rng.standard_normal((runs, 1, int(seconds * RATE) + 1))
    kw = dict(tstep=1 / RATE, tstop=seconds, method=method, substeps=substeps)
    walls: dict[float, list[float]] = {0.0: [], TEMP: []}
    for temp in walls:  # compile both kernels (those of `runs` runs) outside the timing
        simulate(checked, u, temp=temp, **{**kw, "tstop": min(seconds, 0.005)})
    for _ in range(rounds):
        for temp, times in walls.items():
            start = time.perf_counter()
            simulate(checked, u, temp=temp, **kw)
            times.append(time.perf_counter() - start)
    dampers = int((net.masses.b > 0).sum() + (net.dashpots.b > 0).sum())
    return NoiseCost(net.title, net.n, dampers, runs, seconds, method, substeps,
                     min(walls[0.0]), min(walls[TEMP]))


def cost_of_noise(net: FlatNetlist | None = None, **settings) -> float:
    """Noisy over noiseless wall time (`measure`)."""
    return measure(net, **settings).ratio
