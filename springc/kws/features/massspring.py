"""Mass-spring feature extraction (paper Sec. III.C, Fig. 7a): the SVM features Phi of a clip
computed by simulating the physical network, with the Gram sums taken in the kernel.

The network, per Mel bin i (all from the standard library, written out by `front_end`):

    in(0) -> melfilter  y{i}      fitted two-mode filter (`fit_melbank`), peak response 1
          -> Q (squarer) lp{i}    g/(2a_i) (y^2 - a_i lp)^2: the force g y^2 on lp (squaring);
                                  a_i puts the squarer's own compression at SQUARER_RANGE, far
                                  above any filter amplitude, so the filter stays linear
          -> lowpass lp{i}        critically damped, fc = 50 Hz, local stiffness klp: holds
                                  g <y^2> / klp, the squared envelope
          -> compressor c{i}      spring kq to a light mass with the Duffing spring l_i c^3:
                                  quasi-static below its resonance fq, c = lp below the
                                  threshold and (kq lp / l_i)^(1/3) above (cube root)
          -> fan-out into m delay lines (coupling kc), line j of base + j L sites of delay
             t_s = td / L each, coupled by kc to its terminal node f{i}_{j}: delays differ by
             exactly j td at low frequency.
The terminal node f{i}_{j} ends the line without reflection: the missing rest of the chain
would pull on the last site with kc (1 - e^{-iq}) x = (i w t_s kc - m_s w^2 / 2) x + O(q^3),
a dashpot t_s kc = sqrt(m_s kc) and a negative half site mass, so the terminal is half a site
(m_s / 2) with that dashpot (a full site with the dashpot reflects ~w t_s / 2, 3% at 5 Hz,
and the echo shifts the delays by ~5%, measured). In the full classifier
(`springc.kws.training.transfer`) the same mass and damping come from the mvm heads instead, so the
features there equal the ones computed here.

Compression: c = (kq lp / l)^(1/3) ~ (y^2)^(1/3) = |y|^(2/3) above the threshold, the digital
realisation's law (paper Fig. 5), with l_i = kq / lp_i^2 for lp_i the low-pass level of a tone
of filter amplitude A_c (`threshold`): below it the feature is y^2 (passive squaring). The
paper compresses in the squarer itself, through the cubic stiffness it puts on the filter
mass; that detunes the resonant filter with amplitude (a 500 Hz bin rings near 2.3 kHz at 100x
its threshold) and cost 6 points of 12-class accuracy against digital on the built-in corpus
(speaker cross-validation, `springc cv`, at 4x2, 6x3 and 8x3 alike). Compressing after the
low-pass acts on the slow envelope, where the stiffening does no harm. The compressor's
stiffness still grows with amplitude (kq + 3 l c^2, ~2e4 kq at full scale), so its mass is
the larger of kq / (2 pi fq)^2 and what keeps sqrt(k_max / m) h <= STABLE_WH at the step h
(`compressor_mass`); louder clips than FULL_SCALE plans for are simulated again with smaller
steps (`springc.kws.features.integration.Integration.retries`).

Phi: the `gram` reduction over the terminal nodes, pairs (k <= l) weighted 1 (k = l) or 2 and
summed into the groups of `springc.kws.features.phi.group_index`: exactly `phi_vector` of the
recorded terminal trajectories, without storing them.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace

import numpy as np

from springc.design.emit import SprWriter, num
from springc.design.melbank import MelFilter
from springc.errors import UsageError
from springc.lang.ir import FlatNetlist
from springc.kws.features import integration
from springc.kws.features.phi import group_index, n_features
from springc.sim.reductions import Reduction, gram_reduction
from springc.check import check

INPUT_RATE = 16000.0  # Hz: the clips' rate, the `.tran` step of the networks
# RK4 at 128 kHz: at 32 kHz RK4 detunes and damps the top filter bands badly (the per-mode
# estimates of `springc.check.accuracy`; docs/performance.md#how---tolerance-chooses), and
# the compressor's stiffening also needs the small step.
SUBSTEPS = 8
# Largest filter amplitude planned for (sizes the compressor mass). Measured on the
# preprocessed demo corpus: the filter outputs' clip peaks reach 0.63 (lowest bin; 99th
# percentile 0.52, top bins 0.15-0.3). A clip louder than planned stiffens its compressors
# beyond the step and is simulated again with finer steps.
FULL_SCALE = 0.7
STABLE_WH = 2.0  # w h kept below this (RK4's limit on the imaginary axis is 2.83)
# The squarer's own compression amplitude (m of filter output): 14x FULL_SCALE, so its cubic
# stiffness 6 (g/a) y^2 stays below 0.5% of the filter's (no detuning).
SQUARER_RANGE = 10.0
NETWORK_VERSION = 5
# Data-set runs integrate in single precision: twice the SIMD width, and Phi stays within
# round-off of float64 (docs/performance.md#training); the Gram sums accumulate in float64.
DATASET_PRECISION = "float32"
# exp-rk4 integrates the Mel filters exactly (RK4 resolves them only at 8 substeps); each
# candidate costs a kernel compile (about 25 s for an exponential one), so exp-heun3 is not
# tried: the compressors stiffen past its smaller stability interval (it diverged at 1 and 2
# substeps at 4x2 and 8x3 on the built-in corpus, docs/keyword-spotting.md#integration)
FEATURE_METHODS = ("exp-rk4",)


@dataclass(frozen=True)
class MassSpringSettings:
    """Everything that fixes the feature network (SI units; defaults as in the paper where it
    gives them). `sites`: delay-line sites per td (the chain's band edge 2 sites / td rad/s
    stays 6x above the 50 Hz cut-off, delay dispersion below 5% at 50 Hz); `base`: sites of
    the shortest line; `threshold`: the compression amplitude A_c (m of filter output); `g`
    = `klp`, so the low-pass holds y^2; `kq`, `fq`, `zeta`: the compressor's spring (10x
    softer than klp, so compressing barely changes the low-pass), its resonance at rest (5x
    the low-pass cut-off: quasi-static) and its damping ratio there. `filter_scale`,
    `compression_scale`: per bin, factors that `springc tune` found (empty: all 1): the Mel
    filter's frequencies (fa and alpha times the factor: the same response, shifted on a log
    axis) and the compressor's Duffing stiffness l_i. `squarer_range`: the filter amplitude R
    (m) at which the squarer's own quartic term detunes a filter fully (`leverages`); a
    smaller R passes more energy to the low-pass and detunes loud filters more."""

    bins: int = 8
    delays: int = 3
    td: float = 0.032
    tau: float = 80.0
    fc: float = 50.0
    sites: int = 16
    base: int = 2
    klp: float = 100.0
    kc: float = 0.25
    g: float = 100.0
    threshold: float = 0.001
    kq: float = 10.0
    fq: float = 250.0
    zeta: float = 0.7
    input_gain: float = 1.0
    settle: float = 0.05
    filterbank: str = "two-mode"
    fmin: float = 20.0
    fmax: float = 8000.0
    network: int = NETWORK_VERSION  # in the feature-cache key: bump when the netlist changes
    method: str = "rk4"  # how the network is integrated (`springc.kws.features.integration`)
    substeps: int = SUBSTEPS
    filter_scale: tuple[float, ...] = ()
    compression_scale: tuple[float, ...] = ()
    squarer_range: float = SQUARER_RANGE

    def __post_init__(self) -> None:
        # settings.json gives lists; the settings are hashed (cached networks)
        for name in ("filter_scale", "compression_scale"):
            object.__setattr__(self, name, tuple(float(v) for v in getattr(self, name)))

    def validate(self) -> None:
        """UsageError for settings the network cannot realise."""
        if self.bins < 2 or self.delays < 1:
            raise UsageError(f"need bins >= 2 and delays >= 1, got {self.bins} x {self.delays}")
        if self.filterbank != "two-mode":
            raise UsageError("the mass-spring realisation uses the two-mode filterbank",
                             hint="--filterbank two-mode")
        if self.sites < 2 or self.base < 2:
            raise UsageError("delay lines need at least 2 sites per td and a base of 2 sites")
        if min(self.td, self.tau, self.fc, self.klp, self.kc, self.g, self.threshold,
               self.input_gain, self.kq, self.fq, self.zeta, self.squarer_range) <= 0:
            raise UsageError("td, tau, fc, klp, kc, g, threshold, input gain, kq, fq, zeta and "
                             "the squarer range must be > 0")
        if self.line_damping() * self.delays >= self.lowpass_damping():
            raise UsageError(f"{self.delays} delay lines (impedance {self.line_damping():.3g} "
                             f"N s/m each) overload the low-pass (damping "
                             f"{self.lowpass_damping():.3g}); lower kc or raise klp")
        for name in ("filter_scale", "compression_scale"):
            scale = getattr(self, name)
            if scale and (len(scale) != self.bins or min(scale) <= 0):
                raise UsageError(f"{name} needs {self.bins} positive factors, got {scale}")

    def to_dict(self) -> dict:
        """Plain dict (settings.json, cache keys); the tuned factors and the squarer range
        only where set, so the paper's network keeps its keys."""
        d = asdict(self)
        for name in ("filter_scale", "compression_scale"):
            if d[name]:
                d[name] = list(d[name])
            else:
                del d[name]
        if d["squarer_range"] == SQUARER_RANGE:
            del d["squarer_range"]
        return d

    def filter_factors(self) -> np.ndarray:
        """Per bin, the tuned factor on the Mel filter's frequencies (1 untuned)."""
        return np.array(self.filter_scale or (1.0,) * self.bins)

    def compression_factors(self) -> np.ndarray:
        """Per bin, the tuned factor on the compressor's Duffing stiffness (1 untuned)."""
        return np.array(self.compression_scale or (1.0,) * self.bins)

    @property
    def site_delay(self) -> float:
        """t_s, the delay per site (s)."""
        return self.td / self.sites

    def site_mass(self) -> float:
        """m_s = t_s^2 kc, a delay-line site's mass (kg)."""
        return self.site_delay**2 * self.kc

    def line_damping(self) -> float:
        """The lines' characteristic impedance t_s kc (N s/m): their matched termination."""
        return self.site_delay * self.kc

    def lowpass_damping(self) -> float:
        """Total critical damping of the low-pass mass, 2 klp / (2 pi fc)."""
        return 2 * self.klp / (2 * math.pi * self.fc)

    def line_sites(self, j: int) -> int:
        """Sites of delay line j (0-based): base + j * sites."""
        return self.base + j * self.sites

    def latency(self) -> float:
        """Delay of the shortest line from the compressor node to its terminal (s)."""
        return (self.base + 1) * self.site_delay


