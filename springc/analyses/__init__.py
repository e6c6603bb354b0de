"""Analyses of the linearisation at rest: small-signal frequency response (`ac`) and modes
(`modes`). Each module has one entry function returning a result object with its own
writers (CSV or JSON, text, PNG)."""
