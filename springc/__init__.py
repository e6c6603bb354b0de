"""springc: a netlist compiler and toolchain for springtronics (nonlinear mass-spring networks).

`springc.load(path_or_text)` is the way in from Python (`springc.api`, docs/api.md); keyword
spotting's commands are `springc.train`, `evaluate`, `cross_validate`, `synthesise` and
`tune` (`springc.kws`)."""

from springc.version import __version__  # noqa: F401  (springc.__version__)

_KWS = ("cross_validate", "evaluate", "synthesise", "train", "tune")
__all__ = ["Netlist", "Result", "default_device", "load", *_KWS]


def __getattr__(name: str):
    # the API imports the checks and scipy, keyword spotting its whole stack: only when it
    # is used, so that `springc.lang` and the CLI's light commands start fast
    if name in _KWS:
        from springc import kws

        return getattr(kws, name)
    if name in __all__:
        from springc import api

        return getattr(api, name)
    raise AttributeError(f"module 'springc' has no attribute {name!r}")
