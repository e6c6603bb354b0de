"""springc's version, in a module of its own: what records it (a model folder's settings) reads
it from here, not from the package, whose `__init__` reaches every stage."""

__version__ = "0.1.0"
