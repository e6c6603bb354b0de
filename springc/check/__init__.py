"""The check stage: flat IR in, checked netlist and build report out.

`checks.check(net)` runs the physics checks (signs, the whole potential bounded below and
positive semidefinite at rest, masses, the step against the integrator's stability region);
`linear` is the linearisation they use, `accuracy` the per-mode error estimates, and
`compiler.build(path)` loads, checks and summarises a file for `springc build`.
"""
