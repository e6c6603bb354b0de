"""Weight transfer: a trained SVM becomes mass-spring classifier heads (paper Sec. III.B).

For each classifier row c (a class, or a digit pair) with raw coefficients coef_c on Phi:

    C_c = spread(coef_c)             (each coefficient on the (k, l) pairs of its group)
    C_c = Q Lambda Q^T               (eigen-decomposition; Q orthogonal)
    head c: mvm encoding Q^T         (outputs y_k = Q_k . phi, `springc.design.mvm`)
            Q couplings y_k -> r_c   gamma_k = s_c lambda_k, alpha_k = A^2 gamma_k / (eps kc)
            readout r_c              tau = 80 s, Q_r = 0.01, stiffness all from the couplings

The readout integrates sum_k gamma_k y_k^2 = s_c phi^T C_c phi with the kernel exp(-(T-t)/tau)
(its slow pole), so at the end of the clip x_r = (s_c / D) c . Phi with
D = sqrt(b_r^2 - 4 m_r k_r) (the readout's Green's function past its fast pole): the scale
s_c / D is a design number, never fitted. Squaring error: the paper's eps = A^2 gamma / alpha
with A the peak feature amplitude (terminal displacement) and stiffness in units of the delay
line's kc (the paper's "stiffness scale of the delay line"): eps = A^2 gamma / (alpha kc), the
definition of `springc.design.squaring` (whose unit, Fig. 6c-d, has kc = 1).
The zero modes that carry the features are held only by the lines' impedance (t_s kc w, about
kc / 100 at the features' few-Hz envelopes), so the couplings' cubic stiffness and the
readout's parametric back-action distort the features from eps ~ 1e-4 on (measured; see
docs/results-massspring.md). s_c is the largest scale whose couplings stay within the readout's
stiffness: sum_k gamma_k alpha_k = A^2 s_c^2 sum lambda^2 / (eps kc) = FILL m_r w_r^2.

Impedance: every head's mvm inputs sit on the shared terminal nodes f{i}_{j}; with H heads each
mvm is designed for mass m_s / (2H) and damping t_s kc / H (its nodes get half of each), so
together their zero modes put half a line site with the matched damping on each terminal, the
reflection-free termination the features were computed with (`springc.kws.features.massspring`).

Summing heads (`Design(heads="summing")`, for a fabricated device): the zero modes rest on
stiffnesses that cancel exactly, so a relative spread of 1e-6 on them moves the decisions
(docs/results-spread.md). A summing head makes each component y_e = q_e . phi / |q_e|_1 with a
weighted sum by springs instead (`springc.design.summer`: every coefficient at first order),
its coupling gamma_e realising lambda_e |q_e|_1^2, and its squaring error measured against the
summing node's own stiffness k_e = kappa |q_e|_1 (what holds it against the coupling's
back-action). A spring on a tap pulls it at every frequency, down to the features' slow
envelopes, where only the line's static stiffness kc / sites (its longest) holds the tap (a
matched termination is a damper): kappa is set so that all heads together add no more than
`LOAD` of that, or of the impedance t_s kc 2 pi fc if smaller (of the buffer's stiffness, with
a buffer), to any tap; the summing nodes resonate `SUM_RESONANCE` times above the low-pass
cut-off (quasi-static over the features).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from springc.design.blocks import readout_params
from springc.design.emit import SprWriter, num
from springc.design.mvm import DEFAULT_STIFFNESS_RATIO, design_mvm, mvm_text
from springc.design.squaring import leverage_for
from springc.errors import UsageError
from springc.kws.features import integration
from springc.kws.features import massspring as msp
from springc.kws.features.phi import n_features, spread
from springc.kws.training import tapbuffer
from springc.check import CheckedNetlist, check

HEADS = ("zero-mode", "summing")
LOAD = 1e-3  # summing heads: the most of what holds a tap that their springs may add
SUM_RESONANCE = 10.0  # summing nodes' resonance over the low-pass cut-off
SUM_ZETA = 0.7  # and their damping ratio
TAU_READOUT = 80.0  # s (paper)
Q_READOUT = 0.01  # paper
FILL = 0.99  # share of the readout stiffness from the couplings (the local spring: the rest)
DROP = 1e-9  # eigenvalues below this fraction of the largest carry no coupling


@dataclass(frozen=True)
class Head:
    """One classifier head: its row name, eigenvalues and vectors of C, the couplings' gamma and
    alpha (for the kept components `keep`), the scale x_r -> c . Phi and the intercept."""

    name: str
    lam: np.ndarray
    q: np.ndarray
    keep: np.ndarray
    gamma: np.ndarray
    alpha: np.ndarray
    scale: float
    intercept: float
    kappa: float = 0.0  # summing heads: coupling stiffness per unit weight (0: zero-mode)


@dataclass(frozen=True)
class Design:
    """How the heads are built: `heads` zero-mode (the paper's multiplier) or summing (a
    weighted sum by springs per component); an optional tap buffer
    (`springc.kws.training.tapbuffer`); the zero-mode multiplier's stiffness factor."""

    heads: str = "zero-mode"
    buffer: tapbuffer.TapBuffer | None = None
    mvm_stiffness: float = 1.0

    def __post_init__(self) -> None:
        if self.heads not in HEADS:
            raise UsageError(f"unknown heads {self.heads!r}; use one of {', '.join(HEADS)}")
        if not self.mvm_stiffness > 0:
            raise UsageError(f"the mvm stiffness factor must be > 0, not {self.mvm_stiffness}")

    def to_dict(self) -> dict:
        """As settings.json's transfer "design" keeps it."""
        return {"heads": self.heads, "mvm_stiffness": self.mvm_stiffness,
                "buffer": self.buffer.to_dict() if self.buffer else None}

    @classmethod
    def from_dict(cls, d: dict | None) -> "Design":
        """The design a settings.json records (none recorded: the paper's)."""
        if not d:
            return cls()
        buffer = tapbuffer.TapBuffer(**d["buffer"]) if d.get("buffer") else None
        return cls(d.get("heads", "zero-mode"), buffer, float(d.get("mvm_stiffness", 1.0)))


