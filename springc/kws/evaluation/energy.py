"""Where the input work goes in a mass-spring keyword spotter: the energy dissipated in each
stage of the classifier network (Mel filters, low-pass masses, delay lines, terminals, mvm
heads, readouts) against the work done by the input force, per clip.

The insertion loss of the paper's Fig. 8e-f (readouts over input work) is the last row; the
rows before it say which stage costs what. The balance closes: work in = energy dissipated in
all stages + mechanical energy left at the end (`check_balance`, a test).

At physical scale (`Scale`: a device of mass M kg hearing L dB SPL on a membrane of A m^2 at
T kelvin) the network is the normalised one in other units (`springc.design.scale`): every
mass times mu = M / (normalised mass), every displacement times lambda = p A / (mu g), g the
largest input gain, so every energy times mu lambda^2 = (p A / g)^2 / mu. The budget is then
also counted in k_B T and against the sound itself: p^2 / (rho c) A per second reaches the
membrane (about 1 pJ in a second at 60 dB SPL on 1 mm^2, 2.4e8 k_B T at 300 K), and a decision
among R readouts that each hold at least `FLOOR_KT` k_B T can lose at most
10 log10(p^2 A t / (rho c R FLOOR_KT k_B T)) dB of it (`Scale.bound_db`: 53 dB there).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from springc.lang.ir import FlatNetlist
from springc.check import check

# Stage of a mass element, by its flattened name (`springc.kws.features.massspring.front_end` and
# `springc.kws.training.transfer.head_text` name them).
STAGES: tuple[tuple[str, str], ...] = (
    ("Mel filters", r"^Xf\d+\."),
    ("low-pass masses", r"^Xlp\d+\."),
    ("compressors", r"^Xc\d+\."),
    ("delay lines", r"^Xd\d+_\d+\."),
    ("terminals", r"^Mf\d+_\d+$"),
    ("mvm heads", r"^Xh\d+\.(Xm\.|Ms)"),  # zero-mode multipliers or summing nodes
    ("readouts", r"^Xh\d+\.Xr\."),
    ("readouts", r"^Br[ab]\d+_"),  # a router's readout dashpots (`springc.kws.features.router`)
)


RHO_C = 413.3  # Pa s/m: characteristic impedance of air at 20 C (1.204 kg/m^3 x 343.2 m/s)
FLOOR_KT = 100.0  # k_B T each readout must hold for a decision above its thermal noise
DEFAULTS = dict(spl=60.0, area=1e-6, temp=300.0, device_mass=2e-9)  # 1 mm^2, 1 um silicon


@dataclass(frozen=True)
class Scale:
    """A budget's physical scale: the sound level (dB SPL re 20 uPa) on the membrane's area
    (m^2), the temperature (K), and the whole device's mass (kg) or, where `mass` is given,
    the kg of each normalised mass unit."""

    spl: float
    area: float
    temp: float
    device_mass: float | None = None
    mass: float | None = None

    @classmethod
    def of(cls, spl=None, area=None, temp=None, device_mass=None, mass=None) -> "Scale":
        """The scale the options give, `DEFAULTS` for the rest (no mass given: the default
        device mass); UsageError for both masses at once or a value out of range."""
        from springc.errors import UsageError

        if device_mass is not None and mass is not None:
            raise UsageError("--device-mass (the whole device) and --mass (kg per unit) say "
                             "the same thing: give one")
        if device_mass is None and mass is None:
            device_mass = DEFAULTS["device_mass"]
        given = dict(spl=spl, area=area, temp=temp)
        scale = cls(**{k: float(DEFAULTS[k] if v is None else v) for k, v in given.items()},
                    device_mass=device_mass, mass=mass)
        scale.validate()
        return scale

    def validate(self) -> None:
        """UsageError naming the option for a value out of range."""
        from springc.errors import UsageError

        for name, value in (("--device-mass", self.device_mass), ("--mass", self.mass),
                            ("--area", self.area), ("--temp", self.temp)):
            if value is not None and not (math.isfinite(value) and value > 0):
                raise UsageError(f"{name} must be a positive finite number, not {value:g}")
        if not math.isfinite(self.spl):
            raise UsageError(f"--spl must be a finite level in dB re 20 uPa, not {self.spl:g}")

    @property
    def pressure(self) -> float:
        """Pa: the RMS sound pressure."""
        from springc.design.scale import P_REF

        return P_REF * 10 ** (self.spl / 20)

    @property
    def kt(self) -> float:
        """J: k_B T."""
        from springc.sim.thermal import K_B

        return K_B * self.temp

    def joules(self, net: FlatNetlist) -> float:
        """J per normalised energy unit of `net`: (p A / g)^2 / mu (module docstring)."""
        driven = np.array([s.kind == "in" for s in net.forces.source], bool)
        gain = float(np.abs(net.forces.gain[driven]).max())
        return (self.pressure * self.area / gain) ** 2 / self.unit_mass(net)

    def unit_mass(self, net: FlatNetlist) -> float:
        """mu, kg per normalised mass unit of `net`."""
        return self.mass if self.mass is not None else self.device_mass / float(net.mass().sum())

    def sound(self, seconds: float) -> float:
        """J of sound on the membrane over `seconds`: p^2 / (rho c) A t."""
        return self.pressure**2 / RHO_C * self.area * seconds

    def bound_db(self, readouts: int, seconds: float) -> float:
        """The most a decision among `readouts` readouts of FLOOR_KT k_B T each can lose."""
        return 10 * math.log10(self.sound(seconds) / (readouts * FLOOR_KT * self.kt))


def physical_table(parts: dict[str, np.ndarray], joules: float, scale: Scale,
                   seconds: float, readouts: int) -> list[str]:
    """Markdown rows at physical scale: each stage's energy (J, k_B T) and its loss against
    the input work and against the sound on the membrane (dB, medians over the clips), then
    the sound, the bound and what each readout holds."""
    sound = scale.sound(seconds)
    work = parts["work in"]
    rows = ["| stage | energy (J, median) | k_B T | of the input work (dB) | of the sound (dB) |",
            "|---|---|---|---|---|"]
    for stage, e in parts.items():
        with np.errstate(divide="ignore"):
            db_work = 10 * np.log10(np.median(e / work))
            db_sound = 10 * np.log10(np.median(e) * joules / sound)
        j = np.median(e) * joules
        rows.append(f"| {stage} | {j:.3g} | {j / scale.kt:.3g} | {db_work:.1f} | "
                    f"{db_sound:.1f} |")
    each = np.median(parts.get("readouts", np.zeros(1))) * joules / readouts / scale.kt
    return rows + ["", f"sound on the membrane: {sound:.3g} J in {seconds:g} s "
                   f"({sound / scale.kt:.3g} k_B T at {scale.temp:g} K); a decision among "
                   f"{readouts} readouts of {FLOOR_KT:g} k_B T each may lose at most "
                   f"{scale.bound_db(readouts, seconds):.1f} dB of it",
                   f"each readout holds {each:.3g} k_B T (median clip), "
                   f"{10 * math.log10(max(each, 1e-300) / FLOOR_KT):.1f} dB from the "
                   f"{FLOOR_KT:g} k_B T it needs"]


def budget_json(report: dict) -> dict:
    """`physical_budget`'s report as plain numbers (medians over the clips): per stage J,
    k_B T and dB of the input work and of the sound; the scale, sound, bound, readouts."""
    work, kt, sound = report["stages"]["work in"], report["kt_j"], report["sound_j"]
    stages = {}
    for stage, e in report["stages"].items():
        with np.errstate(divide="ignore"):
            stages[stage] = {"j": float(np.median(e)), "kt": float(np.median(e) / kt),
                             "db_of_work": float(10 * np.log10(np.median(e / work))),
                             "db_of_sound": float(10 * np.log10(np.median(e) / sound))}
    return {"stages": stages, "scale": report["scale"], "sound_j": sound, "kt_j": kt,
            "bound_db": report["bound_db"], "readouts": report["readouts"],
            "seconds": report["seconds"]}


def stage_of(mass_name: str) -> str:
    """The stage a mass element belongs to ("other" if none matches)."""
    for stage, pattern in STAGES:
        if re.match(pattern, mass_name):
            return stage
    return "other"


def stage_dampers(net: FlatNetlist) -> dict[str, list[str]]:
    """{stage: names of its damped mass elements and dashpots} in STAGES order (empty
    stages left out)."""
    m, d = net.masses, net.dashpots
    damped = [m.names[e] for e in range(len(m)) if m.b[e] != 0]
    damped += [d.names[e] for e in range(len(d)) if d.b[e] != 0]
    groups: dict[str, list[str]] = {}
    for name in damped:
        groups.setdefault(stage_of(name), []).append(name)
    order = list(dict.fromkeys(s for s, _ in STAGES)) + ["other"]
    return {s: groups[s] for s in order if s in groups}


def budget_reductions(net: FlatNetlist) -> list[str]:
    """The reductions `budget` needs: input work, each damped mass, final energy."""
    names = [n for group in stage_dampers(net).values() for n in group]
    return ["work:in", "energy"] + [f"dissipated:{n}" for n in names]


def budget(net: FlatNetlist, reds: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """{stage: energy dissipated (J) per clip} plus "work in" and "left at the end"."""
    out = {"work in": reds["work:in"]}
    for stage, names in stage_dampers(net).items():
        out[stage] = sum(reds[f"dissipated:{n}"] for n in names)
    out["left at the end"] = reds["energy"]
    return out


def check_balance(parts: dict[str, np.ndarray]) -> np.ndarray:
    """Per clip: |work in - dissipated - left| / work in (zero up to the integrator's error)."""
    spent = sum(v for k, v in parts.items() if k != "work in")
    return np.abs(parts["work in"] - spent) / parts["work in"]


def budget_table(parts: dict[str, np.ndarray]) -> list[str]:
    """Markdown rows: stage, median energy (J), median share of the input work (dB)."""
    work = parts["work in"]
    rows = ["| stage | energy (J, median) | of the input work (dB, median) |", "|---|---|---|"]
    for stage, e in parts.items():
        with np.errstate(divide="ignore"):
            db = 10 * np.log10(np.median(e / work))
        rows.append(f"| {stage} | {np.median(e):.3g} | {db:.1f} |")
    return rows


def run_budget(net: FlatNetlist, signals: np.ndarray, tstop: float, *,
               substeps: int | None = None) -> dict[str, np.ndarray]:
    """Simulate `signals` (clips, samples) at the clips' 16 kHz through `net` (in float64)
    and return `budget`."""
    from springc.kws.features.massspring import INPUT_RATE
    from springc.sim.simulate import simulate

    sig = np.atleast_2d(np.asarray(signals, dtype=np.float64))[:, None, :]
    res = simulate(check(net), sig, INPUT_RATE, probes=[], reductions=budget_reductions(net),
                   tstop=tstop, batch=len(sig), substeps=substeps)
    return budget(net, res.reductions)


def model_budget(model_dir, signals: np.ndarray) -> dict[str, np.ndarray]:
    """The budget of a trained mass-spring model's whole classifier on `signals`."""
    from springc.kws.features import massspring as msp

    net, s = classifier_network(model_dir)
    return run_budget(net, signals, msp.horizon(s, signals.shape[-1] / msp.INPUT_RATE))


def model_network(model_dir, seconds: float) -> tuple[FlatNetlist, float]:
    """(a trained model's whole network, sound to decision: the mass-spring classifier or
    the router; the time it simulates for a clip of `seconds`)."""
    from springc.kws.features import massspring as msp
    from springc.kws.training.model import load_model

    if load_model(model_dir).settings.get("realisation") == "router":
        from springc.kws.features.router import RING_OUT
        from springc.lang import load_file

        return load_file(Path(model_dir) / "router.spr"), seconds + RING_OUT
    net, s = classifier_network(model_dir)
    return net, msp.horizon(s, seconds)


def readout_count(net: FlatNetlist) -> int:
    """The readouts of a classifier network (mass-spring heads or router dashpots)."""
    from springc.kws.features.router import READOUT

    heads = {n for n in net.masses.names if re.match(r"^Xh\d+\.Xr\.", n)}
    routed = {found.group(1) for n in net.dashpots.names if (found := READOUT.match(n))}
    return len(heads) + len(routed)


def classifier_network(model_dir):
    """(the whole classifier network of a trained mass-spring model, its feature settings)."""
    from springc.kws.training import transfer as tr
    from springc.kws.training.model import load_model
    from springc.lang import load_text

    model = load_model(model_dir)
    s, heads = tr.model_heads(model)
    text = tr.classifier_text(heads, s, design=tr.model_design(model))
    return load_text(text, f"{model_dir}/classifier (with heads)"), s


def physical_budget(model_dir, signals: np.ndarray, scale: Scale) -> dict:
    """`model_budget` at physical scale: {"stages": each stage's energy per clip in J,
    "normalised": the same in the network's units, "scale": the scale's settings, "sound_j",
    "kt_j", "bound_db", "readouts", "seconds"}; of a mass-spring or a router model."""
    from springc.kws.features import massspring as msp

    seconds = signals.shape[-1] / msp.INPUT_RATE
    net, tstop = model_network(model_dir, seconds)
    parts = run_budget(net, signals, tstop)
    joules = scale.joules(net)
    readouts = readout_count(net)
    return {"stages": {k: v * joules for k, v in parts.items()}, "normalised": parts,
            "scale": {"device_mass": scale.unit_mass(net) * float(net.mass().sum()),
                      "mass": scale.unit_mass(net), "spl": scale.spl, "area": scale.area,
                      "temp": scale.temp, "pressure": scale.pressure},
            "sound_j": scale.sound(seconds), "kt_j": scale.kt, "joules_per_unit": joules,
            "bound_db": scale.bound_db(readouts, seconds), "readouts": readouts,
            "seconds": seconds}

