"""Keyword spotting, in subpackages that import one way: `data` (speech data sets, synthetic
corpus, pre-processing, tasks) -> `features` (digital or mass-spring filterbanks, Phi) ->
`training` (linear classifiers, weight transfer, model folders) -> `evaluation` (test splits,
cross-validation, energy, classifying recordings) -> `tuning` (refit and gradient tuning).

`springc.kws.load_model(folder)` is the way in from Python (docs/api.md)."""

__all__ = ["Model", "load_model"]


def __getattr__(name: str):
    # loading a model imports the whole evaluation stage: only when it is asked for
    if name in __all__:
        from springc.kws.evaluation import api

        return getattr(api, name)
    raise AttributeError(f"module 'springc.kws' has no attribute {name!r}")
