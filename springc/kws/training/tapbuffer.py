"""Buffered delay taps: the heads' couplings held by a static spring instead of the lines.

In the plain classifier (`springc.kws.training.transfer`) every head's mvm sits on the terminal
nodes f{i}_{j} of the delay lines, whose zero modes nothing holds but the lines' impedance
t_s kc w (about kc / 100 at the features' envelopes): the couplings' cubic stiffness and the
readouts' back-action pull the taps from eps ~ 1e-5 on (docs/results-squaring.md). A buffer
puts a node u{i}_{j} between each tap and the heads:

    f{i}_{j}  half a line site with the matched damping t_s kc (the features' termination)
      -- spring kb kc -- u{i}_{j} -- spring kg kc to ground; the heads' mvm inputs on u

Quasi-statically u = g f with the gain g = kb / (kb + kg): the heads see the features scaled by
g, held by the static stiffness (kb + kg) kc instead of the lines' impedance, and the tap sees
the series spring kb kg / (kb + kg) kc to ground, which must stay well below t_s kc w over the
features' band to leave them as the feature network computes them. The heads are designed for
the amplitude g A they see (their eps is that of the couplings themselves) and their decision
scale divided by g^2, so that x_r / scale is still c . Phi of the taps.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from springc.design.emit import SprWriter, num
from springc.kws.features import massspring as msp


@dataclass(frozen=True)
class TapBuffer:
    """The buffer's springs in units of the lines' kc: `kb` from tap to buffer node, `kg` from
    the buffer node to ground."""

    kb: float
    kg: float

    def __post_init__(self) -> None:
        if not (self.kb > 0 and self.kg >= 0):
            raise ValueError(f"tap buffer needs kb > 0 and kg >= 0, got {self.kb}, {self.kg}")

    @property
    def gain(self) -> float:
        """u / f at low frequency: kb / (kb + kg)."""
        return self.kb / (self.kb + self.kg)

    def to_dict(self) -> dict:
        """As settings.json's transfer "tap_buffer" keeps it."""
        return {"kb": self.kb, "kg": self.kg}


def buffer_node(node: str) -> str:
    """The buffer node of terminal node f{i}_{j}: u{i}_{j}."""
    return "u" + node[1:]


def nodes(s: msp.MassSpringSettings) -> list[str]:
    """Buffer nodes in Phi order."""
    return [buffer_node(node) for node in msp.terminals(s)]


def write(w: SprWriter, s: msp.MassSpringSettings, buffer: TapBuffer) -> None:
    """The terminal nodes as the feature network has them (half a site, matched damping) and
    each one's buffer node with its two springs; the heads then supply the buffers' mass."""
    w.comment(f"buffered taps: f -- {buffer.kb:g} kc -- u -- {buffer.kg:g} kc -- ground "
              f"(gain {buffer.gain:.3g}); the heads' mvm inputs sit on u")
    for node in msp.terminals(s):
        u = buffer_node(node)
        w.statement(f"M{node}", node, "m={ts**2 * kc / 2}", "b={ts * kc}")
        w.statement(f"Cb{node}", node, u, f"k={num(buffer.kb * s.kc)}")
        if buffer.kg > 0:
            w.statement(f"Kg{node}", u, f"k={num(buffer.kg * s.kc)}")


def amplitude(buffer: TapBuffer | None, amplitude: float) -> float:
    """The feature amplitude the heads' couplings see: g A with a buffer, A without."""
    return amplitude * (buffer.gain if buffer else 1.0)


def rescaled(heads: list, buffer: TapBuffer | None) -> list:
    """Heads designed for the buffer's amplitude, their scale times g^2: x_r / scale is then
    c . Phi of the taps (the buffer's Gram sums are g^2 the taps')."""
    if buffer is None:
        return heads
    return [replace(h, scale=h.scale * buffer.gain**2) for h in heads]
