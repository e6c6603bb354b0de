"""Two LLVM intrinsics for the thermal-noise generator's lane loops (`springc.kernels.thermal`),
which numba does not spell in a form that vectorises: its square root is a libm call that may
set errno (LLVM then guards every lane with a branch to it, and the loop stays scalar), and
its leading-zero count lives in numba's internals.
"""

from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba import types
from numba.core import config
from numba.extending import intrinsic


@intrinsic
def sqrt_(typingctx, x):
    """The square root of a float64 (`llvm.sqrt`: no errno, NaN below zero)."""
    if x != types.float64:
        return None
    sig = types.float64(types.float64)

    def codegen(context, builder, signature, args):
        fn = builder.module.declare_intrinsic("llvm.sqrt", [args[0].type])
        return builder.call(fn, args)

    return sig, codegen


@intrinsic
def clz(typingctx, k):
    """The leading zero bits of a uint64 (`llvm.ctlz`, 64 for zero), as uint64."""
    if k != types.uint64:
        return None
    sig = types.uint64(types.uint64)

    def codegen(context, builder, signature, args):
        return builder.ctlz(args[0], ir.Constant(ir.IntType(1), 0))

    return sig, codegen


if config.DISABLE_JIT:  # NUMBA_DISABLE_JIT=1: a kernel runs as Python, these as what they do
    def sqrt_(x: float) -> float:  # noqa: F811
        return math.sqrt(x) if x >= 0 else math.nan

    def clz(k):  # noqa: F811
        return np.uint64(64 - int(k).bit_length())