# the design that holds the 8x3 network's accuracy to eps = 1 (docs/results-eps.md): the taps
# buffered (kb 6e-5 kc to the buffer node, kg 1e4 kc from it to ground) and the multipliers 10x
# stiffer; `springc train` takes it where the heads' eps is above BUFFERED_FROM
BUFFERED = Design("zero-mode", tapbuffer.TapBuffer(6e-5, 1e4), 10.0)
BUFFERED_FROM = 1e-5

def readout_scale(tau: float = TAU_READOUT, qr: float = Q_READOUT, m: float = 1.0) -> float:
    """D = sqrt(b^2 - 4 m k) of the readout: x_r(T) = int exp(-(T-t)/tau) F dt / D."""
    p = readout_params(tau, qr, m)
    return math.sqrt(p.b**2 - 4 * p.m * p.k_total)


def stiffness_scale(s: msp.MassSpringSettings) -> float:
    """The stiffness the squaring error is measured against: the delay line's kc (N/m)."""
    return s.kc


def design_head(name: str, coef: np.ndarray, intercept: float, s: msp.MassSpringSettings,
                amplitude: float, epsilon: float) -> Head:
    """The head for one classifier row: couplings from the eigen-decomposition of C."""
    if not (amplitude > 0 and epsilon > 0):
        raise UsageError(f"feature amplitude and epsilon must be positive, got {amplitude}, "
                         f"{epsilon}")
    lam, q = np.linalg.eigh(spread(coef, s.bins, s.delays))
    keep = np.flatnonzero(np.abs(lam) > DROP * np.abs(lam).max())
    gamma, alpha, scale = couplings_for(lam[keep], s, amplitude, epsilon)
    return Head(name, lam, q, keep, gamma, alpha, scale, float(intercept))


