"""Non-temporal (streaming) vector stores for generated kernels.

A kernel recording probes at every step writes far more than the caches hold; an ordinary
store reads each line into the cache before writing it, a non-temporal one writes whole lines
straight to memory (half the traffic; docs/performance.md#the-shared-kernels-shape). LLVM
emits them for a store with `!nontemporal` metadata, which numba cannot spell, hence these
intrinsics. They are weakly ordered: a kernel ends with `store_fence()` before its caller
reads what it wrote.
"""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.core import cgutils, config
from numba.extending import intrinsic


@intrinsic
def stream_store(typingctx, arr, i, j, k, values):
    """arr[i, j, k:k + len(values)] = values as one non-temporal vector store. The caller
    guarantees that the address is aligned to the vector's size (len(values) x itemsize):
    a misaligned one faults."""
    if not (isinstance(arr, types.Array) and arr.ndim == 3 and arr.layout == "C"
            and isinstance(values, types.UniTuple) and values.dtype == arr.dtype):
        return None
    sig = types.void(arr, i, j, k, values)

    def codegen(context, builder, signature, args):
        ary_ty = signature.args[0]
        ary = context.make_array(ary_ty)(context, builder, args[0])
        index = [context.cast(builder, a, t, types.intp)
                 for a, t in zip(args[1:4], signature.args[1:4])]
        ptr = cgutils.get_item_pointer(context, builder, ary_ty, ary, index, wraparound=False)
        width = values.count
        vec_ty = ir.VectorType(context.get_data_type(arr.dtype), width)
        vec = ir.Constant(vec_ty, ir.Undefined)
        for b in range(width):
            lane = builder.extract_value(args[4], b)
            vec = builder.insert_element(vec, lane, ir.Constant(ir.IntType(32), b))
        store = builder.store(vec, builder.bitcast(ptr, vec_ty.as_pointer()),
                              align=width * arr.dtype.bitwidth // 8)
        store.set_metadata("nontemporal",
                           builder.module.add_metadata([ir.Constant(ir.IntType(32), 1)]))
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def store_fence(typingctx):
    """A full memory fence: orders the streaming stores before everything after it."""
    sig = types.void()

    def codegen(context, builder, signature, args):
        builder.fence("seq_cst")
        return context.get_dummy_value()

    return sig, codegen


if config.DISABLE_JIT:  # NUMBA_DISABLE_JIT=1: a kernel runs as Python, these as what they do
    def stream_store(arr, i, j, k, values) -> None:  # noqa: F811
        arr[i, j, k:k + len(values)] = values

    def store_fence() -> None:  # noqa: F811
        pass