def stage_scaled(s: MassSpringSettings, factor: float) -> MassSpringSettings:
    """The network with every stage after the Mel filters `factor` times stiffer (klp, g,
    kq, kc; their masses and dampers follow): the displacements after the squarers are those
    of `s` times (1 + a_i) / (1 + factor a_i) per bin (the squarer's leverage a_i grows with
    g; `envelope`), so every energy there is about `factor` times larger, while the filters
    feel the same cubic stiffness (g / a_i does not change). The lever that brings more of
    the sound into the later stages (docs/results-device.md); the classifier is trained on
    the scaled network's features."""
    if not factor > 0:
        raise UsageError(f"the stage stiffness must be > 0, got {factor}")
    return replace(s, klp=s.klp * factor, g=s.g * factor, kq=s.kq * factor, kc=s.kc * factor)


def horizon(s: MassSpringSettings, clip_seconds: float) -> float:
    """Simulated time for a clip: the clip, the longest line's delay, and `settle` for the
    low-pass and (in the classifier) the readouts to catch up."""
    return clip_seconds + s.latency() + (s.delays - 1) * s.td + s.settle


@functools.lru_cache(maxsize=16)
def filters(s: MassSpringSettings) -> tuple[MelFilter, ...]:
    """The fitted two-mode Mel filters of the network (cached, shared with the digital path)."""
    from springc.kws.features.digital import melbank_filters

    return melbank_filters(s.bins, "two-mode", s.fmin, s.fmax)


