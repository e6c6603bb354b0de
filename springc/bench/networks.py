"""Reference networks built in code (`IRBuilder`) for benchmarks and tests.

`kws_network()` is sized like the paper's keyword spotter: 8 two-mode Mel filter
pairs driven from `in(0)`, 8 low-pass (envelope) masses fed by quadratic couplings, 24 delay
lines, a 48-mass all-to-all block and a quadratically coupled readout: 564 degrees of freedom.
"""

from __future__ import annotations

import numpy as np

from springc.design.filters import hz_to_mel, mel_to_hz
from springc.lang.ir import FlatNetlist, IRBuilder, Source, Tran

KWS_RATE = 32000.0  # Hz: the integration grid of the benchmark


def filter_pair(b: IRBuilder, name: str, fa: float, delta: float = 1.1,
                alpha: float = 400.0) -> str:
    """A two-mode band-pass filter (the first example of docs/language.md): unit masses,
    springs wa^2, coupling (wb^2 - wa^2)/2, damping alpha, forces of opposite sign from in(0).
    Returns the output."""
    wa = 2 * np.pi * fa
    xa, xb = f"{name}a", f"{name}b"
    for node in (xa, xb):
        b.mass(f"M{node}", node, 1.0, alpha)
        b.spring(f"K{node}", node, wa**2)
    b.coupling(f"C{name}", xa, xb, (delta**2 - 1) * wa**2 / 2)
    b.force(f"F{xa}", xa, Source("in", channel=0), alpha * (1 + delta**2) * wa**2 * 1e-3)
    b.force(f"F{xb}", xb, Source("in", channel=0), alpha * (1 - delta**2) * wa**2 * 1e-3)
    return xa


def delay_line(b: IRBuilder, name: str, start: str, sites: int, td: float,
               kc: float) -> str:
    """A chain of `sites` masses m = td^2 kc joined by springs kc, driven from `start`,
    weak grounding springs 1e-6 kc, matched damping sqrt(m kc) at the end. Returns the end."""
    m = td**2 * kc
    prev = start
    for s in range(sites):
        node = f"{name}_{s}"
        last = s == sites - 1
        b.mass(f"M{node}", node, m, np.sqrt(m * kc) if last else 0.0)
        b.spring(f"K{node}", node, 1e-6 * kc)
        b.coupling(f"C{node}", prev, node, kc)
        prev = node
    return prev


def kws_network(bands: int = 8, lines_per_band: int = 3, block: int = 24,
                extra_sites: int = 11) -> FlatNetlist:
    """The ~564-dof keyword-spotting-sized benchmark network (see the module docstring)."""
    b = IRBuilder("kws-sized benchmark network", "<bench_networks.kws_network>")
    centres = mel_to_hz(np.linspace(hz_to_mel(100.0), hz_to_mel(6000.0), bands))
    ends = []
    for k, fa in enumerate(centres):
        out = filter_pair(b, f"f{k}", fa)
        lp = f"lp{k}"
        wl = 2 * np.pi * 30.0
        b.mass(f"M{lp}", lp, 1.0, 1.4 * wl)
        b.spring(f"K{lp}", lp, wl**2)
        b.quad(f"Q{lp}", out, lp, 1e5)
        for j in range(lines_per_band):
            line = k * lines_per_band + j
            sites = 20 + (line < extra_sites)
            ends.append(delay_line(b, f"d{line}", lp, sites, td=(1 + j) * 5e-5, kc=1e4))
    _all_to_all_block(b, ends, block)
    b.mass("Mread", "read", 1.0, 200.0)
    b.spring("Kread", "read", (2 * np.pi * 20.0) ** 2)
    for k in range(block):
        b.quad(f"Qread{k}", f"out{k}", "read", 1e5)
    b.probe("x", "read")
    b.probe("x", "f0a")
    b.probe("x", "lp3")
    b.tran = Tran(1.0 / KWS_RATE, 1.0, None)
    return b.finish()


