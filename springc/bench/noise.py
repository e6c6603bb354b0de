"""`springc bench --noise`: the cost of transient thermal noise, the wall time of a simulation
with every damper's noise force drawn (`.options temp=`, `springc.sim.thermal`) over the same
simulation without it, on the keyword-spotting feature network at 8x3
(`networks.pipeline_features`) by default. The project's target is at most 1.5x.

Both kernels are compiled before the timing; the two simulations then alternate, `rounds`
times each, so that load from other work on the machine falls on both alike. The ratio is of
their fastest rounds (the least disturbed); the median of the rounds' own ratios (each
noisy call over the noiseless call before it) and the ratio of process CPU times are beside
it. Beside the cost, what the noise is: the generator's moments and its distance from
Box-Muller in numpy's functions on the same bits (`springc.kernels.thermal`), and
equipartition and the displacement PSD on a damped oscillator against `springc noise`.
Writes bench-noise.md and bench/noise.json.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from springc.check import check
from springc.lang.ir import FlatNetlist
from springc.sim.simulate import simulate

RATE = 16000.0  # Hz: the feature network's input grid
TEMP = 300.0  # K
COMMAND = "springc bench --noise --out docs"


@dataclass(frozen=True)
class NoiseCost:
    """Wall and CPU times (s) of each round with and without noise, and their ratios;
    `effect`: the RMS of the probes' noisy-minus-noiseless difference over their RMS."""

    network: str
    dofs: int
    dampers: int
    runs: int
    seconds: float
    method: str
    substeps: int
    noiseless_walls: tuple[float, ...]
    noisy_walls: tuple[float, ...]
    noiseless_cpu: tuple[float, ...]
    noisy_cpu: tuple[float, ...]
    effect: float

    @property
    def noiseless_s(self) -> float:
        return min(self.noiseless_walls)

    @property
    def noisy_s(self) -> float:
        return min(self.noisy_walls)

    @property
    def ratio(self) -> float:
        """Fastest noisy wall over fastest noiseless wall."""
        return self.noisy_s / self.noiseless_s

    @property
    def paired_ratio(self) -> float:
        """Median over the rounds of noisy wall over the noiseless wall just before it."""
        return float(np.median(np.divide(self.noisy_walls, self.noiseless_walls)))

    @property
    def cpu_ratio(self) -> float:
        """Least noisy process CPU time over the least noiseless one."""
        return min(self.noisy_cpu) / min(self.noiseless_cpu)

    def as_dict(self) -> dict:
        return {**asdict(self), "noiseless_s": self.noiseless_s, "noisy_s": self.noisy_s,
                "ratio": self.ratio, "paired_ratio": self.paired_ratio,
                "cpu_ratio": self.cpu_ratio}


def measure(net: FlatNetlist | None = None, runs: int = 64, seconds: float = 0.25,
            method: str = "rk4", substeps: int = 4, rounds: int = 3,
            seed: int = 0) -> NoiseCost:
    """Time `runs` runs of `seconds` of white-noise input on `net` (None: the 8x3 feature
    network) at `TEMP` and without noise, alternating (`NoiseCost`; its `ratio` is the
    cost)."""
    if net is None:
        from springc.bench.networks import pipeline_features

        net = pipeline_features()
    checked = check(net)
    rng = np.random.default_rng(seed)
    u = 0.1 * rng.standard_normal((runs, 1, int(seconds * RATE) + 1))
    kw = dict(tstep=1 / RATE, tstop=seconds, method=method, substeps=substeps)
    walls: dict[float, list[float]] = {0.0: [], TEMP: []}
    cpu: dict[float, list[float]] = {0.0: [], TEMP: []}
    for temp in walls:  # compile both kernels (those of `runs` runs) outside the timing
        simulate(checked, u, temp=temp, **{**kw, "tstop": min(seconds, 0.005)})
    probes = {}
    for _ in range(rounds):
        for temp in walls:
            start, start_cpu = time.perf_counter(), time.process_time()
            res = simulate(checked, u, temp=temp, **kw)
            walls[temp].append(time.perf_counter() - start)
            cpu[temp].append(time.process_time() - start_cpu)
            probes[temp] = np.stack([res.probes[k] for k in res.probes])
    quiet = float(np.mean(probes[0.0] ** 2))  # 0 without input: the effect is then inf
    diff = float(np.mean((probes[TEMP] - probes[0.0]) ** 2))
    effect = float(np.sqrt(diff / quiet)) if quiet > 0 else float("inf")
    dampers = int((net.masses.b > 0).sum() + (net.dashpots.b > 0).sum())
    return NoiseCost(net.title, net.n, dampers, runs, seconds, method, substeps,
                     tuple(walls[0.0]), tuple(walls[TEMP]), tuple(cpu[0.0]), tuple(cpu[TEMP]),
                     effect)


