"""The router: a keyword spotter that is a linear passive network, so that the sound's energy
reaches its readouts instead of being lost in squarers far below their nonlinear scale.

The network is the Mel filterbank of the mass-spring realisation (two-mode filters,
`netlists/lib/melfilter.spr`'s `routedfilter`) whose damping is split: filter i keeps a
share of it in its own dampers and hands the share W[r, i] to readout r, a pair of dashpots
to ground on its two masses (`Bra{r}_{i}`, `Brb{r}_{i}`). Both masses are damped alike, so
readout r dissipates exactly

    E_r = sum_i W[r, i] D_i,

D_i the energy filter i dissipates over the clip (the clip's power in that band, weighted by
the filter's response). The decision is the readout that dissipates most: a linear
classifier without intercept on the features D, which `springc train --realisation router`
fits (`svm.select(intercept=False)`, on D scaled by its root mean square, which the raw
weights absorb) and `router_weights` makes realisable: adding the same u_i to every class's
weight on D_i moves every score by u . D and no decision, so each column is shifted to a
least weight of 0, and all are scaled by one factor so that no filter hands on more than
all of its damping.

What a linear passive network cannot do, the router does not: its readouts see the clip's
band powers, not when in the clip they came (the time structure the paper's squarers, delay
lines and quadratic activations give), so it classifies from the long-term spectrum alone
(docs/results-device.md: the accuracy and the energy that buys).
"""

from __future__ import annotations

import functools
import re
from dataclasses import asdict, dataclass

import numpy as np

from springc.design.emit import SprWriter, num
from springc.lang.ir import FlatNetlist

ROUTER_VERSION = 2  # in the feature-cache key: bump when the network changes
INPUT_RATE = 16000.0  # Hz: the clips' rate and the `.tran` step
RING_OUT = 0.05  # s simulated after the clip: the filters ring out (alpha >= 400 rad/s)
# How the router is integrated: the Lawson form of RK4 with 4 substeps per sample. On 32
# clips of the built-in corpus its readouts lie within 3.4e-6 of RK4 x16's and its energy
# balance closes to 1.3e-4, at half the time of RK4 x8 (2.4e-5, 1.1e-4); what `springc sim`
# chooses for the bare network, the Lawson form at the sample step, resolves the filters'
# motion but samples the 8 kHz filters' v^2 too coarsely (balance off by up to 13%)
METHOD, SUBSTEPS = "exp-rk4", 4
READOUT = re.compile(r"^Br[ab](\d+)_\d+$")  # a readout dashpot; group 1: its readout


@dataclass(frozen=True)
class RouterSettings:
    """The filterbank of a router: `bins` two-mode Mel filters from `fmin` to `fmax` Hz."""

    bins: int = 16
    fmin: float = 20.0
    fmax: float = 8000.0
    network: int = ROUTER_VERSION

    def to_dict(self) -> dict:
        return asdict(self)


def filters(s: RouterSettings) -> tuple:
    """The fitted two-mode Mel filters (shared with the mass-spring realisation)."""
    from springc.kws.features.digital import melbank_filters

    return melbank_filters(s.bins, "two-mode", s.fmin, s.fmax)