def leverages(s: MassSpringSettings) -> np.ndarray:
    """a_i = 6 g R^2 / w_a,i^2 (R = `squarer_range`, by default SQUARER_RANGE): the squarer
    leverage whose own compression (cubic stiffness 6 (g/a) y^2 = w_a^2 at |y| = R) lies far
    above every filter amplitude."""
    wa = np.array([2 * np.pi * f.fa for f in filters(s)])
    return 6 * s.g * s.squarer_range**2 / wa**2


def envelope(s: MassSpringSettings, amplitude: float) -> np.ndarray:
    """Per bin, the low-pass level g <y^2> / (klp + g a_i) held for a tone of filter amplitude
    `amplitude` (<y^2> = amplitude^2 / 2; g a_i is the squarer's stiffness on lp)."""
    return s.g * amplitude**2 / 2 / (s.klp + s.g * leverages(s))


def compressor_duffing(s: MassSpringSettings) -> np.ndarray:
    """l_i = kq / e_i^2 with e_i the envelope at the threshold A_c: the compressor's
    threshold sqrt(kq / l_i) is the low-pass level of a tone of amplitude A_c."""
    return s.kq / envelope(s, s.threshold) ** 2


def compressed(level: np.ndarray, kq: float, duffing: np.ndarray) -> np.ndarray:
    """The static compressor output c >= 0 for input `level` >= 0: kq c + l c^3 = kq level
    (Cardano's real root of the depressed cubic)."""
    p, q = kq / duffing, -kq * level / duffing
    root = np.sqrt(q**2 / 4 + p**3 / 27)
    return np.cbrt(-q / 2 + root) + np.cbrt(-q / 2 - root)


