"""A design made in normalised units (unit masses, unit displacements) at a physical scale.

With every mass multiplied by `mass` (mu, kg per normalised mass unit) and every displacement
by `length` (lambda, m per normalised length unit), time unchanged, the same dynamics
m x'' + b x' + dV/dx = F hold for x' = lambda x when each coefficient is multiplied by its
degree's factor (forces scale as mu lambda, energies as mu lambda^2):

    element                      coefficient                  factor
    M  m, b                      mass, damping                mu
    M  x0, v0                    initial state                lambda
    K  k, C  k, B  b             degree 2 (and dashpots)      mu
    C  a                         leverage (dimensionless)     1
    D  l                         degree 4                     mu / lambda^2
    Q  g, a (x_i^2 - a x_j)      g, the leverage a (a length) mu / lambda, lambda
    P  c (total degree d)        degree d                     mu lambda^(2 - d)
    F  gain                      force                        mu lambda

`scale_netlist` applies the table; `flat_text` writes the result as a flat `.spr` file
(every coefficient as a number, full precision), so `springc design scale` can hand it on.
With a sound-pressure level and an area, the `in(k)` forces become the acoustic force on a
membrane: see `acoustic_gains`.
"""

from __future__ import annotations

import math
import re
from dataclasses import replace

import numpy as np

from springc.errors import UsageError
from springc.lang.ir import GROUND, FlatNetlist, Source

P_REF = 20e-6  # Pa: the reference of sound-pressure level (0 dB SPL)


def scale_netlist(net: FlatNetlist, mass: float, length: float) -> FlatNetlist:
    """`net` with every coefficient multiplied by its factor (module docstring)."""
    _require_positive(mass=mass, length=length)
    mu, lam = mass, length
    p = net.monomials
    degree = np.array([p.exp[p.ptr[e]:p.ptr[e + 1]].sum() for e in range(len(p))], float)
    return replace(
        net,
        masses=replace(net.masses, m=net.masses.m * mu, b=net.masses.b * mu,
                       x0=net.masses.x0 * lam, v0=net.masses.v0 * lam),
        springs=replace(net.springs, k=net.springs.k * mu),
        couplings=replace(net.couplings, k=net.couplings.k * mu),
        dashpots=replace(net.dashpots, b=net.dashpots.b * mu),
        duffings=replace(net.duffings, l=net.duffings.l * mu / lam**2),
        quads=replace(net.quads, g=net.quads.g * mu / lam, a=net.quads.a * lam),
        monomials=replace(p, c=p.c * mu * lam ** (2.0 - degree)),
        forces=replace(net.forces, gain=net.forces.gain * mu * lam),
    )


def acoustic_gains(net: FlatNetlist, spl_db: float, area: float) -> FlatNetlist:
    """The `in(k)` forces as sound pressure on a membrane of `area` (m^2) at `spl_db` (dB re
    20 uPa): an input of unit RMS (the level the keyword-spotting clips are normalised to)
    becomes a force of RMS p A on the node with the largest `in` gain, and every other `in`
    gain keeps its ratio to that one (the filter design's relative gains)."""
    _require_positive(area=area)
    if not math.isfinite(spl_db):
        raise UsageError(f"--spl must be a finite level in dB, not {spl_db:g}")
    driven = np.array([s.kind == "in" for s in net.forces.source], bool)
    if not driven.any():
        raise UsageError("the netlist has no F ... in(k) element for sound to drive",
                         hint="--spl and --area set the gains of the in(k) forces")
    gains = net.forces.gain.copy()
    largest = np.abs(gains[driven]).max()
    pressure = P_REF * 10 ** (spl_db / 20)
    gains[driven] = gains[driven] / largest * pressure * area
    return replace(net, forces=replace(net.forces, gain=gains))


def _require_positive(**values: float) -> None:
    for name, value in values.items():
        if not (math.isfinite(value) and value > 0):
            raise UsageError(f"--{name} must be a positive finite number, not {value:g}")


