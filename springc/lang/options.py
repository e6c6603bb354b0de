"""The keys `.options` accepts, what each means and which values are valid.

An unknown key or a bad value is an error at its position, never ignored: a misspelt
`.options methd=rk38` must not silently run RK4.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from springc.kernels.integrators import TABLEAUX


class OptionValueError(ValueError):
    """A value an option does not accept; the message says which values it does."""


@dataclass(frozen=True)
class OptionSpec:
    """One `.options` key: `word` options take a bare word (`method=rk4`), the others a
    number; `convert` checks the raw value and returns what goes into `FlatNetlist.options`."""

    name: str
    word: bool
    description: str
    convert: Callable[[object], object]


def known_methods() -> list[str]:
    """Every integrator name: the Runge-Kutta tableaux, then the splitting schemes."""
    # imported here: expint pulls in scipy.linalg, which parsing a netlist does not need
    from springc.kernels.expint import SCHEMES

    return [*TABLEAUX, *SCHEMES]


def method_name(raw: object) -> str:
    """The canonical name of an integrator (`exp_rk4`, `EXP-RK4` -> `exp-rk4`), or
    `OptionValueError` listing every known one. The split schemes are spelt with '-' on the
    command line, but a bare word in a netlist is a name (`[A-Za-z_][A-Za-z0-9_]*`), so
    `.options` takes `method=exp_rk4` or the quoted `method="exp-rk4"`."""
    name = str(raw).lower()
    known = known_methods()
    if name not in known and name.replace("_", "-") in known:
        name = name.replace("_", "-")
    if name not in known:
        spelt = ", ".join(m.replace("-", "_") for m in known if "-" in m)
        raise OptionValueError(f"unknown integration method '{raw}'; known: {', '.join(known)} "
                               f"(write {spelt} or quote the name in .options)")
    return name


def _precision(raw: object) -> str:
    name = str(raw).lower()
    if name not in ("float32", "float64"):
        raise OptionValueError(f"precision must be float32 or float64, not '{raw}'")
    return name


def _substeps(raw: object) -> int:
    value = float(raw)
    if not value.is_integer() or value < 1:
        raise OptionValueError(f"substeps must be an integer >= 1, not {value:g}")
    return int(value)


def _outrate(raw: object) -> float:
    value = float(raw)
    if not value > 0:
        raise OptionValueError(f"outrate must be a positive rate in Hz, not {value:g}")
    return value


def temperature(raw: object) -> float:
    """A temperature in kelvin: finite and >= 0 (0: no thermal noise)."""
    value = float(raw)
    if not (math.isfinite(value) and value >= 0):
        raise OptionValueError(f"temp must be a finite temperature >= 0 K, not {value:g}")
    return value


def _seed(raw: object) -> int:
    value = float(raw)
    if not value.is_integer() or not 0 <= value < 2**63:
        raise OptionValueError(f"seed must be an integer >= 0, not {value:g}")
    return int(value)


KNOWN_OPTIONS: dict[str, OptionSpec] = {
    spec.name: spec
    for spec in (
        OptionSpec("method", True, "integrator (default rk4): a tableau of integrators.TABLEAUX "
                   "or a split scheme of expint.SCHEMES, written exp_rk4 or \"exp-rk4\"",
                   method_name),
        OptionSpec("substeps", False, "integration steps per .tran step (integer >= 1)",
                   _substeps),
        OptionSpec("precision", True, "float32 or float64", _precision),
        OptionSpec("outrate", False, "probe output rate in Hz (> 0)", _outrate),
        OptionSpec("temp", False, "temperature in kelvin of the dampers' thermal noise "
                   "(finite, >= 0; default: no noise; .noise takes 300 K without it)",
                   temperature),
        OptionSpec("seed", False, "seed of the random draws (integer >= 0, default 0)", _seed),
    )
}