def compressor_mass(s: MassSpringSettings) -> np.ndarray:
    """Per bin, the compressor mass: kq / (2 pi fq)^2, raised where the stiffness at full
    scale, kq + 3 l c^2 for the envelope of a FULL_SCALE tone's peak, would put the mode
    above STABLE_WH / h."""
    duffing = compressor_duffing(s)
    c_max = compressed(2 * envelope(s, FULL_SCALE * s.input_gain), s.kq, duffing)
    k_max = s.kq + 3 * duffing * c_max**2
    h = 1.0 / (INPUT_RATE * SUBSTEPS)
    return np.maximum(s.kq / (2 * np.pi * s.fq) ** 2, k_max * (h / STABLE_WH) ** 2)


PREDICTION_TAIL = 2048  # samples of zero padding: the filters ring out within them


def stiffness(signals: np.ndarray, s: MassSpringSettings) -> np.ndarray:
    """Per clip of `signals` (clips, samples) at 16 kHz, the largest angular frequency any
    compressor reaches times the sample period: what `integration.run_with_retries` needs to
    send a clip too loud for a step to finer ones before simulating it. Predicted digitally,
    at a few percent of a simulation's cost: the filters' responses (tuned factors included),
    y^2 averaged over 1 ms and low-passed (two one-pole stages: the critically damped
    low-pass) at the squarer's static gain, the static compressor at the peak level (within
    5% above the simulated peaks on 8x3 speech)."""
    signals = np.atleast_2d(np.asarray(signals, dtype=np.float32))
    level = _peak_level(signals, s) * s.g / (s.klp + s.g * leverages(s))
    duffing = compressor_duffing(s) * s.compression_factors()
    c = compressed(level, s.kq, duffing)
    omega = np.sqrt((s.kq + 3 * duffing * c**2) / compressor_mass(s))
    return omega.max(axis=-1) / INPUT_RATE


def _peak_level(signals: np.ndarray, s: MassSpringSettings) -> np.ndarray:
    """(clips, bins): the largest low-passed y^2 of each filter output (0 for no samples)."""
    from scipy import fft as sfft
    from scipy.signal import lfilter

    n = signals.shape[1]
    if n == 0:
        return np.zeros((len(signals), s.bins))
    size = sfft.next_fast_len(n + PREDICTION_TAIL, real=True)
    y = sfft.irfft(sfft.rfft(signals, size)[:, None, :] * _bank(s, size), size)[..., :n]
    block = int(INPUT_RATE / 1000)
    power = np.pad(y * y, ((0, 0), (0, 0), (0, -n % block))).reshape(*y.shape[:2], -1, block)
    pole = math.exp(-2 * math.pi * s.fc * block / INPUT_RATE)
    mean_square = lfilter([(1 - pole) ** 2], [1, -2 * pole, pole**2], power.mean(-1), axis=-1)
    return mean_square.max(axis=-1)


@functools.lru_cache(maxsize=8)
def _bank(s: MassSpringSettings, size: int) -> np.ndarray:
    """The network's filter responses (input gain and tuned factors in) on the rfft grid of a
    `size`-point transform, (bins, size // 2 + 1) complex64."""
    from scipy import fft as sfft

    f = sfft.rfftfreq(size, 1.0 / INPUT_RATE)
    bank = [replace(mf, fa=mf.fa * ff, alpha=mf.alpha * ff).response(f)
            for mf, ff in zip(filters(s), s.filter_factors())]
    return (np.stack(bank) * s.input_gain).astype(np.complex64)


