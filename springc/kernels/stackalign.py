"""Aligning a generated kernel's stack frame to 64 bytes.

A register kernel's lane loop spills hundreds of vector registers a step; numba keeps the
ABI's 16-byte stack alignment, so many spills split cache lines, and which ones depends on
the frame's size. LLVM realigns a frame a function asks for (`alignstack`), which numba
cannot spell, hence this intrinsic, called first in those kernels (`codegen.aligned_frame`).
The measurements: docs/performance.md#the-float32-row-and-the-stack-frame.
"""

from __future__ import annotations

from numba import types
from numba.core import config
from numba.extending import intrinsic

FRAME_ALIGN = 64  # bytes: a 512-bit vector, and a cache line


@intrinsic
def align_stack(typingctx):
    """Align the calling function's stack frame to FRAME_ALIGN bytes (its prologue realigns
    the stack pointer, and LLVM may then spill vectors with aligned moves)."""
    sig = types.void()

    def codegen(context, builder, signature, args):
        attrs = builder.function.attributes
        attrs.alignstack = FRAME_ALIGN
        # llvmlite writes alignstack only beside another attribute (an empty set prints
        # none); numba's functions report errors by their return value, never unwind
        attrs.add("nounwind")
        return context.get_dummy_value()

    return sig, codegen


if config.DISABLE_JIT:  # NUMBA_DISABLE_JIT=1: a kernel runs as Python, with Python's frame
    def align_stack() -> None:  # noqa: F811
        pass
