"""The keys `.options` accepts, what each means and which values are valid.

An unknown key or a bad value is an error at its position, never ignored: a misspelt
`.options methd=rk38` must not silently run RK4.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from springc.integrators import TABLEAUX


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


def _method(raw: object) -> str:
    name = str(raw).lower()
    if name not in TABLEAUX:
        raise OptionValueError(f"unknown integration method '{raw}'; known: "
                               f"{', '.join(TABLEAUX)}")
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


KNOWN_OPTIONS: dict[str, OptionSpec] = {
    spec.name: spec
    for spec in (
        OptionSpec("method", True, "integrator, a name in integrators.TABLEAUX (default rk4)",
                   _method),
        OptionSpec("substeps", False, "integration steps per .tran step (integer >= 1)",
                   _substeps),
        OptionSpec("precision", True, "float32 or float64", _precision),
        OptionSpec("outrate", False, "probe output rate in Hz (> 0)", _outrate),
    )
}