def compressor_damping(s: MassSpringSettings) -> np.ndarray:
    """Per bin, the compressor's total damping: ratio zeta at its resonance at rest, or the
    delay lines' impedance if that is more. The local damper supplies what the lines do not;
    the low-pass sees the total through the spring kq (its `bext`)."""
    critical = 2 * np.sqrt(s.kq * compressor_mass(s))
    return np.maximum(s.zeta * critical, s.delays * s.line_damping())


def terminal(i: int, j: int) -> str:
    """Name of the terminal node of bin i, delay j (the feature phi_(i m + j))."""
    return f"f{i}_{j}"


def terminals(s: MassSpringSettings) -> list[str]:
    """Terminal nodes in Phi order, l = i m + j."""
    return [terminal(i, j) for i in range(s.bins) for j in range(s.delays)]


def front_end(w: SprWriter, s: MassSpringSettings) -> None:
    """Write the feature extraction up to the last site of every delay line, and its coupling
    to the terminal nodes f{i}_{j} (which need mass and damping from the caller)."""
    damping = compressor_damping(s)
    if damping.max() >= s.lowpass_damping():
        raise UsageError(f"the compressors' damping ({damping.max():.3g} N s/m) overloads the "
                         f"low-pass (damping {s.lowpass_damping():.3g}); raise klp or the "
                         "threshold")
    for name in ("melfilter", "squarer", "lowpass", "compressor", "delayline"):
        w.include(f"{name}.spr")
    w.params(ts=s.site_delay, kc=s.kc, klp=s.klp, fc=s.fc, g=s.g, kq=s.kq)
    # the compressor mass stays sized for the untuned stiffness: a tuned factor moves l alone
    rows = zip(filters(s), s.filter_factors(), leverages(s),
               compressor_duffing(s) * s.compression_factors(), compressor_mass(s), damping)
    for i, (f, ff, a, duffing, mass, b) in enumerate(rows):
        w.blank()
        w.comment(f"bin {i}: Mel centre {f.centre:.0f} Hz (modes {f.fa:.0f} and {f.fb:.0f} Hz); "
                  f"compression from filter amplitude {s.threshold:.3g} m")
        w.statement(f"Xf{i}", f"y{i}", "melfilter", f"fa={num(f.fa * ff)}",
                    f"delta={num(f.delta)}", f"alpha={num(f.alpha * ff)}", "ch=0",
                    f"gain={num(f.gain * s.input_gain)}")
        w.statement(f"Xq{i}", f"y{i}", f"lp{i}", "squarer", "g={g}", f"a={num(a)}")
        w.statement(f"Xlp{i}", f"lp{i}", "lowpass", "fc={fc}", "k={klp}", f"bext={num(b)}")
        local = b - s.delays * s.line_damping()
        w.statement(f"Xc{i}", f"lp{i}", f"c{i}", "compressor", "k={kq}", f"m={num(mass)}",
                    f"b={num(local)}", f"l={num(duffing)}")
        for j in range(s.delays):
            w.statement(f"Cfan{i}_{j}", f"c{i}", f"e{i}_{j}", "k={kc}")
            w.statement(f"Xd{i}_{j}", f"e{i}_{j}", f"o{i}_{j}", "delayline",
                        f"n={s.line_sites(j)}", "td={ts}", "kc={kc}", "term=0")
            w.statement(f"Ct{i}_{j}", f"o{i}_{j}", terminal(i, j), "k={kc}")


def tran(w: SprWriter, s: MassSpringSettings, seconds: float = 1.0) -> None:
    """`.tran` on the clips' 16 kHz grid, RK4 with SUBSTEPS substeps per sample."""
    w.statement(".tran", f"{{1/{INPUT_RATE:g}}}", num(horizon(s, seconds)))
    w.statement(".options", f"substeps={SUBSTEPS}")


def feature_text(s: MassSpringSettings) -> str:
    """The `.spr` text of the feature-extraction network with matched terminal nodes."""
    s.validate()
    w = SprWriter()
    w.title(f"mass-spring feature extraction, {s.bins} bins x {s.delays} delays")
    w.comment(__doc__.split("\n\n")[1])
    front_end(w, s)
    w.blank()
    w.comment("terminal nodes: half a line site each, with the matched damping t_s kc")
    for node in terminals(s):
        w.statement(f"M{node}", node, "m={ts**2 * kc / 2}", "b={ts * kc}")
    tran(w, s)
    return w.text()