def flat_text(net: FlatNetlist, comment: str = "") -> str:
    """`net` as a flat `.spr` netlist: one line per element, numbers at full precision.
    Node and element names inside instances (`X1.a`) become `X1_a`, made unique."""
    nodes = _plain_names(net.nodes)

    def node(idx: int) -> str:
        return "0" if idx == GROUND else nodes[idx]

    lines = [f"* {line}" for line in comment.splitlines()]
    lines += [f".title {net.title}"] if net.title else []
    lines += _elements(net, node)
    labels = {}
    for pr in net.probes:
        labels[pr.label] = f"{pr.quantity}({node(pr.node)})"
    if labels:
        lines.append(".probe " + " ".join(labels.values()))
    if net.tran:
        lines.append(f".tran {_num(net.tran.tstep)} {_num(net.tran.tstop)}")
    for kind, specs in (("ac", net.acs), ("noise", net.noises)):
        lines += [f".{kind} {node(s.node)} {_num(s.fstart)} {_num(s.fstop)} points={s.points} "
                  f"input={s.input}" for s in specs]
    for key in sorted(net.options):
        value = net.options[key]
        text = f'"{value}"' if isinstance(value, str) else _num(value)
        lines.append(f".options {key}={text}")
    return "\n".join(lines) + "\n"


def probe_names(net: FlatNetlist) -> dict[str, str]:
    """Each probe label of `net` -> its label in `flat_text(net)`."""
    nodes = _plain_names(net.nodes)
    return {pr.label: f"{pr.quantity}({nodes[pr.node]})" for pr in net.probes}


def _elements(net: FlatNetlist, node) -> list[str]:
    names = _ElementNames()
    m, k, d, c, q, b = (net.masses, net.springs, net.duffings, net.couplings, net.quads,
                        net.dashpots)
    out = [f"{names('M', m.names[e])} {node(m.node[e])} m={_num(m.m[e])} b={_num(m.b[e])} "
           f"x0={_num(m.x0[e])} v0={_num(m.v0[e])}" for e in range(len(m))]
    out += [f"{names('K', k.names[e])} {node(k.node[e])} k={_num(k.k[e])}" for e in range(len(k))]
    out += [f"{names('D', d.names[e])} {node(d.node[e])} l={_num(d.l[e])}" for e in range(len(d))]
    out += [f"{names('C', c.names[e])} {node(c.i[e])} {node(c.j[e])} k={_num(c.k[e])} "
            f"a={_num(c.a[e])}" for e in range(len(c))]
    out += [f"{names('Q', q.names[e])} {node(q.i[e])} {node(q.j[e])} g={_num(q.g[e])} "
            f"a={_num(q.a[e])}" for e in range(len(q))]
    out += [f"{names('B', b.names[e])} {node(b.i[e])} {node(b.j[e])} b={_num(b.b[e])}"
            for e in range(len(b))]
    p = net.monomials
    for e in range(len(p)):
        factors = " ".join(f"{node(p.var[i])}^{p.exp[i]}" for i in range(p.ptr[e], p.ptr[e + 1]))
        out.append(f"{names('P', p.names[e])} c={_num(p.c[e])} {factors}")
    f = net.forces
    out += [f"{names('F', f.names[e])} {node(f.node[e])} {_source(f.source[e])} "
            f"gain={_num(f.gain[e])}" for e in range(len(f))]
    return out


class _ElementNames:
    """Element names as the letter of their kind and a plain, unique identifier."""

    def __init__(self) -> None:
        self.used: set[str] = set()

    def __call__(self, letter: str, name: str) -> str:
        plain = re.sub(r"[^A-Za-z0-9_]", "_", name)
        if not plain.upper().startswith(letter) or plain != name:
            plain = f"{letter}_{plain}"
        return _unique(plain, self.used)


def _plain_names(names: list[str]) -> list[str]:
    """Node names without dots (`X1.a` -> `X1_a`), unique."""
    used = {n for n in names if "." not in n}
    return [n if "." not in n else _unique(n.replace(".", "_"), used) for n in names]


def _unique(name: str, used: set[str]) -> str:
    out, k = name, 1
    while out.lower() in {u.lower() for u in used}:
        out, k = f"{name}_{k}", k + 1
    used.add(out)
    return out


def _source(src: Source) -> str:
    if src.kind == "in":
        return f"in({src.channel})"
    if src.kind == "wav":
        return f'wav("{src.path}" {src.channel})'
    return f"{src.kind}({' '.join(_num(a) for a in src.args)})"


def _num(value: float) -> str:
    """Full precision: the number reads back as the same float."""
    return repr(float(value))
