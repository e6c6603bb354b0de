"""`springc bench`: speed against error of the generated kernels and their peers.

`suite` runs the reference networks (`networks`) through every integrator and the peers
(`reference`: plain numpy RK4 and scipy `solve_ivp`; ngspice through `springc.export`) and
rates each kernel against the machine's measured ceiling (`ceiling`); `throughput` is the
single-network kernel benchmark.
"""
