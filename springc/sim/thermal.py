"""Transient thermal noise: the temperature and seed of a simulation, and the arrays of its
kernel's noise forces (`springc.kernels.thermal` writes the code that draws them).

By the fluctuation-dissipation theorem a damper b at temperature T is a white force of
one-sided PSD 4 k_B T b; held over an integration step h it is a draw of variance
2 k_B T b / h per step. A netlist without `.options temp=` (or with temp=0) has no noise, and
its kernel no noise code.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from springc.errors import UsageError
from springc.lang.ir import FlatNetlist
from springc.lang.options import KNOWN_OPTIONS, OptionValueError

K_B = 1.380649e-23  # J/K, the Boltzmann constant (exact in the SI since 2019)


def with_overrides(net: FlatNetlist, temp: float | None, seed: int | None) -> FlatNetlist:
    """`net` with the temperature and seed of the caller (None: the netlist's), each checked
    as `.options` checks it (a `UsageError` naming the value)."""
    if temp is None and seed is None:
        return net
    options = dict(net.options)
    for key, value in (("temp", temp), ("seed", seed)):
        if value is None:
            continue
        try:
            options[key] = KNOWN_OPTIONS[key].convert(value)
        except (OptionValueError, ValueError, TypeError) as exc:
            raise UsageError(str(exc)) from None
    if options.get("temp", 0.0) > 0 and not ((net.masses.b > 0).any()
                                             or (net.dashpots.b > 0).any()):
        raise UsageError(f"temp={options['temp']:g} K asks for thermal noise, but "
                         f"{net.file} has no damper",
                         hint="give a mass a damping b= or add a B dashpot: thermal noise "
                              "comes from dissipation")
    return replace(net, options=options)


def temperature(net: FlatNetlist) -> float:
    """The netlist's temperature in kelvin (0: no thermal noise)."""
    return float(net.options.get("temp", 0.0))


def noise_arrays(net: FlatNetlist, h: float, dtype) -> dict[str, object]:
    """The kernel's noise arguments (`springc.kernels.thermal.NOISE_ARGS` but `run0`, which
    each call sets) for step `h`: the dampers with b > 0, `M ... b=` (to ground) then `B`
    dashpots, as `springc.analyses.noise.dissipative` lists them, each with
    sigma = sqrt(2 k_B T b / h) over the mass of its nodes, and the noisy nodes."""
    m, d = net.masses, net.dashpots
    damped, pots = np.flatnonzero(m.b > 0), np.flatnonzero(d.b > 0)
    i = np.concatenate([m.node[damped], d.i[pots]]).astype(np.int64)
    j = np.concatenate([np.full(len(damped), -1), d.j[pots]]).astype(np.int64)
    b = np.concatenate([m.b[damped], d.b[pots]])
    sigma = np.sqrt(2.0 * K_B * temperature(net) * b / h)
    mass = net.mass()
    sj = np.where(j >= 0, sigma / mass[np.maximum(j, 0)], 0.0)
    seed = int(net.options.get("seed", 0))
    return {
        "nz_node": np.unique(np.concatenate([i, j[j >= 0]])).astype(np.uint64),
        "nz_i": i.astype(np.uint64), "nz_j": j,
        "nz_si": np.ascontiguousarray(sigma / mass[i], dtype),
        "nz_sj": np.ascontiguousarray(sj, dtype),
        "nz_seed": np.uint64(seed),
    }