def couplings_for(lam: np.ndarray, s: msp.MassSpringSettings, amplitude: float,
                  epsilon: float) -> tuple[np.ndarray, np.ndarray, float]:
    """gamma, alpha and the decision scale of the couplings that realise the eigenvalues
    `lam` (of the coupled components) at squaring error `epsilon`: the largest scale whose
    couplings stay within the readout's stiffness (`FILL`)."""
    k_total = readout_params(TAU_READOUT, Q_READOUT).k_total
    k_t = stiffness_scale(s)
    scale = math.sqrt(FILL * k_total * epsilon * k_t / (amplitude**2 * np.sum(lam**2)))
    gamma = scale * lam
    alpha = leverage_for(amplitude, gamma, epsilon, k_t)
    return gamma, alpha, scale / readout_scale()


def redesigned_heads(heads: list[Head], s: msp.MassSpringSettings, amplitude: float,
                     epsilon: float) -> list[Head]:
    """The same heads (weights and intercepts) with their couplings designed again for the
    squaring error `epsilon` at the tap amplitude `amplitude`."""
    return reweighted_heads(heads, [h.lam[h.keep] for h in heads],
                            [h.intercept for h in heads], s, amplitude, epsilon)


def reweighted_heads(heads: list[Head], weights: list, intercepts: list,
                     s: msp.MassSpringSettings, amplitude: float,
                     epsilon: float) -> list[Head]:
    """The heads with new eigenvalues `weights[k]` on their coupled components (the same
    eigenvectors, so the same mvm) and new intercepts, their couplings designed as
    `design_head` does (`springc.kws.tuning.refit` fits them on the network's exact response)."""
    out = []
    for h, w, b in zip(heads, weights, intercepts):
        w = np.asarray(w, np.float64)
        lam = h.lam.copy()
        lam[h.keep] = w
        gamma, alpha, scale = couplings_for(w, s, amplitude, epsilon)
        out.append(replace(h, lam=lam, gamma=gamma, alpha=alpha, scale=scale,
                           intercept=float(b)))
    return out


def heads_for(models, s: msp.MassSpringSettings, amplitude: float, epsilon: float,
              design: Design = Design()) -> list[Head]:
    """One head per row of every model [(classes, LinearModel)], in order, built as `design`
    says (with a buffer: for the amplitude it leaves, the decision scale still the taps')."""
    seen = tapbuffer.amplitude(design.buffer, amplitude)
    out = []
    for classes, model in models:
        names = ["-".join(classes)] if len(model.coef) == 1 else list(classes)
        for name, coef, b in zip(names, model.coef, model.intercept):
            out.append(design_head(name, coef, b, s, seen, epsilon))
    if design.heads == "summing":
        out = summing_heads(out, s, seen, epsilon, design)
    return tapbuffer.rescaled(out, design.buffer)


def summing_heads(heads: list[Head], s: msp.MassSpringSettings, amplitude: float,
                  epsilon: float, design: Design) -> list[Head]:
    """The heads' couplings for summing nodes (module docstring): kappa from the taps' load,
    gamma_e = scale lambda_e |q_e|_1^2, alpha_e at squaring error `epsilon` against the node's
    stiffness kappa |q_e|_1, the scale the largest within the readout's stiffness (`FILL`)."""
    if design.buffer is not None:
        holding = (design.buffer.kb + design.buffer.kg) * s.kc
    else:
        holding = min(s.line_damping() * 2 * math.pi * s.fc,
                      s.kc / s.line_sites(s.delays - 1))
    load = sum(np.abs(h.q[:, h.keep]).sum(axis=1) for h in heads)
    kappa = LOAD * holding / float(load.max())
    k_total = readout_params(TAU_READOUT, Q_READOUT).k_total
    out = []
    for h in heads:
        l1 = np.abs(h.q[:, h.keep]).sum(axis=0)
        lam, k_node = h.lam[h.keep] * l1**2, kappa * l1
        scale = math.sqrt(FILL * k_total * epsilon / (amplitude**2 * np.sum(lam**2 / k_node)))
        gamma = scale * lam
        out.append(replace(h, gamma=gamma, alpha=leverage_for(amplitude, gamma, epsilon, k_node),
                           scale=scale / readout_scale(), kappa=kappa))
    return out