def cost_of_noise(net: FlatNetlist | None = None, **settings) -> float:
    """Noisy over noiseless wall time (`measure`)."""
    return measure(net, **settings).ratio


def draw_statistics(draws: int = 1 << 21) -> dict:
    """Moments of `draws` of the kernels' generator (seed 0, 1024 runs, one damper pair)
    with their standard errors for a standard normal, and the largest difference from
    Box-Muller in numpy's log, sqrt, sin and cos on the same bits."""
    from springc.kernels import thermal

    steps = draws // 2048
    r = thermal.counter_bits(0, np.arange(1024), [0, 1], np.arange(steps))
    odd = np.array([False, True])[None, :, None]
    z = thermal.box_muller(r, odd)
    exact = thermal.box_muller_libm(r, odd)
    n = z.size
    c = z - z.mean()
    return {"draws": n, "mean": float(z.mean()), "var": float(z.var()),
            "skew": float(np.mean(c**3) / z.var() ** 1.5),
            "kurtosis": float(np.mean(c**4) / z.var() ** 2),
            "se": {"mean": n**-0.5, "var": (2 / n) ** 0.5, "skew": (6 / n) ** 0.5,
                   "kurtosis": (24 / n) ** 0.5},
            "pair_corr": float(np.corrcoef(z[:, 0].ravel(), z[:, 1].ravel())[0, 1]),
            "max_vs_libm": float(np.abs(z - exact).max()),
            "max_abs": float(np.abs(z).max())}


def oscillator(runs: int = 256, tstop: float = 1000.0) -> dict:
    """Equipartition and the PSD of x on tests/test_thermal_noise.py's oscillator (m = k = b
    = k_B 300 K: omega_0 = 1 rad/s, Q = 1, x_rms = 1 m), RK4 at h = 0.05 s, after 20 s:
    mean k x^2 / 2 and m v^2 / 2 over k_B T / 2, and Welch's PSD against `springc noise`
    from 0.05 to 1 Hz (its worst bin)."""
    import scipy.signal

    import springc
    from springc.analyses.noise import K_B, noise

    kt = K_B * TEMP
    text = (f"M1 a m={kt!r} b={kt!r}\nK1 a k={kt!r}\n"
            ".options temp=300 seed=5 method=rk4 substeps=1\n.probe x(a)\n.probe v(a)\n")
    net = springc.load(text)
    h = 0.05
    res = simulate(net.checked, np.zeros((runs, 0, int(tstop / h) + 1)), tstep=h,
                   tstop=tstop)
    keep = res.t >= 20.0
    x, v = res.probes["x(a)"][:, keep], res.probes["v(a)"][:, keep]
    f, psd = scipy.signal.welch(x, fs=1 / h, nperseg=2048, axis=-1)
    band = (f >= 0.05) & (f <= 1.0)
    want = noise(net.checked, "a", f[band], TEMP).psd
    return {"runs": runs, "tstop": tstop, "h": h,
            "potential": float(np.mean(x**2)), "kinetic": float(np.mean(v**2)),
            "psd_worst": float(np.abs(psd.mean(axis=0)[band] / want - 1).max())}


def run_noise(runs: int = 64, seconds: float = 0.25, rounds: int = 7, osc_runs: int = 256,
              osc_tstop: float = 1000.0,
              progress: Callable[[str], None] = lambda m: None) -> dict:
    """Measure (see the module docstring); returns the numbers as a dict."""
    from springc.sim import execute

    out: dict = {"threads": execute.threads(), "load": os.getloadavg()[0]}
    cost = measure(runs=runs, seconds=seconds, rounds=rounds)
    out["cost"] = cost.as_dict()
    out["load_after_cost"] = os.getloadavg()[0]
    progress(f"noisy/noiseless {cost.ratio:.3f} (paired {cost.paired_ratio:.3f}, "
             f"CPU {cost.cpu_ratio:.3f})")
    out["draws"] = draw_statistics()
    progress("generator statistics done")
    out["oscillator"] = oscillator(osc_runs, osc_tstop)
    out["load_end"] = os.getloadavg()[0]
    return out


