"""Keyword spotting, in subpackages that import one way: `data` (speech data sets, synthetic
corpus, pre-processing, tasks) -> `features` (digital or mass-spring filterbanks, Phi) ->
`training` (linear classifiers, weight transfer, model folders) -> `evaluation` (test splits,
cross-validation, energy, classifying recordings) -> `tuning` (refit and gradient tuning).

`springc.kws.load_model(folder)` is the way in from Python (docs/api.md), with `train`,
`evaluate`, `cross_validate`, `synthesise` and `tune` for the commands (also
`springc.train`, ...)."""

__all__ = ["Model", "cross_validate", "evaluate", "load_model", "synthesise", "train", "tune"]


def __getattr__(name: str):
    # these import the whole evaluation (or tuning) stage: only when one is asked for
    if name == "tune":
        from springc.kws.tuning.tune import tune_model

        return tune_model
    if name in __all__:
        from springc.kws.evaluation import api

        return getattr(api, name)
    raise AttributeError(f"module 'springc.kws' has no attribute {name!r}")
