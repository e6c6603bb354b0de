"""springc: a netlist compiler and toolchain for springtronics (nonlinear mass-spring networks).

`springc.load(path_or_text)` is the way in from Python (`springc.api`, docs/api.md)."""

__version__ = "0.1.0"

__all__ = ["Netlist", "Result", "default_device", "load"]


def __getattr__(name: str):
    # the API imports the checks and scipy: only when it is used, so that `springc.lang` and
    # the CLI's light commands start fast
    if name in __all__:
        from springc import api

        return getattr(api, name)
    raise AttributeError(f"module 'springc' has no attribute {name!r}")
