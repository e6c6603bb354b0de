"""The check stage: flat IR in, checked netlist out.

`check(net)` runs the physics checks (signs, masses, the whole potential bounded below and
positive semidefinite at rest, the step against the integrator's stability region) and returns
a `CheckedNetlist`, the only type that kernels, the simulator, the analyses and the exporter
accept; it raises `CheckError` with every failed check. `linear` is the linearisation the
checks use, `accuracy` the per-mode error estimates, and `compiler.build(path)` loads, checks
and summarises a file for `springc build`.
"""

from springc.check.checks import CheckedNetlist, check

__all__ = ["CheckedNetlist", "check"]
