"""Thermal noise at rest (`springc noise`, `.noise`).

By the fluctuation-dissipation theorem every damper b at temperature T is a white force of
one-sided power spectral density 4 k_B T b (N^2/Hz): on the node of an `M ... b=` element,
and on the two nodes of a `B` dashpot with opposite signs. Through the linearisation at rest,
G(w) = K - w^2 M + i w B, node o moves by x_o = g^T f with g = G^-1 e_o (G is symmetric), so
one solve per frequency gives every source's transfer h_s = d_s^T g and the displacement PSD
S_o = sum_s 4 k_B T b_s |h_s|^2 (m^2/Hz). The input-referred noise divides S_o by |H|^2, the
response to input channel k as `springc ac` defines it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from springc.analyses import ac
from springc.check import linear
from springc.check.checks import CheckedNetlist, require_checked
from springc.errors import UsageError
from springc.lang.ir import GROUND, FlatNetlist
from springc.lang.options import temperature
from springc.sim.results import atomic_path
from springc.sim.thermal import K_B

DEFAULT_TEMP = 300.0  # K, where neither the caller nor `.options temp=` sets one


@dataclass(frozen=True)
class Source:
    """One dissipative element: its name, nodes (`j` GROUND for a damper to ground) and b."""

    name: str
    i: int
    j: int
    b: float


@dataclass
class NoiseResult:
    """Displacement PSD `psd` (m^2/Hz) of `node` at `f_hz`, each source's share, and the
    input-referred PSD (None where the netlist has no input on that channel)."""

    node: str
    temp: float
    f_hz: np.ndarray
    psd: np.ndarray
    sources: dict[str, np.ndarray]
    input_referred: np.ndarray | None
    channel: int

    @property
    def rms(self) -> float:
        """RMS displacement over the band (m): the square root of the PSD's integral."""
        return math.sqrt(float(np.trapezoid(self.psd, self.f_hz)))

    def to_json(self) -> dict:
        """`{"f", "psd", "sources", "rms", "input_referred"}` and the node and temperature."""
        ref = None if self.input_referred is None else self.input_referred.tolist()
        return {"node": self.node, "temp": self.temp, "f": self.f_hz.tolist(),
                "psd": self.psd.tolist(),
                "sources": {k: v.tolist() for k, v in self.sources.items()},
                "rms": self.rms, "input_referred": ref, "input": self.channel}

    def plot(self, path: str | Path | None = None, *, ax=None, largest: int = 5):
        """Log-log PSD: the total and the `largest` contributors (by their band integral),
        on the matplotlib Axes `ax` where given, else on a new figure. Returns the new
        figure (written as a PNG too where `path` is given), or `ax` as given (its figure
        written to `path` where given)."""
        from springc.sim.results import plot_into

        return plot_into(lambda axes: draw(self, axes, largest), ax, path, dpi=100)

    def to_xarray(self):
        """An `xarray.Dataset` over frequency `f` (Hz): `psd` and each source's `share`
        (m^2/Hz, over `source` too), `input_referred` (1/Hz: the PSD of an input in(k), a
        number, that moves the node as much; absent where there is none) and `rms` (m);
        coordinate `temp` (K)."""
        import xarray as xr

        psd = {"units": "m^2/Hz", "long_name": f"displacement PSD of {self.node}"}
        data = {"psd": ("f", self.psd, psd),
                "share": (("source", "f"), np.array(list(self.sources.values())),
                          psd | {"long_name": "each damper's share of the PSD"}),
                "rms": ((), self.rms, {"units": "m", "long_name": "RMS over the band"})}
        if self.input_referred is not None:
            data["input_referred"] = ("f", self.input_referred, {
                "units": "1/Hz", "long_name": f"input-referred PSD, in({self.channel})"})
        coords = {"f": ("f", self.f_hz, {"units": "Hz", "long_name": "frequency"}),
                  "source": list(self.sources), "temp": ((), self.temp, {"units": "K"})}
        return xr.Dataset(data, coords=coords, attrs={"node": self.node, "input": self.channel})


def dissipative(net: FlatNetlist) -> list[Source]:
    """Every element with damping b > 0: `M ... b=` to ground, then `B` dashpots."""
    m, d = net.masses, net.dashpots
    out = [Source(m.names[e], int(m.node[e]), GROUND, float(m.b[e]))
           for e in range(len(m)) if m.b[e] > 0]
    out += [Source(d.names[e], int(d.i[e]), int(d.j[e]), float(d.b[e]))
            for e in range(len(d)) if d.b[e] > 0]
    return out


def resolve_temp(net: FlatNetlist, temp: float | None) -> float:
    """The temperature: as given, else `.options temp=`, else `DEFAULT_TEMP`; it must be
    above 0 K, where there is no thermal noise to analyse."""
    if temp is None:
        temp = float(net.options.get("temp", DEFAULT_TEMP))
    try:
        temp = temperature(temp)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if temp == 0:
        raise UsageError("temperature 0 K: there is no thermal noise",
                         hint="give --temp or .options temp= in kelvin")
    return temp


