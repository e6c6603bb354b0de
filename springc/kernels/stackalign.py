"""Aligning a generated kernel's stack frame to 64 bytes.

A register kernel's lane loop holds the whole step of 16 or 32 runs in vector registers and
spills hundreds of 64-byte values a step to its stack frame. numba's functions keep the
ABI's 16-byte stack alignment, so LLVM places those spills at whatever 16-byte offset the
frame gives them: unaligned vector moves, many of which split across two cache lines, and
which ones depended on the caller's stack depth and the frame's size. The feature extractor,
64 runs of 1 s recording 16 probes (A/B in one process, least of 9-11): float32 42.8 -> 36.2
ms, float64 91.4 -> 56.0 ms; recording nothing, float64 63.6 -> 49.2 ms. LLVM realigns a
frame when a function asks for it (`alignstack`); numba has no spelling for that, hence this
intrinsic, called first in those kernels (`codegen.aligned_frame`).
"""

from __future__ import annotations

from numba import types
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
