"""Gradients of streaming reductions with respect to netlist parameters.

In: a netlist file (`ParamNetlist.load`), reductions as `springc sim --reduce` writes them
(`final:x(N)`, `msq:x(N)[:T0:T1]`, `work:in`, `dissipated:NAME`, `loss:NAME`,
`gram:TAU:N1,N2,...`), top-level `.param` names, the inputs `simulate` takes.
Out: `gradient(...)` -> `GradResult`: each reduction's value per run and d(value)/d(param)
per run, exact for the discrete computation the simulator does (same tableau, step and
input interpolation, in float64), by the discrete adjoint of the Runge-Kutta step
(`adjoint`) chained with the exact parameter -> coefficient Jacobian (`params`, `derive`).
`coefficient_gradient(checked, ...)` gives d(value)/d(every element coefficient) for a
checked netlist; `legal` maps unconstrained optimiser variables to parameter values that
keep every check satisfied. How it works and what was measured: docs/gradients.md.
"""

from springc.grad.gradient import (CoefficientGradient, GradResult, coefficient_gradient,
                                   gradient)
from springc.grad.params import ParamNetlist

__all__ = ["CoefficientGradient", "GradResult", "ParamNetlist", "coefficient_gradient",
           "gradient"]