def head_text(k: int, head: Head, s: msp.MassSpringSettings, heads: int,
              mvm_stiffness: float = 1.0) -> str:
    """`.subckt mvm{k}` (encoding Q^T) and `.subckt head{k} f0 .. f{N-1} r`: the mvm on the
    terminals, the quadratic couplings and the readout. `mvm_stiffness` multiplies the mvm's
    stiffness d (`springc.design.mvm`'s default: DEFAULT_STIFFNESS_RATIO kc). A summing head
    (`head.kappa` > 0) has a weighted sum by springs per component instead of the mvm."""
    if head.kappa > 0:
        return summing_head_text(k, head, s)
    n = s.bins * s.delays
    kc = s.kc / heads
    design = design_mvm(head.q.T, m=s.site_mass() / (2 * heads), b=s.line_damping() / heads,
                        kc=kc, stiffness=mvm_stiffness * DEFAULT_STIFFNESS_RATIO * kc)
    mvm = mvm_text(design, source=f"the eigenvectors of C for {head.name}")
    mvm = mvm.replace("\n.subckt mvm ", f"\n.subckt mvm{k} ").replace(".ends mvm", f".ends mvm{k}")
    w = SprWriter()
    w.comment(f"head{k}: classifier row {head.name!r}; readout x_r = {head.scale:.6g} c . Phi, "
              f"decision x_r / {head.scale:.6g} + ({head.intercept:.6g})")
    w.comment(f"{len(head.keep)} of {n} eigen-components coupled (|lambda| > {DROP:g} max)")
    w.subckt(f"head{k}", [f"f{p}" for p in range(n)] + ["r"])
    w.statement("Xm", *[f"f{p}" for p in range(n)], *[f"y{p}" for p in range(n)], f"mvm{k}")
    for e, g, a in zip(head.keep, head.gamma, head.alpha):
        w.statement(f"Qy{e}", f"y{e}", "r", f"g={num(g)}", f"a={num(a)}")
    kext = float(np.sum(head.gamma * head.alpha))
    w.statement("Xr", "r", "readout", f"tau={num(TAU_READOUT)}", f"qr={num(Q_READOUT)}",
                f"kext={num(kext)}")
    w.ends(f"head{k}")
    return mvm + "\n" + w.text()


def summing_head_text(k: int, head: Head, s: msp.MassSpringSettings) -> str:
    """`.subckt head{k} f0 .. f{N-1} r`: per coupled component e a summing node s{e}
    (`springc.design.summer`, weights q_e), its quadratic coupling to the readout, the
    readout."""
    from springc.design.summer import design_summer

    taps = [f"f{p}" for p in range(s.bins * s.delays)]
    w = SprWriter()
    w.comment(f"head{k}: classifier row {head.name!r} with summing nodes; readout x_r = "
              f"{head.scale:.6g} c . Phi, decision x_r / {head.scale:.6g} + "
              f"({head.intercept:.6g})")
    w.comment(f"{len(head.keep)} of {len(taps)} eigen-components summed by springs of "
              f"{head.kappa:.6g} N/m per unit weight")
    w.subckt(f"head{k}", taps + ["r"])
    for e, g, a in zip(head.keep, head.gamma, head.alpha):
        summer = design_summer(head.q[:, e], head.kappa, SUM_RESONANCE * s.fc, SUM_ZETA)
        for fields in summer.elements(taps, f"s{e}", str(e)):
            w.statement(*fields)
        w.statement(f"Qy{e}", f"s{e}", "r", f"g={num(g)}", f"a={num(a)}")
    kext = float(np.sum(head.gamma * head.alpha))
    w.statement("Xr", "r", "readout", f"tau={num(TAU_READOUT)}", f"qr={num(Q_READOUT)}",
                f"kext={num(kext)}")
    w.ends(f"head{k}")
    return w.text()