@functools.lru_cache(maxsize=8)
def feature_network(s: MassSpringSettings) -> FlatNetlist:
    """The elaborated feature network (cached per settings)."""
    from springc.lang import load_text

    return load_text(feature_text(s), "<mass-spring features>")


def phi_reduction(net: FlatNetlist, s: MassSpringSettings, label: str = "phi") -> Reduction:
    """The `gram` reduction whose result is Phi (runs, N): pairs k <= l of terminal nodes,
    weight 1 on the diagonal and 2 off it, grouped by `group_index`."""
    nodes = terminals(s)
    gidx = group_index(s.bins, s.delays)
    k, kk = np.triu_indices(len(nodes))
    red = gram_reduction(net, s.tau, [nodes[a] for a in k], [nodes[b] for b in kk], gidx[k, kk],
                         np.where(k == kk, 1.0, 2.0), label=label)
    if red.gram.groups != n_features(s.bins, s.delays):
        raise AssertionError("group index does not cover every feature")
    return red


def simulate_phi(signals: np.ndarray, s: MassSpringSettings, *, chunk: int | None = None,
                 progress: bool = False, method: str | None = None,
                 substeps: int | None = None, precision: str | None = None) -> np.ndarray:
    """Phi (clips, N) of `signals` (clips, samples) at 16 kHz, by simulating the network
    (with `s.method` and `s.substeps` unless `method`, `substeps` say otherwise)."""
    from springc.sim.simulate import simulate

    net = feature_network(s)
    signals = np.atleast_2d(np.asarray(signals, dtype=np.float64))
    res = simulate(checked_features(s), signals[:, None, :], INPUT_RATE,
                   reductions=[phi_reduction(net, s)],
                   tstop=horizon(s, signals.shape[1] / INPUT_RATE), probes=[], chunk=chunk,
                   batch=len(signals), progress=progress, method=method or s.method,
                   substeps=substeps or s.substeps, precision=precision)
    return res.reductions["phi"]


@functools.lru_cache(maxsize=8)
def checked_features(s: MassSpringSettings):
    """The checked feature network (cached per settings: a data set's batches share it)."""
    return check(feature_network(s))


INTEGRATION_CLIPS = 16  # clips (unaugmented, first in order) the choice is measured on


@dataclass(frozen=True)
class Reference:
    """The tight reference run (`integration.REFERENCE`) on a sample of clips: what the
    integration choice compares with (Phi) and what sizes the heads (the peaks)."""

    signals: np.ndarray  # (clips, samples) at 16 kHz
    phi: np.ndarray  # (clips, N)
    peaks: np.ndarray  # (clips,): the largest |x| of any terminal node

    @property
    def amplitude(self) -> float:
        """A: the median over the clips of the peak terminal displacement."""
        return float(np.median(self.peaks))


def reference_run(signals: np.ndarray, s: MassSpringSettings) -> Reference:
    """Phi and the peaks of `signals` (clips, samples) at 16 kHz in one simulation: Phi as a
    reduction, the terminal nodes recorded at 2 kHz (one kernel, compiled once, serves both)."""
    from springc.sim.simulate import simulate

    signals = np.atleast_2d(np.asarray(signals, dtype=np.float64))
    labels = [f"x({node})" for node in terminals(s)]
    method, substeps, precision = integration.REFERENCE
    res = simulate(checked_features(s), signals[:, None, :], INPUT_RATE, probes=labels,
                   reductions=[phi_reduction(feature_network(s), s)], outrate=2000.0,
                   method=method, substeps=substeps, precision=precision, chunk=BATCH,
                   tstop=horizon(s, signals.shape[1] / INPUT_RATE))
    peaks = np.max([np.abs(res.probes[k]).max(axis=1) for k in labels], axis=0)
    return Reference(signals, res.reductions["phi"], peaks)


def sample_signals(clips: list) -> np.ndarray:
    """The first INTEGRATION_CLIPS of `clips`, unaugmented: the sample of the reference run."""
    return load_signals(clips[:INTEGRATION_CLIPS], False, 0, [])


