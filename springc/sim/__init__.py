"""The runtime: a netlist, its inputs and settings in, results out.

`simulate.simulate` generates and loads the kernel, runs batches of inputs over threads and
returns a `results.SimResult` with only the probed quantities and the requested `reductions`;
`sources` and `audio` read and interpolate the input signals, `stepcheck` chooses the step of
nonlinear netlists by step doubling, and `results` writes result files.
"""