def classifier_text(heads: list[Head], s: msp.MassSpringSettings, include_heads: bool = True,
                    epsilon: float | None = None, design: Design = Design()) -> str:
    """The whole classifier: the shared front end with every head on its terminal nodes.
    With `include_heads`, the heads' text follows inline (one self-contained netlist);
    otherwise `.include "head{k}.spr"` lines name the files `write_classifier` writes.
    With the design's buffer, the heads sit on buffer nodes instead
    (`springc.kws.training.tapbuffer`; `heads_for` designs them for its amplitude); its
    `mvm_stiffness` multiplies the zero-mode heads' mvm stiffness (`BUFFERED`: the design
    stable to eps = 1 of docs/results-eps.md)."""
    s.validate()
    buffer = design.buffer
    w = SprWriter()
    w.title(f"mass-spring keyword spotter, {s.bins} bins x {s.delays} delays, "
            f"{len(heads)} heads")
    w.comment("From sound to decision in one passive network: feature extraction "
              "(springc.kws.features.massspring) feeding every classifier head "
              "(springc.kws.training.transfer)."
              + (f" Squaring error eps = {epsilon:g}." if epsilon else ""))
    w.comment("Prediction: the row decisions x(r{k}) / scale_k + intercept_k (in each head's "
              "header), argmax over a model's classes (sign for a binary model).")
    w.include("readout.spr")
    if not include_heads:
        for k in range(len(heads)):
            w.include(f"head{k}.spr")
    msp.front_end(w, s)
    w.blank()
    if buffer is None and design.heads == "summing":
        w.comment("terminal nodes: half a line site each, with the matched damping t_s kc; "
                  "the heads' summing springs read them")
        for node in msp.terminals(s):
            w.statement(f"M{node}", node, "m={ts**2 * kc / 2}", "b={ts * kc}")
    elif buffer is None:
        w.comment("heads: mvm inputs on the terminal nodes (they supply the terminals' mass "
                  "and matched damping), one readout each")
    else:
        tapbuffer.write(w, s, buffer)
        w.comment("heads: mvm inputs on the buffer nodes, one readout each")
    taps = msp.terminals(s) if buffer is None else tapbuffer.nodes(s)
    for k, head in enumerate(heads):
        w.statement(f"Xh{k}", *taps, f"r{k}", f"head{k}")
    msp.tran(w, s)
    text = w.text()
    if include_heads:
        text += "\n" + "\n".join(head_text(k, h, s, len(heads), design.mvm_stiffness)
                                 for k, h in enumerate(heads))
    return text


def readout_reductions(heads: list[Head]) -> list[str]:
    """final:x(r{k}) per head, the energy dissipated in every readout, and the input work."""
    return ([f"final:x(r{k})" for k in range(len(heads))]
            + [f"dissipated:r{k}" for k in range(len(heads))] + ["work:in"])


def decisions(reds: dict[str, np.ndarray], heads: list[Head]) -> np.ndarray:
    """Row decisions (clips, rows): x_r / scale + intercept, the physical c . Phi + b."""
    return np.stack([reds[f"final:x(r{k})"] / h.scale + h.intercept
                     for k, h in enumerate(heads)], axis=1)


def insertion_loss_db(reds: dict[str, np.ndarray], heads: list[Head]) -> np.ndarray:
    """Per clip: -10 log10(energy dissipated in all readouts / work done by the input)."""
    diss = sum(reds[f"dissipated:r{k}"] for k in range(len(heads)))
    with np.errstate(divide="ignore", invalid="ignore"):
        return -10 * np.log10(diss / reds["work:in"])