def noise(checked: CheckedNetlist, node: str, f_hz: np.ndarray, temp: float | None = None,
          channel: int | None = None) -> NoiseResult:
    """The thermal-noise PSD of `node` at frequencies `f_hz` (module docstring). `channel`:
    the input the input-referred noise is referred to (None: channel 0 where it is used)."""
    net = require_checked(checked, "noise").net
    if node not in net.nodes:
        raise UsageError(f"unknown node '{node}'", hint=ac.near(net, node))
    found = dissipative(net)
    if not found:
        raise UsageError("the netlist has no damper: thermal noise comes from dissipation",
                         hint="give a mass a damping b= or add a B dashpot")
    temp = resolve_temp(net, temp)
    f_hz = np.asarray(f_hz, dtype=np.float64)
    g = _transfers(linear.linearise(net), net.nodes.index(node), 2 * np.pi * f_hz)
    shares = {s.name: 4 * K_B * temp * s.b * np.abs(_at(g, s.i) - _at(g, s.j)) ** 2
              for s in found}
    psd = np.sum(list(shares.values()), axis=0)
    used = channel if channel is not None else 0
    referred = None
    if channel is not None or _driven(net, used):
        h = g @ ac.input_vector(net, used)
        referred = psd / np.abs(h) ** 2
    return NoiseResult(node, temp, f_hz, psd, shares, referred, used)


def _driven(net: FlatNetlist, channel: int) -> bool:
    """Whether some `F` element is driven by in(channel)."""
    return any(s.kind == "in" and s.channel == channel for s in net.forces.source)


def _at(g: np.ndarray, node: int) -> np.ndarray | float:
    """Column `node` of the transfers (0 for ground)."""
    return 0.0 if node == GROUND else g[:, node]


def _transfers(lin: linear.Linearisation, target: int, w: np.ndarray) -> np.ndarray:
    """g(w) = G(w)^-1 e_target for every w, shape (len(w), n): batched dense solves for
    small networks, one sparse factorisation per frequency for large ones (as `ac`)."""
    n = lin.M.shape[0]
    e = np.zeros(n, complex)
    e[target] = 1.0
    if n <= ac.DENSE_MAX:
        k, m, b = lin.K.toarray(), lin.M.toarray(), lin.B.toarray()
        system = k[None] - w[:, None, None] ** 2 * m[None] + 1j * w[:, None, None] * b[None]
        return np.linalg.solve(system, np.broadcast_to(e, (len(w), n))[..., None])[..., 0]
    k, m, b = (x.astype(complex).tocsc() for x in (lin.K, lin.M, lin.B))
    return np.stack([sla.spsolve(sp.csc_matrix(k - ww**2 * m + 1j * ww * b), e) for ww in w])


def sweep(net: FlatNetlist, fmin: float | None, fmax: float | None,
          points: int | None) -> ac.Sweep:
    """The band: as given, else the `.noise` directive's, else `springc ac`'s default."""
    spec = net.noises[0] if net.noises else None
    base = ac.Sweep(spec.fstart, spec.fstop, spec.points) if spec else ac.default_sweep(net)
    return ac.override(base, fmin, fmax, points)


def target(net: FlatNetlist, node: str | None, channel: int | None) -> tuple[str, int | None]:
    """(output node, input channel): as given, else the `.noise` directive's."""
    spec = net.noises[0] if net.noises else None
    if node is None:
        if spec is None:
            raise UsageError("no output node: give --node or a .noise directive")
        node = net.nodes[spec.node]
    if channel is None and spec is not None:
        channel = spec.input if _driven(net, spec.input) else None
    return node, channel


def write_csv(result: NoiseResult, path: str | Path) -> None:
    """Columns `f_hz,psd_m2_per_hz[,input_referred],<source>...`, written atomically."""
    cols = {"f_hz": result.f_hz, "psd_m2_per_hz": result.psd}
    if result.input_referred is not None:
        cols["input_referred"] = result.input_referred
    cols |= {f"psd:{name}": share for name, share in result.sources.items()}
    lines = [",".join(cols)] + [",".join(repr(float(c[r])) for c in cols.values())
                                for r in range(len(result.f_hz))]
    with atomic_path(path, ".csv") as tmp:
        tmp.write_text("\n".join(lines) + "\n")


def plot(result: NoiseResult, path: str | Path, largest: int = 5) -> None:
    """PNG of `NoiseResult.plot`, written atomically."""
    result.plot(path, largest=largest)


def draw(result: NoiseResult, ax, largest: int = 5) -> None:
    """The total PSD and the `largest` contributors (by their band integral) on Axes `ax`,
    log-log."""
    ax.loglog(result.f_hz, result.psd, "k", lw=1.6, label="total")
    ranked = sorted(result.sources.items(), key=lambda kv: -np.trapezoid(kv[1], result.f_hz))
    for name, share in ranked[:largest]:
        ax.loglog(result.f_hz, share, lw=0.9, label=name)
    ax.set(xlabel="f (Hz)", ylabel="displacement PSD (m$^2$/Hz)",
           title=f"thermal noise at {result.node}, {result.temp:g} K, "
                 f"RMS {result.rms:.3g} m")
    ax.legend(fontsize="small")