def integrated(s: MassSpringSettings, clips: list, tol: float | None
               ) -> tuple[MassSpringSettings, integration.Integration, Reference | None]:
    """`s` with the integration `tol` chooses on `sample_signals(clips)`, that choice, and the
    reference run on them (None: the paper's RK4 x8, and no reference run)."""
    if tol is None:
        return s, integration.PAPER, None
    sample = sample_signals(clips)

    def measure() -> tuple[integration.Integration, Reference]:
        runs = []  # the reference run, kept for its peaks

        def reference() -> np.ndarray:
            runs.append(reference_run(sample, s))
            return runs[0].phi

        return choose_integration(s, sample, tol, reference), runs[0]

    chosen, ref = integration.remembered(
        "features' integration", [feature_text(s), repr(s), repr(tol),
                                  integration.signal_key(sample)], measure)
    return replace(s, method=chosen.method, substeps=chosen.substeps), chosen, ref


def choose_integration(s: MassSpringSettings, signals: np.ndarray,
                       tol: float = integration.TOLERANCE,
                       reference: Callable[[], np.ndarray] | None = None
                       ) -> integration.Integration:
    """The cheapest integration of the feature network with Phi within `tol` of the tight
    reference on `signals` (a sample of clips, (clips, samples) at 16 kHz); `reference` as in
    `integration.choose`."""
    def outputs(sig, method, substeps, precision):  # one try: loud clips are NaN rows
        return phi_batch(sig, replace(s, method=method, substeps=substeps), slice(0, 1),
                         precision)

    duration = horizon(s, signals.shape[1] / INPUT_RATE)
    return integration.choose(checked_features(s), signals, outputs, duration, tol,
                              DATASET_PRECISION, FEATURE_METHODS, reference)


def simulate_traces(signals: np.ndarray, s: MassSpringSettings,
                    rate: float = 1000.0) -> tuple[np.ndarray, np.ndarray]:
    """(t, x) with x (clips, bins, T): the compressed features c{i} (the compressor outputs,
    which feed the delay lines) at `rate`, for plots and the comparison with the digital
    features. Integrated like `reference_run`, Phi included, so that it runs the reference's
    kernel, which training has compiled."""
    from springc.sim.simulate import simulate

    signals = np.atleast_2d(np.asarray(signals, dtype=np.float64))
    labels = [f"x(c{i})" for i in range(s.bins)]
    method, substeps, precision = integration.REFERENCE
    res = simulate(checked_features(s), signals[:, None, :], INPUT_RATE, probes=labels,
                   reductions=[phi_reduction(feature_network(s), s)], outrate=rate,
                   method=method, substeps=substeps, precision=precision, chunk=BATCH,
                   tstop=horizon(s, signals.shape[1] / INPUT_RATE))
    return res.t, np.stack([res.probes[k] for k in labels], axis=1)


def from_features(fs, **overrides) -> MassSpringSettings:
    """Mass-spring settings matching digital `FeatureSettings` (bins, delays, td, tau, fc,
    filter range), with `overrides` for the physical parameters (threshold, kc, ...)."""
    return MassSpringSettings(bins=fs.bins, delays=fs.delays, td=fs.td, tau=fs.tau, fc=fs.fc,
                              fmin=fs.fmin, fmax=fs.fmax, **overrides)


def physical_settings(fs, given=None) -> MassSpringSettings:
    """The mass-spring settings of a training run: `given`, or the digital settings' sizes
    with the default physical parameters; validated."""
    s = given if given is not None else from_features(fs)
    s.validate()
    return s


# -- data sets: batches of clips through the network on Dask --------------------------------

BATCH = 16  # clips simulated in lockstep by one worker (SIMD lanes; one progress tick)
GPU_BATCH = 4096  # clips a batch on the GPU: one launch of a block a clip fills an H100


def load_signals(clips: list, augment: bool, seed: int, noise_files: list) -> np.ndarray:
    """The clips as the network hears them, (clips, samples) float32 at 16 kHz: the same
    preprocessing and (for training) the same per-clip augmentation as the digital path."""
    from springc.kws.data.dataset import _clip_rng, load_clip

    noise = noise_bank(tuple(noise_files)) if augment and noise_files else None
    return np.stack([load_clip(c, augment=augment, rng=_clip_rng(seed, c.key()), noise=noise)
                     for c in clips]).astype(np.float32)


@functools.lru_cache(maxsize=2)
def noise_bank(files: tuple):
    """The background noise of augmentation, read once per process."""
    from springc.kws.data.dataset import NoiseBank

    return NoiseBank(list(files))


