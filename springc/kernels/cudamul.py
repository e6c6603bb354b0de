"""Products that a GPU rounds on their own: `mul_rn(a, b)` is `a * b` with numba's types
(int64 * float32 is a float64 product, as on the CPU), compiled to PTX `mul.rn`, which NVVM
never fuses with an add into a fused multiply-add. numba-cuda offers no switch for NVVM's
contraction (NVIDIA/numba-cuda#118), so the CUDA form's text calls this for every product
when `springc.kernels.cuda.CudaOptions.fma` is False, and a GPU run then rounds each
operation as the CPU kernels compiled without contraction do. Under numba's CUDA simulator
it is the Python product."""

from __future__ import annotations

import operator

from numba import config

if config.ENABLE_CUDASIM:
    def mul_rn(a, b):
        """a * b (the simulator runs the kernels as Python)."""
        return a * b
else:
    from llvmlite import ir
    from numba import types
    from numba.core import cgutils
    from numba.cuda.extending import intrinsic

    _ROUNDED = {types.float64: "llvm.nvvm.mul.rn.d", types.float32: "llvm.nvvm.mul.rn.f"}

    @intrinsic
    def mul_rn(typingctx, a, b):
        """a * b typed as numba types it; a floating product as NVVM's round-to-nearest
        multiply, which is never contracted."""
        sig = typingctx.resolve_function_type(operator.mul, (a, b), {})
        out = sig.return_type

        def codegen(context, builder, signature, args):
            vals = [context.cast(builder, v, t, s) for v, t, s in zip(args, (a, b), sig.args)]
            if out not in _ROUNDED:  # integers: numba's own product
                return context.get_function(operator.mul, sig)(builder, vals)
            lt = context.get_value_type(out)
            fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(lt, [lt, lt]),
                                                _ROUNDED[out])
            return builder.call(fn, vals)

        return out(a, b), codegen