def classifier_batch(signals: np.ndarray, checked: CheckedNetlist, specs: list[str],
                     tstop: float, plan: integration.Integration = integration.PAPER,
                     tries: slice = slice(None),
                     s: msp.MassSpringSettings | None = None) -> dict:
    """Readout reductions of one batch through the whole checked classifier (a Dask task),
    integrated as `plan` says (finer steps for clips too loud for it, and with the settings
    `s` of its front end, for clips predicted too stiff for it; `tries` as in
    `integration.run_with_retries`)."""
    from springc.sim.simulate import simulate

    sig = signals.astype(np.float64)[:, None, :]
    stiff = None if s is None else msp.stiffness(signals, s)
    return integration.run_with_retries(plan, lambda method, sub, idx: simulate(
        checked, sig[idx], msp.INPUT_RATE, probes=[], reductions=specs, tstop=tstop,
        chunk=msp.BATCH, batch=len(idx), method=method, substeps=sub,
        precision=plan.precision).reductions, len(sig), tries, stiff)


def choose_classifier_integration(checked: CheckedNetlist, heads: list[Head],
                                  s: msp.MassSpringSettings,
                                  signals: np.ndarray) -> integration.Integration:
    """The cheapest integration of the whole classifier whose readouts x(r_k) are within
    `integration.TOLERANCE` of the tight reference on `signals` (a sample of clips). Double
    precision: the multipliers cancel stiffness to make their zero modes, and in single
    precision the round-off of that cancellation moves the readouts by 2e-2 (measured, 4x2).
    exp-rk4 treats the Mel filters exactly, whose high Q sets RK4's substeps."""
    specs = readout_reductions(heads)
    tstop = msp.horizon(s, signals.shape[1] / msp.INPUT_RATE)

    def outputs(sig, method, substeps, precision):  # one try: loud clips are NaN rows
        reds = classifier_batch(sig, checked, specs, tstop,
                                integration.Integration(method, substeps, precision),
                                slice(0, 1), s)
        return np.stack([reds[f"final:x(r{k})"] for k in range(len(heads))], axis=1)

    return integration.choose(checked, signals, outputs, tstop, precision="float64",
                              methods=CLASSIFIER_METHODS)


def compile_ahead(s: msp.MassSpringSettings) -> None:
    """Start compiling the whole classifier's double-precision kernels (the reference's and
    every candidate method's) on an idle Dask worker, while the features' integration is
    being chosen: otherwise they compile only after the SVM fit, one after the other. A
    kernel depends on the kinds of force terms and on what is reduced, never on the weights,
    so stand-in heads compile the kernels the trained classifier will run (a test checks)."""
    from springc.kws.features.distributed import ahead

    ahead(compile_classifier, s)


def stand_in_heads(s: msp.MassSpringSettings, rows: int = 12) -> list[Head]:
    """Heads of random weights, built like trained ones (the 12 classes of kws12)."""
    from springc.kws.training.svm import LinearModel

    rng = np.random.default_rng(0)
    n = n_features(s.bins, s.delays)
    model = LinearModel(rng.normal(size=(rows, n)), rng.normal(size=rows),
                        np.array([f"c{k}" for k in range(rows)]))
    return heads_for([(tuple(model.classes), model)], s, 1e-5, DEFAULT_EPSILON)


def compile_classifier(s: msp.MassSpringSettings) -> None:
    """Compile (or load) the classifier kernels of `compile_ahead` in this process: the
    stand-in classifier run on 10 ms of silence by each method in double precision."""
    from springc.lang import load_text

    heads = stand_in_heads(s)
    checked = check(load_text(classifier_text(heads, s, epsilon=DEFAULT_EPSILON),
                              "<classifier>"))
    for method in dict.fromkeys((integration.REFERENCE[0],) + CLASSIFIER_METHODS):
        classifier_batch(np.zeros((1, 160)), checked, readout_reductions(heads), 0.01,
                         integration.Integration(method, 2, "float64"), slice(0, 1))


# -- the model folder --------------------------------------------------------------------------

DEFAULT_EPSILON = 1e-5  # squaring error: readouts within ~0.2% of c . Phi (measured)
CLASSIFIER_METHODS = ("exp-rk4", "rk4")
# of those, the clips the classifier's integration is measured on: a whole batch (a kernel
# call costs the same for 4 clips as for 16, its lanes)
CLASSIFIER_SAMPLE = 16


