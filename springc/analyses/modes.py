"""Modes of the linearisation at rest (`springc modes`): eigenfrequencies, damping rates,
Q factors, dominant nodes and the zero-stiffness modes, as text or JSON."""

from __future__ import annotations

import math

from springc.check import linear
from springc.check.checks import CheckedNetlist, require_checked


def mode_report(checked: CheckedNetlist, count: int | None = None) -> dict:
    """The `count` slowest modes (all if None) and the zero modes of the checked netlist (the
    modes its check computed), as a JSON-ready dict."""
    net = require_checked(checked, "mode_report").net
    found = checked.modes
    shown = range(len(found)) if count is None else range(min(count, len(found)))
    rows = [_row(found.mode(k)) for k in shown]
    return {
        "file": net.file,
        "dofs": net.n,
        "omega_max": found.omega_max,
        "modes": rows,
        "total_modes": len(found),
        "complete": found.complete,
        "zero_modes": [{"count": z.count, "at_least": z.at_least,
                        "dominant": [n for n, _ in z.nodes]} for z in found.zero_modes],
    }


def _row(mode: linear.Mode) -> dict:
    return {
        "freq_hz": mode.freq_hz,
        "omega": mode.omega,
        "damping_rate": mode.damping_rate,
        "q": mode.q if math.isfinite(mode.q) else None,
        "oscillating": mode.lam.imag > 0,
        "dominant": [{"node": n, "amplitude": a} for n, a in mode.dominant()],
    }


def mode_text(report: dict) -> str:
    """A table for people."""
    lines = [f"{report['file']}: {report['dofs']} dofs, {report['total_modes']} modes"
             + ("" if report["complete"] else " (large components: fastest modes only)"),
             (f"{'#':>4} {'f (Hz)':>12} {'omega (rad/s)':>14} {'rate (1/s)':>11} {'Q':>9}  "
              "dominant nodes")]
    for idx, row in enumerate(report["modes"]):
        q = "inf" if row["q"] is None else f"{row['q']:.4g}"
        nodes = ", ".join(f"{d['node']} ({d['amplitude']:.2f})" for d in row["dominant"])
        kind = "" if row["oscillating"] else "  [overdamped]"
        lines.append(f"{idx:>4} {row['freq_hz']:>12.6g} {row['omega']:>14.6g} "
                     f"{row['damping_rate']:>11.4g} {q:>9}  {nodes}{kind}")
    for zero in report["zero_modes"]:
        more = "at least " if zero["at_least"] else ""
        lines.append(f"zero modes: {more}{zero['count']} (free motion), dominant nodes "
                     f"{', '.join(zero['dominant'])}")
    return "\n".join(lines)