def router_text(s: RouterSettings, weights: np.ndarray | None = None,
                classes: list[str] | None = None, seconds: float = 1.0) -> str:
    """The `.spr` text of the router with `weights` W (readouts, bins), or of the bare
    filterbank (no readouts: every filter keeps all its damping)."""
    w = SprWriter()
    rows = 0 if weights is None else len(weights)
    w.title(f"router: {s.bins} Mel filters, {rows} readouts")
    w.comment(__doc__.split("\n\n")[1])
    if classes is not None:
        w.comment("readouts: " + ", ".join(f"{r} {c}" for r, c in enumerate(classes)))
    w.include("melfilter.spr")
    for i, f in enumerate(filters(s)):
        share = np.zeros(rows) if weights is None else weights[:, i]
        w.statement(f"Xf{i}", f"a{i}", f"y{i}", "routedfilter", f"fa={num(f.fa)}",
                    f"delta={num(f.delta)}", f"alpha={num(f.alpha)}",
                    f"keep={num(max(0.0, 1.0 - share.sum()))}", "ch=0",
                    f"gain={num(f.gain)}")  # max: a full column sums to 1 +- rounding
        for r in np.flatnonzero(share > 0):
            b = num(f.alpha * share[r])
            w.statement(f"Bra{r}_{i}", f"a{i}", "0", f"b={b}")
            w.statement(f"Brb{r}_{i}", f"y{i}", "0", f"b={b}")
    w.statement(".tran", f"{{1/{INPUT_RATE:g}}}", num(seconds + RING_OUT))
    w.statement(".options", f'method="{METHOD}"', f"substeps={SUBSTEPS}")
    return w.text()


def router_network(s: RouterSettings, weights: np.ndarray | None = None) -> FlatNetlist:
    """`router_text` elaborated."""
    from springc.lang import load_text

    return load_text(router_text(s, weights), "<router>")


def filter_reductions(s: RouterSettings) -> list[str]:
    """The reductions whose sums per filter are D: each filter mass's own dissipation."""
    return [f"dissipated:Xf{i}.{m}" for i in range(s.bins) for m in ("Ma", "Mb")]


def readout_reductions(net: FlatNetlist) -> list[str]:
    """The dissipation of every readout dashpot of a router network."""
    return [f"dissipated:{n}" for n in net.dashpots.names if READOUT.match(n)]


def readout_energies(reds: dict[str, np.ndarray], rows: int) -> np.ndarray:
    """E (clips, rows): each readout's dissipated energy, from `readout_reductions`."""
    first = next(iter(reds.values()))
    out = np.zeros((len(first), rows))
    for key, value in reds.items():
        found = READOUT.match(key.removeprefix("dissipated:"))
        if found:
            out[:, int(found.group(1))] += value
    return out


@functools.lru_cache(maxsize=4)
def checked_bank(s: RouterSettings):
    """The bare filterbank, checked once per settings (a feature pass calls for every chunk
    of clips)."""
    from springc.check import check

    return check(router_network(s))


def filter_energies(signals: np.ndarray, s: RouterSettings) -> np.ndarray:
    """D (clips, bins): the energy each filter of the bare filterbank dissipates on each
    clip of `signals` (clips, samples) at 16 kHz, simulated."""
    from springc.sim.simulate import simulate

    sig = np.atleast_2d(np.asarray(signals, dtype=np.float64))
    reds = filter_reductions(s)
    res = simulate(checked_bank(s), sig[:, None, :], INPUT_RATE, probes=[],
                   reductions=reds, tstop=sig.shape[1] / INPUT_RATE + RING_OUT,
                   batch=len(sig))
    r = res.reductions
    return np.stack([r[reds[2 * i]] + r[reds[2 * i + 1]] for i in range(s.bins)], axis=1)


def router_weights(coef: np.ndarray) -> np.ndarray:
    """W (rows, bins) >= 0, no column above a sum of 1, that decides as `coef` (rows, bins)
    does without intercept: argmax_r W[r] . D = argmax_r coef[r] . D for every D."""
    shifted = coef - coef.min(axis=0)
    total = shifted.sum(axis=0).max()
    if not total > 0:
        raise ValueError("a classifier with equal weights for every class decides nothing")
    return shifted / total


def router_file(s: RouterSettings, model) -> dict[str, str]:
    """{"router.spr": the network} of a trained model (`LinearModel` without intercept)."""
    if np.any(model.intercept != 0):
        raise ValueError("a router realises a classifier without intercept")
    weights = router_weights(np.asarray(model.coef, dtype=np.float64))
    return {"router.spr": router_text(s, weights, list(model.classes))}