def markdown(r: dict) -> str:
    """The report page for `run_noise`'s numbers."""
    c, d, o = r["cost"], r["draws"], r["oscillator"]
    met = "met" if c["ratio"] <= 1.5 else "missed"
    walls = ", ".join(f"{a:.2f}/{b:.2f}" for a, b in zip(c["noiseless_walls"],
                                                          c["noisy_walls"]))
    load = r["load"]
    loaded = load is not None and load > r["threads"]
    return "\n".join([
        "# The cost of thermal noise",
        "",
        "| what | wall (s) | ratio |",
        "|---|---|---|",
        f"| {c['runs']} runs without noise | {c['noiseless_s']:.3f} | 1 |",
        f"| {c['runs']} runs at {TEMP:g} K, every damper's force drawn per step | "
        f"{c['noisy_s']:.3f} | **{c['ratio']:.2f}x** (target at most 1.5x: {met}) |",
        "",
        f"{c['network']} ({c['dofs']} masses, {c['dampers']} dampers: "
        "`springc.bench.networks.pipeline_features`), "
        f"{c['method']} x{c['substeps']} at {RATE:g} Hz input, {c['seconds']:g} s of white "
        "noise input per run, float64, its three probes recorded, "
        f"{r['threads']} threads. Compile excluded (a warm-up call compiles or loads each "
        f"kernel). The two simulations alternate, {len(c['noisy_walls'])} rounds each; the "
        "table's walls are each one's fastest round.",
        "",
        f"- Paired: the median over the rounds of the noisy wall over the noiseless wall just "
        f"before it is {c['paired_ratio']:.2f}x; process CPU time (both threads), fastest "
        f"rounds: {c['cpu_ratio']:.2f}x. Walls of each round, noiseless/noisy (s): {walls}.",
        f"- The noise is there: the probes' noisy-minus-noiseless RMS is "
        f"{c['effect']:.1e} of their RMS (the network in its normalised units; "
        "`springc design scale` gives a device its physical size).",
        f"- Generator ({d['draws']:,} draws, `springc.kernels.thermal.normals`): mean "
        f"{d['mean']:.1e} (standard error {d['se']['mean']:.0e}), variance {d['var']:.5f} "
        f"({d['se']['var']:.0e}), skewness {d['skew']:.1e} ({d['se']['skew']:.0e}), "
        f"kurtosis {d['kurtosis']:.4f} ({d['se']['kurtosis']:.0e}; a normal's is 3), "
        f"correlation of a pair's two draws {d['pair_corr']:.1e}, largest |z| "
        f"{d['max_abs']:.2f}; largest difference from Box-Muller in numpy's log, sqrt, "
        f"sin and cos on the same bits {d['max_vs_libm']:.1e}.",
        f"- Damped oscillator (omega_0 = 1 rad/s, Q = 1, {o['runs']} runs of "
        f"{o['tstop']:g} s, RK4 at h = {o['h']:g} s, after 20 s): mean k x^2 / 2 and "
        f"m v^2 / 2 are {o['potential']:.4f} and {o['kinetic']:.4f} of k_B T / 2 "
        "(target within 2%); Welch's PSD of x against `springc noise` from 0.05 to 1 Hz: "
        f"worst bin {100 * o['psd_worst']:.1f}% off (target 10%).",
        f"- Machine: {r['threads']} cores, shared; 1-minute load average "
        f"{load if load is not None else 'unknown'} when the measurement started, "
        f"{r['load_after_cost']} after the timing"
        + (" (ran under load: the walls are noisy; the alternation puts the load on both "
           "sides, and the paired and CPU ratios are its cross-checks)." if loaded else "."),
        "",
        f"Regenerate: `{COMMAND}` (writes this page and bench/noise.json).",
        "",
    ])


def write_report(result: dict, outdir: Path) -> dict[str, Path]:
    """Write OUT/bench-noise.md and OUT/bench/noise.json; returns their paths."""
    paths = {"md": outdir / "bench-noise.md", "json": outdir / "bench" / "noise.json"}
    paths["json"].parent.mkdir(parents=True, exist_ok=True)
    paths["md"].write_text(markdown(result))
    paths["json"].write_text(json.dumps(result, indent=1))
    return paths