def write_classifier(opts, fits: list, settings: dict,
                     reference: msp.Reference) -> dict[str, str]:
    """Design the heads of trained `fits` for the feature amplitude of `reference` (the
    features' reference run on a sample of training clips), record the transfer in `settings`
    ("transfer") and return the model folder's netlists: features.spr, head{k}.spr,
    classifier.spr."""
    s = opts.massspring
    eps = opts.epsilon or DEFAULT_EPSILON
    design = opts.design or default_design(eps)
    sample, amplitude = reference.signals, reference.amplitude
    heads = heads_for([(f[0], f[1]) for f in fits], s, amplitude, eps, design)
    settings["transfer"] = {"epsilon": eps, "amplitude": amplitude,
                            "heads": [h.name for h in heads],
                            "scales": [h.scale for h in heads],
                            "stiffness_scale": stiffness_scale(s),
                            "design": design.to_dict()}
    plan = integration.PAPER
    if opts.tolerance is not None:
        from springc.lang import load_text

        text = classifier_text(heads, s, epsilon=eps, design=design)
        part = sample[:CLASSIFIER_SAMPLE]
        plan = integration.remembered(
            "classifier's integration", [text, repr(s), integration.signal_key(part)],
            lambda: choose_classifier_integration(check(load_text(text, "<classifier>")),
                                                  heads, s, part))
    settings["transfer"]["integration"] = plan.to_dict()
    files = {"features.spr": msp.feature_text(s),
             "classifier.spr": classifier_text(heads, s, include_heads=False, epsilon=eps,
                                               design=design)}
    for k, h in enumerate(heads):
        files[f"head{k}.spr"] = head_text(k, h, s, len(heads), design.mvm_stiffness)
    return files


def default_design(epsilon: float) -> Design:
    """The heads `springc train` builds at squaring error `epsilon` unless told: the paper's
    up to BUFFERED_FROM, beyond it `BUFFERED` (the plain heads fail from eps ~ 1e-4 on,
    docs/results-eps.md)."""
    return BUFFERED if epsilon > BUFFERED_FROM else Design()


def tuned_heads(heads: list[Head], couplings: list | None,
                intercepts: list | None) -> list[Head]:
    """The heads with `springc tune`'s factors: coupling e of head k gets g f and a / f
    (f = couplings[k][e]; the readout's stiffness g a stays, the squaring strength moves),
    and the intercepts replaced. None: as transferred."""
    out = []
    for k, h in enumerate(heads):
        f = np.asarray(couplings[k], np.float64) if couplings is not None else 1.0
        b = float(intercepts[k]) if intercepts is not None else h.intercept
        out.append(replace(h, gamma=h.gamma * f, alpha=h.alpha / f, intercept=b))
    return out


def model_design(model) -> Design:
    """The design a mass-spring model's heads were built with (settings.json's transfer
    "design"; none recorded: the paper's)."""
    return Design.from_dict(model.settings.get("transfer", {}).get("design"))


def model_heads(model) -> tuple[msp.MassSpringSettings, list[Head]]:
    """The settings and heads of a trained mass-spring model (re-derived, deterministic; a
    tuned model's refitted weights and factors from settings.json's "transfer": "refit",
    then "couplings", "intercepts")."""
    from springc.errors import DataError

    feats = {k: v for k, v in model.settings["features"].items() if k != "realisation"}
    tr = model.settings.get("transfer")
    try:
        s = msp.MassSpringSettings(**feats)
        amplitude, epsilon = float(tr["amplitude"]), float(tr["epsilon"])
        heads = heads_for(model.models, s, amplitude, epsilon, model_design(model))
        if tr.get("refit"):
            refit = tr["refit"]
            heads = reweighted_heads(heads, refit["weights"], refit["intercepts"], s,
                                     amplitude, epsilon)
        heads = tuned_heads(heads, tr.get("couplings"), tr.get("intercepts"))
    except (TypeError, KeyError, ValueError) as exc:
        raise DataError(str(model.folder / "settings.json"),
                        f"not a mass-spring model ({exc})") from None
    return s, heads
