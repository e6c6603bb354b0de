"""The kernel stage: a checked netlist and `codegen.KernelOptions` in, a compiled kernel out.

`codegen` writes the Python source of a Numba kernel as text (never importing numba),
`integrators` holds the Butcher tableaux the stages are unrolled from, and `loader` writes the
text to the kernel cache and compiles it. The kernel forms:

| form | module | serves |
|---|---|---|
| shared (loops over index arrays) | `codegen` | any netlist; one per set of element kinds |
| written out per node | `codegen.emit_nodes` | long runs of small nets with reductions |
| register (a run's step in scalars) | `regkernel` | long runs up to 48 masses; single runs |
| exponential (Lawson, splitting) | `expint` | stiff driven linear blocks, exactly |

`streamstore` and `stackalign` are the numba intrinsics the generated kernels call.
"""