def clips_phi(clips: list, s: MassSpringSettings, augment: bool, seed: int,
              noise_files: tuple, tries: slice = slice(None)) -> dict[str, np.ndarray]:
    """{"phi": Phi} of one batch of clips, read, augmented and simulated by one core (a Dask
    task: reading the audio on the workers keeps every core busy); `tries` as in
    `phi_batch`."""
    return {"phi": phi_batch(load_signals(clips, augment, seed, list(noise_files)), s, tries)}


def phi_batch(signals: np.ndarray, s: MassSpringSettings, tries: slice = slice(None),
              precision: str = DATASET_PRECISION) -> np.ndarray:
    """Phi of one batch, simulated by one core (a Dask task); clips too loud for the step are
    simulated again with finer steps (`Integration.retries`, the part `tries` of them; a clip
    that diverges at the last of a part that is not the whole gets a row of NaN)."""
    plan = integration.Integration(s.method, s.substeps, precision)
    signals = np.asarray(signals, dtype=np.float64)
    return integration.run_with_retries(
        plan, lambda method, sub, idx: {"phi": simulate_phi(
            signals[idx], s, chunk=BATCH, method=method, substeps=sub,
            precision=plan.precision)}, len(signals), tries, stiffness(signals, s))["phi"]


def batches(signals, size: int = BATCH) -> list:
    """Consecutive batches of at most `size` clips (an array of signals or a list)."""
    return [signals[k:k + size] for k in range(0, len(signals), size)]


def dataset_phi(clips: list, split: str, s: MassSpringSettings, *, noise_files: list,
                seed: int = 0, scheduler: str | None = None,
                workers: int | None = None) -> np.ndarray:
    """Phi (clips, N) of a split's clips, simulated on Dask (`springc.kws.features.distributed`)."""
    from functools import partial

    work = partial(clips_phi, s=s, augment=split == "train", seed=seed,
                   noise_files=tuple(noise_files))
    return map_pooled(work, clips, f"mass-spring {split}", scheduler, workers)["phi"]


def map_pooled(work: Callable[..., dict], items, desc: str, scheduler: str | None = None,
               workers: int | None = None) -> dict[str, np.ndarray]:
    """The rows work(batch, tries=...) gives for the batches of `items` (clips or signals),
    computed on Dask: every clip at the chosen step first; those the first try leaves as NaN
    rows (too loud or too stiff for its step) then together, in full batches, at the finer
    steps. A kernel call costs about the same for one clip as for a full batch, so one loud
    clip would otherwise cost its batch a whole second call."""
    out = _map_rows(work, items, slice(0, 1), desc, scheduler, workers)
    nan = [np.isnan(v).reshape(len(v), -1).any(axis=1) for v in out.values()]
    loud = np.flatnonzero(np.any(nan, axis=0))
    if len(loud):
        picked = items[loud] if isinstance(items, np.ndarray) else [items[k] for k in loud]
        again = _map_rows(work, picked, slice(1, None),
                          f"{desc}, {len(loud)} loud clip(s) at finer steps", scheduler, workers)
        for key, value in out.items():
            value[loud] = again[key]
    return out


def _map_rows(work: Callable[..., dict], items, tries: slice, desc: str,
              scheduler: str | None, workers: int | None) -> dict[str, np.ndarray]:
    from functools import partial

    from springc.kws.features.distributed import map_batches, on_gpu

    parts = batches(items, GPU_BATCH if on_gpu() else BATCH)
    got = map_batches(partial(work, tries=tries), parts, scheduler, workers=workers, desc=desc,
                      sizes=[len(p) for p in parts])
    return {key: np.concatenate([g[key] for g in got]) for key in got[0]}


def feature_correlation(signals: np.ndarray, s: MassSpringSettings) -> np.ndarray:
    """Per clip and bin, the correlation of the compressed feature c_i(t) with the digital
    feature of the same bin (`springc.kws.features.digital`), both at 1 kHz: (clips, bins)."""
    from springc.kws.features.digital import FeatureSettings, features

    _, x = simulate_traces(signals, s)
    d = features(np.asarray(signals, dtype=np.float64), INPUT_RATE,
                 FeatureSettings(bins=s.bins, delays=s.delays, fmin=s.fmin, fmax=s.fmax))
    k = min(x.shape[-1], d.shape[-1])
    a = x[..., :k] - x[..., :k].mean(-1, keepdims=True)
    b = d[..., :k] - d[..., :k].mean(-1, keepdims=True)
    return (a * b).sum(-1) / np.sqrt((a * a).sum(-1) * (b * b).sum(-1))
