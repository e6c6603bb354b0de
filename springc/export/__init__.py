"""Export: a netlist in other tools' syntax. `spice` writes ngspice netlists by the
force-current analogy; `ngspice` runs them and reads the results back for cross-checks.
"""