def _all_to_all_block(b: IRBuilder, ends: list[str], block: int) -> None:
    """`block` input masses (coupled to the delay-line ends) and `block` outputs, every pair
    of the 2*block masses coupled."""
    nodes = [f"in{k}" for k in range(block)] + [f"out{k}" for k in range(block)]
    w = 2 * np.pi * 10.0
    for node in nodes:
        b.mass(f"M{node}", node, 1.0, 50.0)
        b.spring(f"K{node}", node, w**2)
    for k, end in enumerate(ends[:block]):
        b.coupling(f"Cin{k}", end, f"in{k}", 1e4)
    rng = np.random.default_rng(7)
    for p in range(len(nodes)):
        for q in range(p + 1, len(nodes)):
            b.coupling(f"Cb{p}_{q}", nodes[p], nodes[q], 50.0 * rng.uniform(0.5, 1.5))


def duffing_resonator(f0: float = 50.0, zeta: float = 0.02, lam: float = 1e6,
                      amp: float = 100.0) -> FlatNetlist:
    """One damped Duffing oscillator driven by a sine near resonance."""
    b = IRBuilder("Duffing resonator", "<bench_networks.duffing_resonator>")
    w0 = 2 * np.pi * f0
    b.mass("M1", "a", 1.0, 2 * zeta * w0)
    b.spring("K1", "a", w0**2)
    b.duffing("D1", "a", lam)
    b.force("F1", "a", Source("sin", (amp, f0)))
    b.probe("x", "a")
    b.tran = Tran(1e-4, 0.5, None)
    return b.finish()


def long_delay_line(sites: int = 200, td: float = 1e-4, kc: float = 1e4) -> FlatNetlist:
    """A long delay line driven from in(0) at its first mass, matched at the end."""
    b = IRBuilder("long delay line", "<bench_networks.long_delay_line>")
    m = td**2 * kc
    b.mass("Mhead", "head", m, 0.0)
    b.force("Fhead", "head", Source("in", channel=0), kc)
    end = delay_line(b, "d", "head", sites, td, kc)
    b.probe("x", "head")
    b.probe("x", end)
    b.tran = Tran(td / 2, sites * td * 2, None)
    return b.finish()


# -- the keyword-spotting pipeline's own networks --------------------------------------------

def pipeline_features(bins: int = 8, delays: int = 3) -> FlatNetlist:
    """The feature network `springc train --realisation mass-spring` simulates
    (`springc.kws.features.massspring.feature_text`: 488 masses at 8x3), probed on its first, middle
    and last terminal nodes (what Phi is made of)."""
    from springc.kws.features import massspring as msp
    from springc.lang import load_text

    s = msp.MassSpringSettings(bins=bins, delays=delays)
    ends = msp.terminals(s)
    probes = [ends[0], ends[len(ends) // 2], ends[-1]]
    text = msp.feature_text(s) + "".join(f".probe x({p})\n" for p in probes)
    return load_text(text, "<bench_networks.pipeline_features>")


def pipeline_classifier(bins: int = 8, delays: int = 3, heads: int = 12,
                        seed: int = 0) -> FlatNetlist:
    """The whole classifier `springc eval` simulates for a mass-spring model
    (`springc.kws.training.transfer.classifier_text`: front end and `heads` heads, 788 masses at
    8x3),
    its heads designed from random classifier rows (a trained model's weights change the
    coefficients, not the work), probed on three readouts."""
    from springc.kws.features import massspring as msp
    from springc.kws.features.phi import n_features
    from springc.kws.training.svm import LinearModel
    from springc.kws.training.transfer import DEFAULT_EPSILON, classifier_text, heads_for
    from springc.lang import load_text

    s = msp.MassSpringSettings(bins=bins, delays=delays)
    rng = np.random.default_rng(seed)
    rows = LinearModel(rng.standard_normal((heads, n_features(bins, delays))),
                       rng.standard_normal(heads), np.array([f"c{k}" for k in range(heads)]))
    amplitude = 1e-3  # m: a typical peak terminal displacement of the built-in corpus
    hs = heads_for([(list(rows.classes), rows)], s, amplitude, DEFAULT_EPSILON)
    probes = [0, heads // 2, heads - 1]
    text = classifier_text(hs, s) + "".join(f".probe x(r{k})\n" for k in probes)
    return load_text(text, "<bench_networks.pipeline_classifier>")
