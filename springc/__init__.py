"""springc: a netlist compiler and toolchain for springtronics (nonlinear mass-spring networks)."""

__version__ = "0.1.0"
